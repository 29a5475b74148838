//! Trust under contention: a store whose write lock is held elsewhere (a long erasure, a
//! backup, a pilot filing) and a server that stalls must not delay an E-stop's answer, lose
//! its latch or its audit row, or cost a running test its controller link.

use std::time::Duration;

use bdft_tests::send_signal;
use bdft_tests::server::{
    HeldWrite, Server, consented_synthetic_subject, controller_ready, dry_run, eventually,
    replace_controller, running_practice, short_study, wait_latched,
};
use serde_json::{Value, json};

fn audit_rows(api: &bdft_tests::server::Api, action: &str) -> Vec<Value> {
    let (_, log) = api.get("/api/audit?limit=10000");
    log.as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == action)
        .cloned()
        .collect()
}

#[test]
fn an_estop_is_answered_and_kept_while_the_store_is_held() {
    let mut server = Server::start("contention-estop");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 1.0, 0.3));
    let (_, practice, pid) = consented_synthetic_subject(&server, &api, study);
    let lock = HeldWrite::take(&server);
    // With the write lock held (for as long as this test wants: it is released only below),
    // the stop is answered — before, the answer waited for the busy timeout and came 503,
    // the latch never stored.
    let (code, body) = api.post("/api/estop", json!({}));
    assert_eq!(code, 200, "{body}");
    assert!(body["confirmed_ms"].as_f64().unwrap() >= 0.0, "{body}");
    assert!(body.get("latch_not_kept").is_none(), "{body}");
    // The controller dies; its successor is told the latch (from the server's latch, not
    // the held store), and no test starts.
    assert_eq!(replace_controller(&api, pid)["estop_latched"], true);
    let (code, body) = api.post(&format!("/api/trials/{practice}/start"), json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("latched"),
        "{body}"
    );
    // The store is still held: the press's audit row waits (in the latch file). The server
    // is killed meanwhile, the lock released, the server started again: the latch holds and
    // the row is written, never dropped.
    assert!(audit_rows(&api, "estop").is_empty());
    server.proc.kill();
    drop(lock);
    server.crash_and_restart();
    let api = server.experimenter();
    let row = eventually(Duration::from_secs(30), || {
        audit_rows(&api, "estop").into_iter().next()
    });
    assert!(row["detail"]["pressed_at"].as_i64().is_some(), "{row}");
    assert_eq!(row["detail"]["delivered"], true, "{row}");
    eventually(Duration::from_secs(30), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["estop_latched"] == true).then_some(())
    });
    let (code, body) = api.post(&format!("/api/trials/{practice}/start"), json!({}));
    assert_eq!(code, 409, "{body}");
    // Only a reset releases it, recorded after the press.
    api.ok("/api/estop/reset", json!({}));
    wait_latched(&api, false);
    let (_, log) = api.get("/api/audit?limit=10000");
    let actions: Vec<&str> = log
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|a| a["action"].as_str())
        .filter(|a| a.starts_with("estop"))
        .collect();
    // Newest first.
    assert_eq!(actions, ["estop.reset", "estop"], "{log}");
}

#[test]
fn a_reset_waits_for_the_press_before_it_to_be_recorded() {
    let server = Server::start("contention-reset");
    let api = server.experimenter();
    // The press is confirmed by the controller: wait until it is connected (on a loaded
    // machine it may not be yet when the server answers).
    controller_ready(&api);
    let lock = HeldWrite::take(&server);
    let (code, body) = api.post("/api/estop", json!({}));
    assert_eq!(code, 200, "{body}");
    // A reset needs the store: while it is held, the reset is refused (503) after waiting,
    // and the latch stays.
    let (code, body) = api.post("/api/estop/reset", json!({}));
    assert_eq!(code, 503, "{body}");
    assert_eq!(api.get("/api/controller").1["estop_latched"], true);
    drop(lock);
    api.ok("/api/estop/reset", json!({}));
    wait_latched(&api, false);
    assert_eq!(audit_rows(&api, "estop").len(), 1);
    assert_eq!(audit_rows(&api, "estop.reset").len(), 1);
}

#[test]
fn a_stalled_server_keeps_its_controller_link_and_the_running_test() {
    let server = Server::start("contention-stall");
    let api = server.experimenter();
    let (subject, _, pid) = running_practice(&server, &api, 3.0);
    // The server stalls (stopped, then continued: every thread of it, its runtime and its
    // reader alike) for four times the silence limit, and its store is held across the
    // test's end (its result waits to be filed). A controller that kept sending meanwhile
    // is not hung.
    let server_pid = server.proc.child.id();
    let lock = HeldWrite::take(&server);
    for _ in 0..4 {
        send_signal(server_pid, "STOP").unwrap();
        std::thread::sleep(Duration::from_millis(300));
        send_signal(server_pid, "CONT").unwrap();
        std::thread::sleep(Duration::from_millis(200));
    }
    // Held past the test's end (3 s) so its result waits for the store.
    std::thread::sleep(Duration::from_millis(2000));
    drop(lock);
    let row = eventually(Duration::from_secs(30), || {
        let (_, d) = api.get(&format!("/api/subjects/{subject}"));
        let t = d["trials"][0]["trial"].clone();
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(row["status"], "complete", "{row}");
    let (_, c) = api.get("/api/controller");
    assert_eq!(
        c["pid"].as_u64(),
        Some(pid),
        "the controller was replaced: {c}"
    );
    assert_eq!(c["connected"], true, "{c}");
}
