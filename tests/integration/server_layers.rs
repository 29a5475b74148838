//! The server's layers seen from outside: changes racing each other are serialized or
//! refused with a 409 (never a 500), every change has its audit row, and the OpenAPI
//! document describes every operation.

use std::time::Duration;

use bdft_tests::send_signal;
use bdft_tests::server::{
    Api, Server, assigned_station, consent_at, consented_synthetic_subject, dry_run, eventually,
    pair_station, replace_controller, run_pilot, run_trial, running_practice, short_study,
    wait_latched,
};
use serde_json::{Value, json};

/// Runs `n` copies of `call` at once (each its own logged-in client): statuses and bodies.
fn at_once(
    server: &Server,
    n: usize,
    call: impl Fn(&Api) -> (u16, Value) + Sync,
) -> Vec<(u16, Value)> {
    let clients: Vec<Api> = (0..n).map(|_| server.experimenter()).collect();
    let barrier = std::sync::Barrier::new(n);
    std::thread::scope(|s| {
        let handles: Vec<_> = clients
            .iter()
            .map(|c| {
                let (call, barrier) = (&call, &barrier);
                s.spawn(move || {
                    barrier.wait();
                    call(c)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

fn audit_actions(api: &Api) -> Vec<String> {
    let (_, log) = api.get("/api/audit?limit=10000");
    log.as_array()
        .unwrap()
        .iter()
        .map(|a| a["action"].as_str().unwrap().to_string())
        .collect()
}

#[test]
fn racing_changes_are_serialized_or_refused_never_a_500() {
    let server = Server::start("layers-race");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 1.0, 0.3));

    // Twelve enrolments at once: every one succeeds, each with its own code and index.
    let answers = at_once(&server, 12, |c| {
        c.post(
            &format!("/api/studies/{study}/subjects"),
            json!({ "synthetic": true }),
        )
    });
    for (code, body) in &answers {
        assert_eq!(*code, 200, "{body}");
    }
    let mut codes: Vec<String> = answers
        .iter()
        .map(|(_, b)| b["subject"]["code"].as_str().unwrap().to_string())
        .collect();
    codes.sort();
    let expected: Vec<String> = (1..=12).map(|i| format!("S{i:02}")).collect();
    assert_eq!(codes, expected);
    let enrolments = audit_actions(&api)
        .iter()
        .filter(|a| *a == "subject.enrol")
        .count();
    assert_eq!(enrolments, 12, "one audit row per enrolment");

    // Run the first subject's practice, then redo it eight times at once: one new attempt,
    // seven clear conflicts.
    let subject = answers[0].1["subject"]["id"].as_i64().unwrap();
    let (_, token) = assigned_station(&api, study, subject);
    let (practice, _) = consent_at(&server, &api, &token, subject);
    let done = run_trial(&api, subject, practice);
    assert_eq!(done["status"], "complete", "{done}");
    let redos = at_once(&server, 8, |c| {
        c.post(
            &format!("/api/trials/{practice}/redo"),
            json!({ "reason": "race" }),
        )
    });
    let ok = redos.iter().filter(|(c, _)| *c == 200).count();
    let conflicts = redos.iter().filter(|(c, _)| *c == 409).count();
    assert_eq!((ok, conflicts), (1, 7), "{redos:?}");
    for (code, body) in &redos {
        if *code == 409 {
            assert!(
                body["error"].as_str().is_some_and(|e| !e.is_empty()),
                "{body}"
            );
        }
    }
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    let attempts = detail["trials"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|t| t["trial"]["slot"] == 0)
        .count();
    assert_eq!(attempts, 2, "exactly one new attempt");
    let actions = audit_actions(&api);
    assert_eq!(actions.iter().filter(|a| *a == "trial.redo").count(), 1);
    // The controller's filing of the result has its audit row too.
    assert!(actions.iter().any(|a| a == "trial.finish"), "{actions:?}");

    // Two experimenters editing a locked study: both refused with the reason.
    let (_, current) = api.get(&format!("/api/studies/{study}"));
    let edits = at_once(&server, 2, |c| {
        c.call(
            "PUT",
            &format!("/api/studies/{study}"),
            Some(json!({ "name": "renamed", "params": current["params"], "version": current["version"] })),
        )
    });
    for (code, body) in &edits {
        assert_eq!(*code, 409, "{body}");
        assert!(body["error"].as_str().unwrap().contains("locked"), "{body}");
    }
}

#[test]
fn the_openapi_document_has_schemas_for_every_operation() {
    let server = Server::start("layers-doc");
    let (code, doc) = Api::anonymous(&server.base).get("/api/openapi.json");
    assert_eq!(code, 200);
    let schemas = doc["components"]["schemas"].as_object().unwrap();
    let mut operations = 0;
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            operations += 1;
            let answers = op["responses"].as_object().unwrap();
            assert!(
                answers.contains_key("200") || answers.contains_key("101"),
                "{method} {path} documents no success answer"
            );
            assert!(
                answers.contains_key("422"),
                "{method} {path} documents no error answer"
            );
            assert!(
                op["security"].is_array(),
                "{method} {path} says nothing of who may call it"
            );
            // A WebSocket upgrade switches protocols: there is no body to describe.
            if let Some(upgrade) = answers.get("101") {
                assert!(
                    upgrade.get("content").is_none(),
                    "{method} {path}: a 101 answer has no body"
                );
            }
            let Some(ok) = answers.get("200") else {
                continue;
            };
            let content = ok["content"]
                .as_object()
                .filter(|c| !c.is_empty())
                .unwrap_or_else(|| panic!("{method} {path}: its answer names no content type"));
            for (media, body) in content {
                let schema = &body["schema"];
                if media == "application/json" {
                    // A JSON answer names its schema, and that schema exists.
                    assert!(
                        schema.as_object().is_some_and(|s| !s.is_empty()),
                        "{method} {path}: its JSON answer names no schema"
                    );
                    let text = schema.to_string();
                    for name in text.split("#/components/schemas/").skip(1) {
                        let name = name.split('"').next().unwrap();
                        assert!(
                            schemas.contains_key(name),
                            "{method} {path}: schema {name} is missing"
                        );
                    }
                } else if media.starts_with("text/") || media.ends_with("+xml") {
                    assert_eq!(
                        schema["type"], "string",
                        "{method} {path}: its {media} answer is not described as text"
                    );
                }
                // Anything else is a binary file (PNG, Parquet): OpenAPI 3.1 describes raw
                // bytes by their media type alone.
            }
        }
    }
    assert!(operations >= 40, "only {operations} operations");
    // The files the server sends are of the media types the document names for them.
    let api = server.experimenter();
    let study = short_study(&api, 2.0, 1.0);
    for (path, operation) in [
        ("/api/audit/export".to_string(), "/api/audit/export"),
        (
            format!("/api/studies/{study}/export/trials"),
            "/api/studies/{id}/export/{kind}",
        ),
        (
            format!("/api/studies/{study}/export/trials?format=parquet"),
            "/api/studies/{id}/export/{kind}",
        ),
        (
            format!("/api/studies/{study}/plots/learning_curve.svg"),
            "/api/studies/{id}/plots/{file}",
        ),
        (
            format!("/api/studies/{study}/plots/learning_curve.png"),
            "/api/studies/{id}/plots/{file}",
        ),
    ] {
        let (code, content_type) = api.content_type(&path);
        assert_eq!(code, 200, "GET {path}");
        let media = content_type.split(';').next().unwrap().trim();
        assert!(
            doc["paths"][operation]["get"]["responses"]["200"]["content"]
                .get(media)
                .is_some(),
            "GET {path} answers {media}, which the document does not name for {operation}"
        );
    }
    // Request bodies are described, down to the study's parameters.
    let create = &doc["paths"]["/api/studies"]["post"];
    assert!(create["requestBody"]["content"]["application/json"]["schema"].is_object());
    let study_params = &schemas["StudyParams"]["properties"];
    for field in ["k_bf", "trial_s", "controllers", "survey"] {
        assert!(
            study_params.get(field).is_some(),
            "StudyParams has no {field}"
        );
    }
    // The subject-facing view of a test has no field for a compensator's name.
    let test_view = schemas["TestView"]["properties"].as_object().unwrap();
    assert!(!test_view.contains_key("controller") && !test_view.contains_key("compensator"));
}

/// The bench (Ziegler–Nichols) PIDs: unstable on the machine at K_BF 0.78 (up to 0.35).
fn bench_tuned(api: &Api, rig: &str) -> Value {
    let (_, mut params) = api.get("/api/defaults");
    let zn = json!({ "kp": 0.5203636363636363, "ti": 0.14818833271649967, "td": 0.03704708317912492, "n": 10.0 });
    for c in params["controllers"].as_array_mut().unwrap() {
        if c.get("pid").is_some() {
            c["pid"] = zn.clone();
        }
    }
    params["rig"] = json!(rig);
    params
}

#[test]
fn the_stability_gate_keeps_unstable_designs_off_the_machine() {
    let server = Server::start("layers-gate");
    let api = server.experimenter();
    // The default study: every design stable on and off the machine, with the margin.
    let (_, defaults) = api.get("/api/defaults");
    let good = api.ok(
        "/api/studies",
        json!({ "name": "default", "params": defaults }),
    )["id"]
        .as_i64()
        .unwrap();
    let (code, report) = api.get(&format!("/api/studies/{good}/stability"));
    assert_eq!(code, 200, "{report}");
    let verdicts = report["verdicts"].as_array().unwrap();
    assert_eq!(verdicts.len(), 5);
    for v in verdicts {
        assert_eq!(v["stable_on"], true, "{v}");
        assert_eq!(v["stable_off"], true, "{v}");
        assert_eq!(v["has_margin"], true, "{v}");
    }
    // The PID family's margins are the ones the slow tuning documents (found by
    // eigenvalues, `tyreus_luyben_pi`); the shaper's now comes from its frequency response.
    let margin = |name: &str| {
        verdicts.iter().find(|v| v["controller"] == name).unwrap()["max_stable_kbf"]
            .as_f64()
            .unwrap()
    };
    for (name, documented) in [("pid", 2.13), ("pid-notch", 4.0), ("pid-shaper", 5.4)] {
        let m = margin(name);
        assert!((m - documented).abs() < 0.05, "{name}: {m} vs {documented}");
    }
    // The bench PID on the real machine: the study cannot be locked, nor acknowledged.
    let real = api.ok(
        "/api/studies",
        json!({ "name": "bench on the machine", "params": bench_tuned(&api, "real") }),
    )["id"]
        .as_i64()
        .unwrap();
    let (_, report) = api.get(&format!("/api/studies/{real}/stability"));
    let pid = &report["verdicts"][0];
    assert_eq!(
        (pid["controller"].as_str(), &pid["stable_on"]),
        (Some("pid"), &json!(false)),
        "{report}"
    );
    let limit = pid["max_stable_kbf"].as_f64().unwrap();
    assert!((limit - 0.35).abs() < 0.01, "{limit}");
    let (code, body) = api.post(&format!("/api/studies/{real}/subjects"), json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("real machine"),
        "{body}"
    );
    let (code, _) = api.post(
        &format!("/api/studies/{real}/acknowledge-instability"),
        json!({ "reason": "trying" }),
    );
    assert_eq!(code, 409);
    assert!(api.get(&format!("/api/studies/{real}")).1["locked_at"].is_null());
    // In simulation it runs only after an acknowledgement, which the audit log keeps.
    let sim = api.ok(
        "/api/studies",
        json!({ "name": "bench in simulation", "params": bench_tuned(&api, "simulated") }),
    )["id"]
        .as_i64()
        .unwrap();
    let (code, body) = api.post(&format!("/api/studies/{sim}/subjects"), json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("acknowledge"),
        "{body}"
    );
    api.ok(
        &format!("/api/studies/{sim}/acknowledge-instability"),
        json!({ "reason": "reproducing the limit cycle in simulation" }),
    );
    let (code, body) = api.post(&format!("/api/studies/{sim}/subjects"), json!({}));
    assert_eq!(code, 200, "{body}");
    assert!(
        audit_actions(&api)
            .iter()
            .any(|a| a == "study.acknowledge_instability")
    );
}

#[test]
fn one_input_source_per_test_and_withdrawal_stops_the_running_test() {
    let server = Server::start("layers-withdraw");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 60.0, 60.0));
    let enrolled = api.ok(
        &format!("/api/studies/{study}/subjects"),
        json!({ "synthetic": true }),
    );
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    // A desk station and a machine station may share the subject; a second station serving
    // the same seat may not (both would feed the same test).
    let (desk, _) = pair_station(&api, study, "off");
    let (machine, _) = pair_station(&api, study, "on");
    let (both, token) = pair_station(&api, study, "both");
    for station in [desk, machine] {
        api.ok(
            &format!("/api/stations/{station}/assign"),
            json!({ "subject_id": subject }),
        );
    }
    let (code, body) = api.post(
        &format!("/api/stations/{both}/assign"),
        json!({ "subject_id": subject }),
    );
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("same seat"),
        "{body}"
    );
    // Moved to the one station that serves both seats, it is fine.
    for station in [desk, machine] {
        api.ok(
            &format!("/api/stations/{station}/assign"),
            json!({ "subject_id": null }),
        );
    }
    api.ok(
        &format!("/api/stations/{both}/assign"),
        json!({ "subject_id": subject }),
    );
    let (practice, _) = consent_at(&server, &api, &token, subject);
    let (code, body) = api.post(&format!("/api/trials/{practice}/start"), json!({}));
    assert_eq!(code, 200, "{body}");
    // The subject withdraws mid-test: the test stops at once, filed aborted with the reason.
    api.ok(
        &format!("/api/subjects/{subject}/withdraw"),
        json!({ "reason": "felt unwell" }),
    );
    let stopped = eventually(Duration::from_secs(20), || {
        let (_, d) = api.get(&format!("/api/subjects/{subject}"));
        let t = d["trials"][0]["trial"].clone();
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(stopped["status"], "aborted", "{stopped}");
    assert!(
        stopped["status_reason"]
            .as_str()
            .unwrap()
            .contains("withdrew"),
        "{stopped}"
    );
}

#[test]
fn a_hung_controller_is_noticed_within_its_silence_limit() {
    let server = Server::start("layers-hung");
    let api = server.experimenter();
    let (subject, _, pid) = running_practice(&server, &api, 60.0);
    let stopped_at = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis() as i64;
    // SIGSTOP: the process and its socket stay open; only its silence tells.
    send_signal(pid as u32, "STOP").unwrap();
    let row = eventually(Duration::from_secs(10), || {
        let (_, d) = api.get(&format!("/api/subjects/{subject}"));
        let t = d["trials"][0]["trial"].clone();
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(row["status"], "incomplete", "{row}");
    assert!(
        row["status_reason"]
            .as_str()
            .unwrap()
            .contains("sent nothing"),
        "{row}"
    );
    // The link counts as lost 75 ms after the last message (live samples come every 10 ms)
    // and the trial is filed within 100 ms of the stop (docs/benchmarks.md has the figures);
    // the bound leaves a loaded machine's scheduling 50 ms more.
    let noticed = row["finished_at"].as_i64().unwrap() - stopped_at;
    // (Printed for docs/benchmarks.md, which collects it over runs.)
    eprintln!("hung controller: its trial filed {noticed} ms after the stop");
    assert!(noticed <= 150, "noticed {noticed} ms after the stop");
    // The hung process is replaced (the server kills it) and trials run again.
    let new_pid = eventually(Duration::from_secs(20), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["pid"].as_u64() != Some(pid))
            .then(|| c["pid"].as_u64().unwrap())
    });
    assert_ne!(new_pid, pid);
}

#[test]
fn the_estop_latch_holds_across_a_controller_restart_until_reset() {
    let server = Server::start("layers-latch");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 1.0, 0.3));
    let (subject, practice, pid) = consented_synthetic_subject(&server, &api, study);
    api.ok("/api/estop", json!({}));
    // The controller dies; its successor starts latched and the server keeps it so.
    assert_eq!(replace_controller(&api, pid)["estop_latched"], true);
    let (code, body) = api.post(&format!("/api/trials/{practice}/start"), json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("latched"),
        "{body}"
    );
    // Only the experimenter's reset releases it, and then tests run again.
    api.ok("/api/estop/reset", json!({}));
    wait_latched(&api, false);
    let done = run_trial(&api, subject, practice);
    assert_eq!(done["status"], "complete", "{done}");
}

#[test]
fn the_estop_is_confirmed_while_a_station_floods_input() {
    let server = Server::start("layers-flood");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    // A person's test, fed by the station socket.
    let enrolled = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let (_, token) = assigned_station(&api, study, subject);
    let (practice, _) = consent_at(&server, &api, &token, subject);
    let ws_url = format!(
        "{}/api/station/ws?token={token}",
        server.base.replace("http://", "ws://")
    );
    let (mut ws, _) = tungstenite::connect(ws_url).expect("station socket");
    assert_eq!(
        api.post(&format!("/api/trials/{practice}/start"), json!({}))
            .0,
        200
    );
    // The station floods input as fast as it can (far beyond any display's rate).
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let count = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let flooding = {
        let (stop, count) = (std::sync::Arc::clone(&stop), std::sync::Arc::clone(&count));
        std::thread::spawn(move || {
            let mut seq = 0u64;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) && seq < 2_000_000 {
                seq += 1;
                count.store(seq, std::sync::atomic::Ordering::Relaxed);
                let msg = json!({ "type": "input", "trial_id": practice, "seq": seq, "position_mm": 5.0 });
                if ws
                    .send(tungstenite::Message::Text(msg.to_string().into()))
                    .is_err()
                {
                    break;
                }
            }
            seq
        })
    };
    // Let the flood build up, then stop the machine.
    eventually(Duration::from_secs(20), || {
        let (_, d) = api.get(&format!("/api/subjects/{subject}"));
        (d["trials"][0]["trial"]["status"] == "running").then_some(())
    });
    eventually(Duration::from_secs(20), || {
        (count.load(std::sync::atomic::Ordering::Relaxed) > 5000).then_some(())
    });
    // 200 means the controller confirmed it (the server's limit is 500 ms); on its own
    // connection it takes far less.
    let (code, body) = api.post("/api/estop", json!({}));
    assert_eq!(code, 200, "the controller confirmed the E-stop: {body}");
    let confirmed_ms = body["confirmed_ms"].as_f64().unwrap();
    assert!(
        confirmed_ms <= 10.0,
        "the E-stop was confirmed {confirmed_ms} ms after the request"
    );
    let row = eventually(Duration::from_secs(10), || {
        let (_, d) = api.get(&format!("/api/subjects/{subject}"));
        let t = d["trials"][0]["trial"].clone();
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(row["status"], "aborted", "{row}");
    assert!(
        row["status_reason"].as_str().unwrap().contains("e-stop"),
        "{row}"
    );
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let sent = flooding.join().unwrap();
    assert!(sent > 1000, "the station flooded ({sent} messages)");
    let (_, audit) = api.get("/api/audit?limit=50");
    let estop = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["action"] == "estop")
        .expect("audited");
    assert_eq!(estop["detail"]["delivered"], true);
}

#[test]
fn a_pilot_never_writes_into_a_study_with_people() {
    let server = Server::start("layers-dry-run");
    let api = server.experimenter();
    let study = short_study(&api, 1.0, 0.3);
    let person = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    // A synthetic subject cannot join a study for people, nor a person a dry run.
    let (code, body) = api.post(
        &format!("/api/studies/{study}/subjects"),
        json!({ "synthetic": true }),
    );
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("dry-run copy"),
        "{body}"
    );
    // The dashboard's pilot of the study runs in its dry-run copy.
    let status = run_pilot(&api, study, 2);
    let copy = status["report"]["study_id"]
        .as_i64()
        .expect("the pilot ran");
    assert_ne!(copy, study, "{status}");
    let (_, info) = api.get(&format!("/api/studies/{copy}/dry-run"));
    assert_eq!(info["dry_run"], true);
    assert_eq!(info["copy_of"], study);
    let (_, original) = api.get(&format!("/api/studies/{study}/dry-run"));
    assert_eq!(
        (
            original["dry_run"].clone(),
            original["dry_run_copy"].as_i64()
        ),
        (json!(false), Some(copy))
    );
    let (code, body) = api.post(&format!("/api/studies/{copy}/subjects"), json!({}));
    assert_eq!(code, 409, "{body}");
    // The study with a person holds that person only, in its pages and its exports.
    let (_, subjects) = api.get(&format!("/api/studies/{study}/subjects"));
    let subjects = subjects.as_array().unwrap();
    assert_eq!(subjects.len(), 1, "{subjects:?}");
    assert_eq!(subjects[0]["subject"]["id"], person["subject"]["id"]);
    let (code, csv) = api.get_text(&format!("/api/studies/{study}/export/trials"));
    assert_eq!(code, 200);
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let synthetic = header.iter().position(|h| *h == "synthetic").unwrap();
    assert!(
        csv.lines()
            .skip(1)
            .all(|l| l.split(',').nth(synthetic) == Some("0")),
        "{csv}"
    );
    let (_, pilots) = api.get(&format!("/api/studies/{copy}/subjects"));
    assert_eq!(pilots.as_array().unwrap().len(), 2);
    let actions = audit_actions(&api);
    assert!(actions.iter().any(|a| a == "study.dry_run"), "{actions:?}");
}
