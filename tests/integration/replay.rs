//! `bdft-server replay` (issue 38), a real server's stored tests run again through the
//! controller's code by the command line: a pilot's every test — practice, both seats, every
//! compensator, uncancelled and cancelled, the identification — equal to its stored record
//! bit for bit, with the offline bound beside the online result; a person's test replayed
//! from the hand their station sent; and a test with nothing to replay refused by name.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use bdft_tests::server::{Server, eventually, pilot_copy, short_study, trial_rows};
use bdft_tests::{server_command, server_output, station};
use serde_json::{Value, json};

use crate::station_safety::{person_and_practice, trial_row};

fn replay(server: &Server, trial: i64) -> Value {
    let out = server_command([
        "replay",
        "--db",
        &server.store(),
        "--trial",
        &trial.to_string(),
    ]);
    serde_json::from_slice(&out.stdout).expect("the report is JSON")
}

#[test]
fn every_test_of_a_pilot_replays_bit_for_bit_with_its_offline_bound() {
    let server = Server::start("replay-pilot");
    let api = server.experimenter();
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(6.0);
    params["practice_s"] = json!(2.0);
    params["step_interval_s"] = json!(0.5);
    params["identification"] = json!({});
    params["cancellation"] = json!({ "arms": ["personal"] });
    let (code, study) = api.create_study("replay", &params);
    assert_eq!(code, 200, "{study}");
    let copy = pilot_copy(&api, study["id"].as_i64().unwrap(), 3);
    let (_, subjects) = api.get(&format!("/api/studies/{copy}/subjects"));
    let (mut replayed, mut bounds, mut online) = (0, 0, 0);
    let mut cells = std::collections::BTreeSet::new();
    for s in subjects.as_array().unwrap() {
        for t in trial_rows(&api, s["subject"]["id"].as_i64().unwrap()) {
            if t["status"] != "complete" {
                continue;
            }
            let r = replay(&server, t["id"].as_i64().unwrap());
            assert_eq!(r["identical"], true, "{t} {r}");
            assert_eq!(r["input"], "synthetic");
            assert_eq!(r["ticks_replayed"], r["ticks_stored"]);
            replayed += 1;
            cells.insert((t["controller"].to_string(), t["station"].to_string()));
            if t["station"] == "off" {
                assert!(r["why_no_bound"].as_str().unwrap().contains("desk"), "{r}");
            } else if let Some(o) = r["offline"].as_object() {
                // Offline, the subject's own model takes out nearly all of the feedthrough
                // the record carries (an upper bound: the cab moves as it did).
                assert!(o["removed_share"].as_f64().unwrap() > 0.9, "{r}");
                assert!(o["note"].as_str().unwrap().starts_with("an upper bound"));
                bounds += 1;
            } else if let Some(on) = r["online"].as_object() {
                let (before, after) = (
                    on["before_mm2"].as_f64().unwrap(),
                    on["after_mm2"].as_f64().unwrap(),
                );
                assert!(after < 0.1 * before, "{r}");
                online += 1;
            }
        }
    }
    // Every compensator at both seats. The identified subject's tests on the machine: five
    // uncancelled and the identification with a bound, five cancelled with their online
    // result (the others' bodies were not identified: nothing to cancel with).
    assert_eq!(cells.len(), 10, "{cells:?}");
    assert!(replayed >= 40, "{replayed}");
    assert_eq!((bounds, online), (6, 5));
}

/// How long a 3-second practice test may take to end on a loaded machine.
const LIMIT: Duration = Duration::from_secs(60);

#[test]
fn a_persons_test_replays_from_the_hand_their_station_sent() {
    let server = Server::start("replay-person");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 3.0);
    let (subject, _, token, practice) = person_and_practice(&server, &api, study);
    let mut ws = station::connect(&server.base, &token);
    let (code, body) = api.post(&format!("/api/trials/{practice}/start"), json!({}));
    assert_eq!(code, 200, "{body}");
    // Fed until the test has ended, however long a loaded machine makes it take.
    let stop = AtomicBool::new(false);
    let status = std::thread::scope(|scope| {
        let feeding = scope.spawn(|| station::feed_until(&mut ws, practice, 60.0, &stop, LIMIT));
        let status = eventually(LIMIT, || {
            let status = trial_row(&api, subject)["status"].clone();
            (status != "scheduled" && status != "running").then_some(status)
        });
        stop.store(true, Ordering::Relaxed);
        feeding.join().unwrap();
        status
    });
    assert_eq!(status, "complete");
    let r = replay(&server, practice);
    assert_eq!(r["input"], "person", "{r}");
    assert_eq!(r["identical"], true, "{r}");
    assert_eq!(r["ticks_replayed"], 3000);
    // The next test has not run: nothing to replay, said by name.
    let next = trial_rows(&api, subject)[1]["id"].as_i64().unwrap();
    let out = server_output([
        "replay",
        "--db",
        &server.store(),
        "--trial",
        &next.to_string(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("trial {next} has no record")),
        "{err}"
    );
}
