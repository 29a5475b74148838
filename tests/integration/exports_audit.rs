//! Exports and the audit log complete: notes and reasons in the notes export, the audit log
//! as CSV (HTTP and `bdft-server export --kind audit`), formula cells neutralized behind
//! leading whitespace, PNG plots of awkward names, and a killed pilot's trials filed.

use std::process::Stdio;
use std::time::Duration;

use bdft_tests::server::{Api, Server, assigned_station, eventually};
use bdft_tests::{TempDir, server_cmd, succeeded};
use serde_json::{Value, json};

pub(crate) use bdft_tests::exports::parse_csv;

pub(crate) fn column(rows: &[Vec<String>], name: &str) -> usize {
    rows[0]
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name} in {:?}", rows[0]))
}

#[test]
fn notes_and_reasons_are_exported_and_the_audit_log_too() {
    let server = Server::start("exports-notes");
    let api = server.experimenter();
    let (_, mut p) = api.get("/api/defaults");
    p["trial_s"] = json!(1.0);
    p["practice_s"] = json!(0.5);
    p["step_interval_s"] = json!(0.5);
    let name = "study <&> \"quoted\" ∂ with =controls";
    let study = api.ok("/api/studies", json!({ "name": name, "params": p }))["id"]
        .as_i64()
        .unwrap();
    let subject = api.ok(&format!("/api/studies/{study}/subjects"), json!({}))["subject"]["id"]
        .as_i64()
        .unwrap();
    let (_, token) = assigned_station(&api, study, subject);
    Api::with_bearer(&api.base, &token).ok("/api/station/consent", json!({ "decision": "agreed" }));
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let trial = s["trials"][1]["trial"]["id"].as_i64().unwrap();
    // A note and reasons whose text a spreadsheet would read as formulas.
    api.ok(
        &format!("/api/trials/{trial}/note"),
        json!({ "text": "\u{a0}=HYPERLINK(\"x\")" }),
    );
    api.ok(
        &format!("/api/trials/{trial}/incomplete"),
        json!({ "reason": " =1+1 felt ill" }),
    );
    api.ok(
        &format!("/api/trials/{trial}/redo"),
        json!({ "reason": "\u{3000}+retry later" }),
    );

    let (code, text) = api.get_text(&format!("/api/studies/{study}/export/notes"));
    assert_eq!(code, 200, "{text}");
    let rows = parse_csv(&text);
    let (kind, body, id) = (
        column(&rows, "kind"),
        column(&rows, "text"),
        column(&rows, "trial_id"),
    );
    let of = |k: &str| {
        rows.iter()
            .find(|r| r[kind] == k && r[id] == trial.to_string())
            .unwrap_or_else(|| panic!("no {k} row in {text}"))
            .clone()
    };
    assert_eq!(of("note")[body], "'\u{a0}=HYPERLINK(\"x\")");
    assert_eq!(of("accept_incomplete")[body], "' =1+1 felt ill");
    assert_eq!(of("redo")[body], "'\u{3000}+retry later");
    let status = of("status");
    assert_eq!(status[column(&rows, "status")], "incomplete");
    assert_eq!(status[body], "' =1+1 felt ill");
    assert_eq!(of("note")[column(&rows, "by")], "admin");

    // The audit log, whole, as CSV over HTTP and from the command line.
    let (code, text) = api.get_text("/api/audit/export");
    assert_eq!(code, 200, "{text}");
    let audit = parse_csv(&text);
    assert_eq!(
        audit[0],
        [
            "id", "at", "actor", "actor_id", "action", "target", "detail"
        ]
    );
    let action = column(&audit, "action");
    for a in [
        "study.create",
        "consent",
        "trial.note",
        "trial.accept_incomplete",
        "trial.redo",
    ] {
        assert!(
            audit.iter().any(|r| r[action] == a),
            "no {a} in the audit export"
        );
    }
    let (code, body) = api.get(&format!("/api/studies/{study}/export/audit"));
    assert_eq!(code, 422, "{body}");
    let dir = TempDir::new("exports-audit-cli");
    let out = dir.path().join("audit.csv");
    succeeded(
        server_cmd([
            "export",
            "--kind",
            "audit",
            "--db",
            &server.store(),
            "--out",
        ])
        .arg(&out),
    );
    let cli = parse_csv(&std::fs::read_to_string(&out).unwrap());
    assert!(cli.len() >= audit.len() - 1 && cli[0] == audit[0]);

    // Plots of a study whose name has markup and quotes render (no 500).
    for file in ["mse_tracking_mm2.png", "mse_tracking_mm2.svg"] {
        let (code, _) = api.get_text(&format!("/api/studies/{study}/plots/{file}"));
        assert_eq!(code, 200, "{file}");
    }
}

/// Every trial of the study's subjects: (id, status, status_reason).
fn trials_of(api: &Api, study: i64) -> Vec<(i64, String, String)> {
    let (_, subjects) = api.get(&format!("/api/studies/{study}/subjects"));
    let mut out = Vec::new();
    for s in subjects.as_array().unwrap() {
        let id = s["subject"]["id"]
            .as_i64()
            .or_else(|| s["id"].as_i64())
            .unwrap();
        let (_, detail) = api.get(&format!("/api/subjects/{id}"));
        for t in detail["trials"].as_array().unwrap() {
            let t = &t["trial"];
            out.push((
                t["id"].as_i64().unwrap(),
                t["status"].as_str().unwrap().to_string(),
                t["status_reason"].as_str().unwrap_or_default().to_string(),
            ));
        }
    }
    out
}

#[test]
fn a_killed_pilot_process_leaves_no_trial_running() {
    let server = Server::start("exports-killed-pilot");
    let api = server.experimenter();
    let mut pilot = server_cmd(["pilot", "--subjects", "2", "--db", &server.store()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Killed while a trial of it runs.
    let study = eventually(Duration::from_secs(120), || {
        let (_, studies) = api.get("/api/studies");
        let id = studies.as_array()?.last()?["id"].as_i64()?;
        trials_of(&api, id)
            .iter()
            .any(|t| t.1 == "running")
            .then_some(id)
    });
    pilot.kill().unwrap();
    pilot.wait().unwrap();
    // The server sees the heartbeat stop and files the trials.
    let filed = eventually(Duration::from_secs(90), || {
        let trials = trials_of(&api, study);
        (!trials.iter().any(|t| t.1 == "running")).then_some(trials)
    });
    let interrupted: Vec<_> = filed
        .iter()
        .filter(|t| t.2.starts_with("pilot process"))
        .collect();
    assert!(!interrupted.is_empty(), "{filed:?}");
    assert!(interrupted.iter().all(|t| t.1 == "incomplete"), "{filed:?}");
    let (_, audit) = api.get("/api/audit?limit=1000");
    let ended: Vec<&Value> = audit
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "pilot.end")
        .collect();
    assert_eq!(ended.len(), 1, "{audit}");
    assert!(
        ended[0]["detail"]["reason"]
            .as_str()
            .unwrap()
            .contains("no heartbeat")
    );
}
