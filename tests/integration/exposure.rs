//! ISO 2631-1 exposure: the W_d weighting and a test's a_w and VDV against scipy's (the
//! fixture `tests/fixtures/exposure/`, made by `make.sh` with `make_fixture.py` from records
//! `bdft-controller simulate` wrote), and the
//! budget end to end: a runaway design on the machine is stopped by the exposure guard at the
//! budget, reaching the action value is audited, and the next test is refused naming the
//! figures.

use std::path::{Path, PathBuf};
use std::time::Duration;

use bdft_controller::exposure::{WdWeighting, of_record};
use bdft_tests::exports::parse_csv;
use bdft_tests::server::{
    Api, Server, dry_run, eventually, run_trial, synthetic_at_a_station, trial_rows,
};
use serde_json::{Value, json};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/exposure")
        .join(name)
}

fn reference() -> Value {
    serde_json::from_str(&std::fs::read_to_string(fixture("reference.json")).unwrap()).unwrap()
}

#[test]
fn the_discrete_weighting_is_within_a_tenth_of_a_db_of_scipys_analog_wd() {
    let dt = 1e-3;
    let wd = WdWeighting::new(dt);
    let rows = reference()["wd"].as_array().unwrap().clone();
    assert_eq!(rows.len(), 23, "0.5 to 80 Hz in one-third octaves");
    let mut worst: f64 = 0.0;
    for r in rows {
        let f = r["f_hz"].as_f64().unwrap();
        let err = 20.0 * (wd.magnitude(f, dt) / r["magnitude"].as_f64().unwrap()).log10();
        worst = worst.max(err.abs());
        assert!(err.abs() < 0.1, "{} Hz: {err:.4} dB", r["nominal_hz"]);
    }
    // The discretization's documented accuracy (exposure.rs, docs/exposure.md).
    assert!(worst < 0.03, "worst {worst:.4} dB");
}

/// The records of the fixture: run → cab acceleration (mm/s²) as the product wrote it.
fn records() -> Vec<(String, Vec<f32>)> {
    let rows = parse_csv(&std::fs::read_to_string(fixture("records.csv")).unwrap());
    assert_eq!(rows[0], ["run", "t_s", "cab_accel_mm_s2"]);
    let mut out: Vec<(String, Vec<f32>)> = Vec::new();
    for r in &rows[1..] {
        let a: f32 = r[2].parse().unwrap();
        match out.last_mut() {
            Some((id, v)) if *id == r[0] => v.push(a),
            _ => out.push((r[0].clone(), vec![a])),
        }
    }
    out
}

#[test]
fn a_w_and_vdv_of_recorded_tests_match_scipy_within_one_percent() {
    let reference = reference();
    let records = records();
    assert_eq!(records.len(), 2);
    // The product's figures, as its loop measured them while the tests ran.
    let runs = parse_csv(&std::fs::read_to_string(fixture("runs.csv")).unwrap());
    assert_eq!(runs[0], ["run", "cab_aw_m_s2", "cab_vdv_m_s175"]);
    for (trial, samples) in &records {
        let want = &reference["records"][trial];
        let (want_aw, want_vdv) = (
            want["aw_m_s2"].as_f64().unwrap(),
            want["vdv_m_s175"].as_f64().unwrap(),
        );
        assert!(
            want_aw > 0.05 && want_vdv > 0.1,
            "{trial}: a record that shakes"
        );
        assert_eq!(want["samples"].as_u64().unwrap() as usize, samples.len());
        let within = |what: &str, ours: f64, theirs: f64| {
            let rel = (ours / theirs - 1.0).abs();
            assert!(
                rel < 0.01,
                "{trial} {what}: ours {ours}, scipy {theirs} ({rel:.4})"
            );
        };
        // The weighting run over the exported record.
        let e = of_record(samples, 1e-3);
        within("a_w from the record", e.aw_m_s2, want_aw);
        within("VDV from the record", e.vdv_m_s175, want_vdv);
        // What the loop measured as the test ran (what the server stores and exports).
        let row = runs[1..].iter().find(|r| r[0] == *trial).unwrap();
        within("a_w of the loop", row[1].parse().unwrap(), want_aw);
        within("VDV of the loop", row[2].parse().unwrap(), want_vdv);
    }
}

/// A study on the simulated machine whose only compensator is the bench Ziegler–Nichols PID
/// (it limit-cycles with the feedthrough closed, about 1.7 g), its interlock set as high as
/// it goes, short tests and the default exposure budget (the action values).
fn runaway_study(api: &Api) -> i64 {
    let (_, mut params) = api.get("/api/defaults");
    let mut pid = params["controllers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["kind"] == "pid")
        .unwrap()
        .clone();
    pid["pid"] = json!({ "kp": 0.5203636363636363, "ti": 0.14818833271649967, "td": 0.03704708317912492, "n": 10.0 });
    params["controllers"] = json!([pid]);
    params["trial_s"] = json!(30.0);
    params["practice_s"] = json!(1.0);
    params["step_interval_s"] = json!(0.5);
    params["max_cab_rms_mm_s2"] = json!(1e6);
    let study = api.ok(
        "/api/studies",
        json!({ "name": "runaway", "params": params, "seed": 11 }),
    )["id"]
        .as_i64()
        .unwrap();
    let dry = dry_run(api, study);
    api.ok(
        &format!("/api/studies/{dry}/acknowledge-instability"),
        json!({ "reason": "the exposure guard's test: a limit cycle in simulation" }),
    );
    dry
}

#[test]
fn the_guard_stops_a_runaway_test_at_the_budget_and_the_next_is_refused_naming_the_figures() {
    let server = Server::start("exposure-guard");
    let api = server.experimenter();
    let study = runaway_study(&api);
    let (_, bad) = api.get("/api/defaults");
    // The limit values cannot be configured away.
    let mut over = bad.clone();
    over["exposure_budget_vdv_m_s175"] = json!(21.5);
    let (code, body) = api.post("/api/studies", json!({ "name": "x", "params": over }));
    assert_eq!(code, 422, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("exposure_budget_vdv_m_s175"),
        "{body}"
    );

    let (enrolled, _, _) = synthetic_at_a_station(&api, study);
    let subject = enrolled["id"].as_i64().unwrap();
    let trials = trial_rows(&api, subject);
    let practice = &trials[0];
    assert_eq!(practice["station"], "off");
    let on = trials.iter().find(|t| t["station"] == "on").unwrap()["id"]
        .as_i64()
        .unwrap();
    // The practice at the desk: measured, but nobody rode the cab.
    let p = run_trial(&api, subject, practice["id"].as_i64().unwrap());
    assert_eq!(p["status"], "complete", "{p}");
    assert!(p["cab_aw_m_s2"].as_f64().is_some(), "{p}");
    let (_, d) = api.get(&format!("/api/subjects/{subject}"));
    assert_eq!(d["exposure"]["days"], json!([]), "{d}");

    // The runaway on the machine: the guard stops it once the day's VDV reaches the budget
    // (9.1 m/s^1.75), within a tick's share past it, long before its 30 s.
    let t = run_trial(&api, subject, on);
    assert_eq!(t["status"], "incomplete", "{t}");
    let reason = t["status_reason"].as_str().unwrap();
    assert!(
        reason.contains("daily vibration budget is used up"),
        "{reason}"
    );
    let vdv = t["cab_vdv_m_s175"].as_f64().unwrap();
    let ran = t["exposure_s"].as_f64().unwrap();
    assert!((9.1..9.1 * 1.02).contains(&vdv), "VDV {vdv}");
    assert!(ran > 0.5 && ran < 29.0, "stopped after {ran} s");

    // Reaching the action value is in the audit log, with its figures.
    let (_, log) = api.get("/api/audit?limit=10000");
    let entry = log
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["action"] == "exposure.action_value")
        .unwrap_or_else(|| panic!("no exposure.action_value in {log}"))
        .clone();
    let detail = &entry["detail"];
    assert_eq!(detail["reached"], json!(["vdv"]), "{entry}");
    assert_eq!(detail["trial_id"], on);
    assert!(
        (detail["vdv_m_s175"].as_f64().unwrap() - vdv).abs() < 1e-9,
        "{entry}"
    );
    assert_eq!(entry["target"], format!("subject:{subject}"));

    // The day on the subject's page.
    let (_, d) = api.get(&format!("/api/subjects/{subject}"));
    let days = d["exposure"]["days"].as_array().unwrap();
    assert_eq!(days.len(), 1, "{d}");
    assert_eq!(days[0]["tests"], 1);
    assert!((days[0]["vdv_m_s175"].as_f64().unwrap() - vdv).abs() < 1e-9);

    // Nothing is left: the next test on the machine is refused before it starts, naming
    // the day so far, the worst case and the budget.
    // (A synthetic subject's failed test is redone by hand, as an experimenter would.)
    let redo = api.ok(
        &format!("/api/trials/{on}/redo"),
        json!({ "reason": "try the runaway again" }),
    );
    let id = eventually(Duration::from_secs(10), || {
        trial_rows(&api, subject)
            .into_iter()
            .find(|t| t["station"] == "on" && t["status"] == "scheduled")
    })["id"]
        .as_i64()
        .unwrap();
    assert!(redo.is_object());
    let (code, body) = api.post(&format!("/api/trials/{id}/start"), json!({}));
    assert_eq!(code, 409, "{body}");
    let msg = body["error"].as_str().unwrap();
    for figure in [
        format!("VDV {vdv:.2} m/s^1.75 so far"),
        "the interlock's limit of 1000.00 m/s² held for 30 s".into(),
        "budget of A(8) 0.5 m/s² and VDV 9.1 m/s^1.75".into(),
    ] {
        assert!(msg.contains(&figure), "{figure:?} in {msg}");
    }
    assert_eq!(
        trial_rows(&api, subject)
            .iter()
            .find(|t| t["id"] == id)
            .unwrap()["status"],
        "scheduled"
    );
}
