//! Valid tests only, nothing skipped, through the real server and controller: a station
//! whose display report shows it hidden beyond the study's limit, or that stops reporting,
//! has its test stopped and filed invalid, and the test comes back; a failed test is
//! re-queued at the end of its block, an accepted-incomplete one is not run again, and the
//! station never says "done" while a test is missing; in Chromium, a station tab that is
//! hidden during a test has it filed invalid with the hidden time.

use std::net::TcpStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bdft_tests::server::{self, Api, Server, eventually, trial_ended, trial_row};
use bdft_tests::station;
use bdft_tests::webdriver::Driver;
use serde_json::{Value, json};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

/// A study of people with `controllers` compensators (the defaults' first ones), tests of
/// `trial_s` and a practice of `practice_s`; the stale-input limit is wide because a test
/// thread feeding input can stall on a loaded machine.
fn person_study(api: &Api, controllers: usize, trial_s: f64, practice_s: f64) -> i64 {
    let (_, mut params) = api.get("/api/defaults");
    let all = params["controllers"].as_array().unwrap().clone();
    params["controllers"] = json!(all[..controllers]);
    params["trial_s"] = json!(trial_s);
    params["practice_s"] = json!(practice_s);
    params["step_interval_s"] = json!(0.5);
    params["stale_input_ms"] = json!(5000.0);
    api.ok(
        "/api/studies",
        json!({ "name": "validity", "params": params, "seed": 7 }),
    )["id"]
        .as_i64()
        .unwrap()
}

/// A person enrolled, consented and assigned to a station serving both seats, with the
/// controller connected: (subject id, the station's API).
fn person_and_station_client(server: &Server, api: &Api, study: i64) -> (i64, Api) {
    let (subject, _, token) = server::person_at_a_station(server, api, study);
    (subject, Api::with_bearer(&server.base, &token))
}

fn trials(api: &Api, subject: i64) -> Vec<Value> {
    server::trial_rows(api, subject)
}

/// What the station shows now.
fn state(station: &Api) -> Value {
    station.get("/api/station/state").1
}

/// The (slot, attempt) of the test the station shows.
fn shown_test(api: &Api, subject: i64, station: &Api) -> (i64, i64) {
    let s = state(station);
    let id = s["test"]["trial_id"]
        .as_i64()
        .unwrap_or_else(|| panic!("{s}"));
    let t = trial_row(api, subject, id);
    (t["slot"].as_i64().unwrap(), t["attempt"].as_i64().unwrap())
}

fn station_socket(server: &Server, station: &Api) -> Socket {
    let mut ws = station::connect(&server.base, station.bearer.as_deref().unwrap());
    station::read_timeout(&mut ws, Duration::from_millis(5));
    ws
}

fn text(v: Value) -> Message {
    Message::Text(v.to_string().into())
}

/// Feeds `trial` from its own thread as a page does: input at 100 Hz, and display reports
/// every 250 ms while `reporting` is set. Stops when `stop` is set.
fn feed(
    mut ws: Socket,
    trial: i64,
    reporting: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<Socket> {
    std::thread::spawn(move || {
        let began = Instant::now();
        let (mut seq, mut last_report) = (0u64, None::<Instant>);
        while !stop.load(Ordering::Relaxed) && began.elapsed() < Duration::from_secs(120) {
            seq += 1;
            let input =
                json!({ "type": "input", "trial_id": trial, "seq": seq, "position_mm": 2.0 });
            if ws.send(text(input)).is_err() {
                break;
            }
            if reporting.load(Ordering::Relaxed)
                && last_report.is_none_or(|t| t.elapsed() >= Duration::from_millis(250))
            {
                last_report = Some(Instant::now());
                let report = json!({ "type": "display", "trial_id": trial, "hidden": false,
                    "frames": seq, "longest_gap_ms": 17.0, "hidden_ms": 0.0, "inputs": seq });
                if ws.send(text(report)).is_err() {
                    break;
                }
            }
            // Read what comes back (and keep the socket's buffers from filling up).
            while ws.read().is_ok() {}
            std::thread::sleep(Duration::from_millis(10));
        }
        ws
    })
}

#[test]
fn a_hidden_or_silent_display_stops_the_test_and_files_it_invalid() {
    let server = Server::start("validity-display");
    let api = server.experimenter();
    let study = person_study(&api, 2, 2.0, 60.0);
    let (subject, station) = person_and_station_client(&server, &api, study);
    let practice = state(&station)["test"]["trial_id"].as_i64().unwrap();

    // A page that reports a healthy display, then one report of 800 ms hidden (the limit is
    // 500 ms): stopped at once, filed invalid with the reason — never complete.
    let ws = station_socket(&server, &station);
    let (reporting, stop) = (
        Arc::new(AtomicBool::new(true)),
        Arc::new(AtomicBool::new(false)),
    );
    api.ok(&format!("/api/trials/{practice}/start"), json!({}));
    let feeder = feed(ws, practice, Arc::clone(&reporting), Arc::clone(&stop));
    std::thread::sleep(Duration::from_millis(500));
    reporting.store(false, Ordering::Relaxed);
    stop.store(true, Ordering::Relaxed);
    let mut ws = feeder.join().unwrap();
    let reported = Instant::now();
    ws.send(text(
        json!({ "type": "display", "trial_id": practice, "hidden": false,
        "frames": 30, "longest_gap_ms": 17.0, "hidden_ms": 800.0, "inputs": 50 }),
    ))
    .unwrap();
    let filed = trial_ended(&api, subject, practice);
    assert_eq!(filed["status"], "invalid", "{filed}");
    let reason = filed["status_reason"].as_str().unwrap();
    assert!(
        reason.contains("hidden for 800 ms (limit 500 ms)"),
        "{reason}"
    );
    // Stopped at once: long before the 60 s practice would have ended.
    assert!(
        reported.elapsed() < Duration::from_secs(30),
        "{:?}",
        reported.elapsed()
    );
    // The test comes back as the next attempt, and the station says what happened.
    let s = state(&station);
    assert_eq!(s["phase"], "ready", "{s}");
    assert_eq!(s["stopped"]["status"], "invalid", "{s}");
    assert_eq!(s["stopped"]["repeated"], true, "{s}");
    assert_eq!(shown_test(&api, subject, &station), (0, 2));

    // A page that feeds input but never reports its display (its tab hidden and throttled,
    // or its drawing stalled): the watchdog stops it too.
    let again = s["test"]["trial_id"].as_i64().unwrap();
    api.ok(&format!("/api/trials/{again}/start"), json!({}));
    let (reporting, stop) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicBool::new(false)),
    );
    let feeder = feed(ws, again, reporting, Arc::clone(&stop));
    let filed = trial_ended(&api, subject, again);
    stop.store(true, Ordering::Relaxed);
    feeder.join().unwrap();
    assert_eq!(filed["status"], "invalid", "{filed}");
    let reason = filed["status_reason"].as_str().unwrap();
    assert!(reason.contains("no display report"), "{reason}");
    // Both are audited, and neither counts in the results.
    let (_, audit) = api.get("/api/audit?limit=50");
    let invalid = audit
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == "trial.invalid")
        .count();
    assert_eq!(invalid, 2, "{audit}");
    let (code, csv) = api.get_text(&format!("/api/studies/{study}/export/trials.csv"));
    assert_eq!(code, 200, "{csv}");
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    for column in [
        "display_hidden_ms",
        "controller_overruns",
        "accepted_reason",
    ] {
        assert!(header.contains(&column), "{header:?}");
    }
}

/// Starts `trial` and aborts it at once; returns its filed row.
fn start_and_abort(api: &Api, subject: i64, trial: i64) -> Value {
    let (code, body) = api.post(&format!("/api/trials/{trial}/start"), json!({}));
    assert_eq!(code, 200, "start {trial}: {body}");
    api.ok(
        &format!("/api/trials/{trial}/abort"),
        json!({ "reason": "subject sneezed" }),
    );
    trial_ended(api, subject, trial)
}

#[test]
fn a_failed_test_comes_back_at_the_end_of_its_block_and_the_station_never_says_done_while_one_is_missing()
 {
    let server = Server::start("validity-queue");
    let api = server.experimenter();
    // Two compensators: the practice (block 0), slots 1–2 (block 1), slots 3–4 (block 2).
    let study = person_study(&api, 2, 30.0, 30.0);
    let (subject, station) = person_and_station_client(&server, &api, study);
    let id_of = |slot: i64, attempt: i64| {
        trials(&api, subject)
            .into_iter()
            .find(|t| t["slot"] == slot && t["attempt"] == attempt)
            .unwrap_or_else(|| panic!("no attempt {attempt} of slot {slot}"))["id"]
            .as_i64()
            .unwrap()
    };

    // The aborted practice comes back; accepted as incomplete, it is not run again.
    let filed = start_and_abort(&api, subject, id_of(0, 1));
    assert_eq!(filed["status"], "aborted", "{filed}");
    assert_eq!(shown_test(&api, subject, &station), (0, 2));
    let s = state(&station);
    assert_eq!(
        (&s["stopped"]["status"], &s["stopped"]["repeated"]),
        (&json!("aborted"), &json!(true)),
        "{s}"
    );
    let accepted = api.ok(
        &format!("/api/trials/{}/incomplete", id_of(0, 1)),
        json!({ "reason": "practice skipped: the subject knows the display" }),
    );
    assert_eq!(
        accepted["id"],
        id_of(0, 2),
        "the latest attempt is accepted"
    );
    assert_eq!(accepted["status"], "incomplete");
    assert!(accepted["accepted_reason"].is_string(), "{accepted}");
    assert_eq!(shown_test(&api, subject, &station), (1, 1));

    // A failed scored test goes to the end of its block: after the block's other test,
    // before the next block.
    start_and_abort(&api, subject, id_of(1, 1));
    assert_eq!(shown_test(&api, subject, &station), (2, 1));
    start_and_abort(&api, subject, id_of(2, 1));
    assert_eq!(shown_test(&api, subject, &station), (1, 2));
    start_and_abort(&api, subject, id_of(1, 2));
    assert_eq!(shown_test(&api, subject, &station), (2, 2));
    start_and_abort(&api, subject, id_of(2, 2));
    assert_eq!(shown_test(&api, subject, &station), (1, 3));
    // The third attempt is the last the server makes by itself.
    start_and_abort(&api, subject, id_of(1, 3));
    assert_eq!(shown_test(&api, subject, &station), (2, 3));
    start_and_abort(&api, subject, id_of(2, 3));
    assert_eq!(shown_test(&api, subject, &station), (3, 1));
    let s = state(&station);
    assert_eq!(s["stopped"]["repeated"], false, "{s}");
    assert!(
        trials(&api, subject)
            .iter()
            .all(|t| t["attempt"].as_i64() <= Some(3))
    );

    // The second block accepted as incomplete: nothing left to run, but two tests are
    // missing — the station holds and never says done.
    for slot in [3, 4] {
        api.ok(
            &format!("/api/trials/{}/incomplete", id_of(slot, 1)),
            json!({ "reason": "the machine seat is out of order" }),
        );
    }
    let s = state(&station);
    assert_eq!(s["phase"], "held", "{s}");
    let (_, monitor) = api.get(&format!(
        "/api/stations/{}/state",
        api.get(&format!("/api/studies/{study}/stations")).1[0]["id"]
    ));
    assert_eq!(monitor["phase"], "held", "{monitor}");
    // A running test cannot be accepted; the experimenter may repeat one by hand past the
    // bound, and accepting the rest finishes the subject.
    api.ok(
        &format!("/api/trials/{}/redo", id_of(1, 3)),
        json!({ "reason": "one more try" }),
    );
    assert_eq!(shown_test(&api, subject, &station), (1, 4));
    let (code, body) = api.post(&format!("/api/trials/{}/start", id_of(1, 4)), json!({}));
    assert_eq!(code, 200, "{body}");
    let (code, body) = api.post(
        &format!("/api/trials/{}/incomplete", id_of(1, 4)),
        json!({ "reason": "x" }),
    );
    assert_eq!(code, 409, "{body}");
    api.ok(
        &format!("/api/trials/{}/abort", id_of(1, 4)),
        json!({ "reason": "still broken" }),
    );
    trial_ended(&api, subject, id_of(1, 4));
    assert_eq!(state(&station)["phase"], "held");
    for (slot, attempt) in [(1, 4), (2, 3)] {
        api.ok(
            &format!("/api/trials/{}/incomplete", id_of(slot, attempt)),
            json!({ "reason": "rig fault, not repeatable today" }),
        );
    }
    let s = state(&station);
    assert_eq!(
        (&s["phase"], &s["reason"]),
        (&json!("done"), &json!("finished")),
        "{s}"
    );
    let (_, audit) = api.get("/api/audit?limit=100");
    let accepts = audit
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == "trial.accept_incomplete")
        .count();
    assert_eq!(accepts, 5, "{audit}");
}

#[test]
fn a_station_tab_hidden_during_a_test_has_it_filed_invalid_in_chromium() {
    let server = Server::start("validity-browser");
    let api = server.experimenter();
    let study = person_study(&api, 2, 30.0, 60.0);
    let (subject, station) = person_and_station_client(&server, &api, study);
    let token = station.bearer.clone().unwrap();

    let driver = Driver::start();
    let dir = bdft_tests::TempDir::new("validity-browser");
    let s = driver.session(dir.path());
    s.open_paired_station(&server.base, &token);
    let station_tab = s.cmd("GET", "/window", json!(null)).unwrap();
    // On a loaded machine the controller link can drop and fault an attempt before the tab
    // is hidden (the server repeats it): then the next attempt is tried, at most three.
    let mut filed = Value::Null;
    for attempt in 1..=3 {
        s.wait_phase("ready");
        let trial = state(&station)["test"]["trial_id"].as_i64().unwrap();
        api.ok(&format!("/api/trials/{trial}/start"), json!({}));
        // Drawing, visible: the page's display reports keep the test going.
        // Until the page draws the test, or the test has ended (faulted) meanwhile.
        let drawing = eventually(Duration::from_secs(60), || {
            let laid_out = s.exec(
                "if (document.body.dataset.phase !== 'running') return false; \
                 const r = document.getElementById('track').getBoundingClientRect(); return r.width > 0 && r.height > 0;",
                json!([]),
            ) == json!(true);
            let running = trial_row(&api, subject, trial)["status"] == "running";
            (laid_out || !running).then_some(laid_out && running)
        });
        if !drawing {
            eprintln!("attempt {attempt} ended before the tab was hidden");
            continue;
        }
        // Another tab in front hides the station's tab (visibilitychange fires).
        let other = s
            .cmd("POST", "/window/new", json!({ "type": "tab" }))
            .unwrap();
        s.cmd("POST", "/window", json!({ "handle": other["handle"] }))
            .unwrap();
        s.goto("about:blank");
        filed = trial_ended(&api, subject, trial);
        // Closing it brings the station's tab to the front again.
        let _ = s.cmd("DELETE", "/window", json!(null));
        s.cmd("POST", "/window", json!({ "handle": station_tab }))
            .unwrap();
        if filed["status"] == "invalid" || attempt == 3 {
            break;
        }
        eprintln!("attempt {attempt} faulted otherwise: {filed}");
    }
    assert_eq!(filed["status"], "invalid", "{filed}");
    // The page said at once that it was hidden: the hidden time is the reason (before the
    // silence of its throttled timers would be).
    let reason = filed["status_reason"].as_str().unwrap();
    assert!(reason.contains("the display was hidden for"), "{reason}");
    // Back at the station: it says what happened, and the test comes back.
    s.wait_phase("ready");
    s.wait_until(
        "const n = document.getElementById('stopped-notice'); return !n.hidden && n.textContent.includes('It will be repeated next.');",
        json!([]),
    );
    let (slot, attempt) = shown_test(&api, subject, &station);
    assert_eq!(slot, 0, "the practice again");
    assert!(attempt > filed["attempt"].as_i64().unwrap());
}
