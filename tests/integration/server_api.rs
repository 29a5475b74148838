//! The experiment server end to end: real server process, real controller process, real
//! SQLite file, real sockets.

use std::time::{Duration, Instant};

use bdft_tests::controller_link::Proc;
use bdft_tests::server::{
    Api, Server, assigned_station, dry_run, eventually, pair_station, run_trial, short_study,
    wait_latched,
};
use bdft_tests::{TempDir, server_command, server_output};
use serde_json::{Value, json};

fn csv(text: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .expect("header")
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

fn col(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}"))
}

/// Enrols a subject, pairs a station serving both sides, assigns and consents.
fn ready_subject(api: &Api, study: i64, synthetic: bool) -> (i64, Api) {
    let enrolled = api.ok(
        &format!("/api/studies/{study}/subjects"),
        json!({ "synthetic": synthetic }),
    );
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let (_, token) = assigned_station(api, study, subject);
    let st = Api::with_bearer(&api.base, &token);
    let (_, state) = st.get("/api/station/state");
    assert_eq!(state["phase"], "consent", "{state}");
    assert!(
        state["consent"]["text"]
            .as_str()
            .unwrap()
            .contains("vibration")
    );
    (subject, st)
}

#[test]
fn a_subject_goes_through_the_whole_protocol_via_the_api() {
    let server = Server::start("protocol");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 1.0, 0.5));
    let (subject, station) = ready_subject(&api, study, true);
    // Nothing runs without consent.
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let first = s["trials"][0]["trial"]["id"].as_i64().unwrap();
    let (code, body) = api.post(&format!("/api/trials/{first}/start"), json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(body["error"].as_str().unwrap().contains("consent"));
    station.ok("/api/station/consent", json!({ "decision": "agreed" }));
    // The protocol is locked now and its hash is on every trial.
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    let hash = st["protocol_hash"].as_str().unwrap().to_string();
    let (code, _) = api.call(
        "PUT",
        &format!("/api/studies/{study}"),
        Some(json!({ "name": "changed", "params": st["params"], "version": st["version"] })),
    );
    assert_eq!(code, 409);

    let mut surveys = 0;
    let mut tests = 0;
    let mut first_survey = true;
    loop {
        let (_, state) = station.get("/api/station/state");
        match state["phase"].as_str().unwrap() {
            "ready" => {
                let t = state["test"]["trial_id"].as_i64().unwrap();
                assert!(
                    state["test"]["label"]
                        .as_str()
                        .unwrap()
                        .starts_with("Controller ")
                        || state["test"]["phase"] == "practice"
                );
                let row = run_trial(&api, subject, t);
                assert_eq!(row["status"], "complete", "{row}");
                assert_eq!(row["protocol_hash"], hash.as_str());
                tests += 1;
            }
            "survey" => {
                let t = state["trial_id"].as_i64().unwrap();
                assert_eq!(state["survey"]["scale_points"], 7);
                if first_survey {
                    first_survey = false;
                    // A bad submission: 422, every bad field named, nothing stored.
                    let (code, body) = station.post("/api/station/survey", json!({ "trial_id": t, "accuracy": 9, "speed": 3, "smoothness": null, "controllability": 0, "comment": "x".repeat(2001) }));
                    assert_eq!(code, 422, "{body}");
                    let fields: Vec<&str> = body["fields"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|f| f["field"].as_str().unwrap())
                        .collect();
                    assert_eq!(
                        fields,
                        ["accuracy", "smoothness", "controllability", "comment"]
                    );
                    let (_, again) = station.get("/api/station/state");
                    assert_eq!(again["phase"], "survey", "nothing was stored");
                }
                station.ok("/api/station/survey", json!({ "trial_id": t, "accuracy": 5, "speed": 4, "smoothness": 3, "controllability": 6, "comment": "=cmd|' /C calc'!A0" }));
                surveys += 1;
            }
            "done" => break,
            other => panic!("unexpected phase {other}: {state}"),
        }
    }
    assert_eq!((tests, surveys), (11, 10));

    // The trials export: 11 rows, practice flagged, ratings and the neutralized comment.
    let (code, text) = api.get_text(&format!("/api/studies/{study}/export/trials"));
    assert_eq!(code, 200);
    let (h, rows) = csv(&text);
    assert_eq!(rows.len(), 11);
    for r in &rows {
        assert_eq!(r[col(&h, "status")], "complete");
        assert_eq!(r[col(&h, "protocol_hash")], hash);
        let practice = r[col(&h, "phase")] == "practice";
        assert_eq!(r[col(&h, "rating_accuracy_1to7")].is_empty(), practice);
        if !practice {
            assert_eq!(r[col(&h, "rating_controllability_1to7")], "6");
            assert!(
                r[col(&h, "comment")].starts_with("'="),
                "formula neutralized: {}",
                r[col(&h, "comment")]
            );
        }
    }
    // Samples: the 1 kHz record of every test (0.5 s practice + 10 × 1 s).
    let (_, text) = api.get_text(&format!("/api/studies/{study}/export/samples"));
    let (h, rows) = csv(&text);
    assert_eq!(rows.len(), 500 + 10 * 1000);
    assert!(
        rows.iter()
            .all(|r| r[col(&h, "valve_cmd")].parse::<f64>().unwrap().abs() <= 10.0)
    );
    // Summary: n = 1 per controller × station for this one subject.
    let (_, summary) = api.get(&format!("/api/studies/{study}/summary"));
    let stats = summary.as_array().unwrap();
    assert_eq!(
        stats
            .iter()
            .filter(|s| s["variable"] == "mse_tracking_mm2")
            .count(),
        10
    );
    assert!(stats.iter().all(|s| s["n"] == 1));
    // The e-stop latches on the controller, the dashboard sees it, and it clears on reset.
    api.ok("/api/estop", json!({}));
    wait_latched(&api, true);
    api.ok("/api/estop/reset", json!({}));
    wait_latched(&api, false);
    // Every experimenter action is in the audit log.
    let (_, audit) = api.get("/api/audit?limit=1000");
    let actions: Vec<&str> = audit
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["action"].as_str().unwrap())
        .collect();
    for a in [
        "login",
        "study.create",
        "subject.enrol",
        "station.pair",
        "station.assign",
        "consent",
        "trial.start",
        "export",
    ] {
        assert!(actions.contains(&a), "{a} missing from {actions:?}");
    }
}

#[test]
fn tokens_never_open_experimenter_routes_and_bad_input_gets_4xx() {
    let server = Server::start("auth");
    let api = server.experimenter();
    let study = short_study(&api, 1.0, 0.5);
    let enrolled = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject_token = enrolled["subject_token"].as_str().unwrap().to_string();
    let (_, station_token) = pair_station(&api, study, "on");
    let subject = Api::with_bearer(&server.base, &subject_token);
    let station = Api::with_bearer(&server.base, &station_token);
    let anon = Api::anonymous(&server.base);
    // The OpenAPI document is generated from the routers the server runs, so walking it
    // walks every experimenter route there is.
    let (code, doc) = anon.get("/api/openapi.json");
    assert_eq!(code, 200);
    let mut walked = 0;
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            if op["security"][0].get("session").is_none() || path.contains("live") {
                continue;
            }
            walked += 1;
            let path = path
                .replace("{id}", "1")
                .replace("{kind}", "trials")
                .replace("{file}", "mse_tracking_mm2.svg");
            for (who, client) in [
                ("subject", &subject),
                ("station", &station),
                ("anonymous", &anon),
            ] {
                let (code, body) = client.call(
                    &method.to_uppercase(),
                    &path,
                    if method == "get" {
                        None
                    } else {
                        Some(json!({}))
                    },
                );
                assert_eq!(code, 401, "{who} token on {method} {path}: {body}");
            }
        }
    }
    assert!(
        walked >= 25,
        "only {walked} experimenter operations documented"
    );
    // Tokens work where they belong, and only there.
    assert_eq!(subject.get("/api/subject").0, 200);
    assert_eq!(station.get("/api/subject").0, 401);
    assert_eq!(subject.get("/api/station/state").0, 401);
    // State changes need the CSRF token.
    let mut no_csrf = server.experimenter();
    no_csrf.csrf = None;
    let (code, _) = no_csrf.post("/api/studies", json!({ "name": "x" }));
    assert_eq!(code, 403);
    // Bad input: clear 4xx JSON errors, never a 500.
    let (code, body) = api.post(
        "/api/studies",
        json!({ "name": "x", "params": { "k_bf": "high" } }),
    );
    assert_eq!(code, 422, "{body}");
    assert!(body["error"].is_string());
    let (_, mut params) = api.get("/api/defaults");
    params["target_std_mm"] = json!(400.0);
    let (code, body) = api.post("/api/studies", json!({ "name": "x", "params": params }));
    assert_eq!(code, 422);
    assert!(
        body["error"].as_str().unwrap().contains("target_std_mm"),
        "{body}"
    );
    // An oversized body is refused with 413. The server may answer before the client has
    // sent it all, so write it on a raw socket and read the answer whatever the write did.
    let big = json!({ "name": "y".repeat(400_000) }).to_string();
    let addr = server.base.trim_start_matches("http://").to_string();
    let mut sock = std::net::TcpStream::connect(&addr).unwrap();
    sock.set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    let head = format!(
        "POST /api/studies HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nX-CSRF-Token: {}\r\nCookie: {}\r\nConnection: close\r\n\r\n",
        big.len(),
        api.csrf.as_deref().unwrap(),
        api.cookie_header()
    );
    use std::io::{Read, Write};
    let _ = sock
        .write_all(head.as_bytes())
        .and_then(|_| sock.write_all(big.as_bytes()));
    let mut answer = String::new();
    let _ = sock.read_to_string(&mut answer);
    assert!(
        answer.starts_with("HTTP/1.1 413"),
        "{}",
        &answer[..answer.len().min(200)]
    );
    assert_eq!(api.get("/api/studies/999").0, 404);
    assert_eq!(api.post("/api/trials/999999/start", json!({})).0, 404);
    assert_eq!(api.get("/api/no/such/route").0, 404);
    // The set-up link cannot be used once an account exists.
    let (code, _) = anon.post(
        "/api/setup",
        json!({ "token": "x", "username": "mallory", "password": "0123456789ab" }),
    );
    assert_eq!(code, 409);
    // Login is rate-limited.
    let mut last = 0;
    for _ in 0..7 {
        last = anon
            .post(
                "/api/login",
                json!({ "username": "admin", "password": "wrong" }),
            )
            .0;
    }
    assert_eq!(last, 429);
    // A study declared for the real machine is refused by a simulating controller.
    let (_, mut params) = api.get("/api/defaults");
    params["rig"] = json!("real");
    let real = api.ok(
        "/api/studies",
        json!({ "name": "real machine", "params": params }),
    )["id"]
        .as_i64()
        .unwrap();
    let enrolled = api.ok(&format!("/api/studies/{real}/subjects"), json!({}));
    let (_, st_token) = assigned_station(&api, real, enrolled["subject"]["id"].as_i64().unwrap());
    Api::with_bearer(&server.base, &st_token)
        .ok("/api/station/consent", json!({ "decision": "agreed" }));
    let (_, s) = api.get(&format!("/api/subjects/{}", enrolled["subject"]["id"]));
    let t = s["trials"][0]["trial"]["id"].as_i64().unwrap();
    eventually(Duration::from_secs(20), || {
        (api.get("/api/controller").1["connected"] == true).then_some(())
    });
    let (code, body) = api.post(&format!("/api/trials/{t}/start"), json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("real rig"),
        "{body}"
    );
    // The OpenAPI document lists the routes.
    let (code, doc) = anon.get("/api/openapi.json");
    assert_eq!(code, 200);
    assert!(doc["paths"]["/api/trials/{id}/start"]["post"].is_object());
}

#[test]
fn a_server_killed_mid_trial_restarts_with_the_trial_incomplete_and_the_rest_intact() {
    let mut server = Server::start("crash");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 60.0, 0.5));
    let (subject, station) = ready_subject(&api, study, true);
    station.ok("/api/station/consent", json!({ "decision": "agreed" }));
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let trials: Vec<i64> = s["trials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["trial"]["id"].as_i64().unwrap())
        .collect();
    let practice = run_trial(&api, subject, trials[0]);
    assert_eq!(practice["status"], "complete");
    let (code, _) = api.post(&format!("/api/trials/{}/start", trials[1]), json!({}));
    assert_eq!(code, 200);
    server.crash_and_restart();
    let api = server.experimenter();
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let rows: Vec<&Value> = s["trials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| &t["trial"])
        .collect();
    assert_eq!(rows[0]["status"], "complete");
    assert_eq!(
        rows[0]["mse_tracking_mm2"], practice["mse_tracking_mm2"],
        "completed data intact"
    );
    assert_eq!(rows[1]["status"], "incomplete");
    assert_eq!(rows[1]["status_reason"], "server restart");
    // The subject resumes at the next scheduled test.
    let (_, state) = Api::with_bearer(&server.base, station.bearer.as_deref().unwrap())
        .get("/api/station/state");
    assert_eq!(state["test"]["trial_id"], trials[2], "{state}");
    // The old controller went away with the old server (its stdin closed), and the new
    // one is connected.
    eventually(Duration::from_secs(20), || {
        (api.get("/api/controller").1["connected"] == true).then_some(())
    });
}

#[test]
fn controller_death_is_detected_within_100_ms_and_the_controller_restarts() {
    let server = Server::start("controller-death");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 60.0, 60.0));
    let (subject, station) = ready_subject(&api, study, true);
    station.ok("/api/station/consent", json!({ "decision": "agreed" }));
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let first = s["trials"][0]["trial"]["id"].as_i64().unwrap();
    let pid = eventually(Duration::from_secs(20), || {
        api.get("/api/controller").1["pid"].as_u64()
    });
    assert_eq!(
        api.post(&format!("/api/trials/{first}/start"), json!({})).0,
        200
    );
    let killed_at = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis() as i64;
    let status = std::process::Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let row = eventually(Duration::from_secs(10), || {
        let (_, s) = api.get(&format!("/api/subjects/{subject}"));
        let t = s["trials"][0]["trial"].clone();
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(row["status"], "incomplete");
    assert!(
        row["status_reason"]
            .as_str()
            .unwrap()
            .contains("controller"),
        "{row}"
    );
    let detected = row["finished_at"].as_i64().unwrap() - killed_at;
    assert!(detected <= 100, "detected {detected} ms after the kill");
    // A new controller process comes up and takes trials again.
    let new_pid = eventually(Duration::from_secs(20), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["pid"].as_u64() != Some(pid))
            .then(|| c["pid"].as_u64().unwrap())
    });
    assert_ne!(new_pid, pid);
    api.ok(
        &format!("/api/trials/{first}/redo"),
        json!({ "reason": "controller died" }),
    );
    let (_, audit) = api.get("/api/audit?limit=20");
    let redone = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["action"] == "trial.redo")
        .expect("redo audited");
    assert_eq!(redone["detail"]["reason"], "controller died");
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let redo = s["trials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| &t["trial"])
        .find(|t| t["slot"] == 0 && t["attempt"] == 2)
        .unwrap()["id"]
        .as_i64()
        .unwrap();
    assert_eq!(
        api.post(&format!("/api/trials/{redo}/start"), json!({})).0,
        200
    );
    api.ok(
        &format!("/api/trials/{redo}/abort"),
        json!({ "reason": "test over" }),
    );
    let row = eventually(Duration::from_secs(10), || {
        let (_, s) = api.get(&format!("/api/subjects/{subject}"));
        let t = s["trials"]
            .as_array()?
            .iter()
            .map(|t| &t["trial"])
            .find(|t| t["id"] == redo)?
            .clone();
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(row["status"], "aborted");
    assert_eq!(row["status_reason"], "test over");
}

#[test]
fn a_person_drives_a_test_through_the_station_socket() {
    let server = Server::start("person");
    let api = server.experimenter();
    // The stale-input limit (its own tests are in controller_trials) is widened here: this
    // test drives input from a test thread, which a loaded 2-core machine can stall for
    // longer than 100 ms while browsers and other servers run beside it.
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(1.5);
    params["practice_s"] = json!(0.0);
    params["step_interval_s"] = json!(0.5);
    params["stale_input_ms"] = json!(2000.0);
    let study = api.ok(
        "/api/studies",
        json!({ "name": "person", "params": params, "seed": 42 }),
    )["id"]
        .as_i64()
        .unwrap();
    let (subject, station) = ready_subject(&api, study, false);
    station.ok("/api/station/consent", json!({ "decision": "agreed" }));
    let (_, state) = station.get("/api/station/state");
    let trial = state["test"]["trial_id"].as_i64().unwrap();
    let token = station.bearer.clone().unwrap();
    let ws_url = format!(
        "{}/api/station/ws?token={token}",
        server.base.replace("http://", "ws://")
    );
    let (mut ws, _) = tungstenite::connect(ws_url).expect("station socket");
    match ws.get_mut() {
        tungstenite::stream::MaybeTlsStream::Plain(s) => {
            s.set_read_timeout(Some(Duration::from_millis(5))).unwrap()
        }
        _ => unreachable!(),
    }
    assert_eq!(
        api.post(&format!("/api/trials/{trial}/start"), json!({})).0,
        200
    );
    // Stream input at about 200 Hz as a page does, collecting live samples meanwhile; the
    // test's end is watched from another thread, so a slow API answer never pauses the
    // input (the controller stops a test whose input pauses for 100 ms).
    let ended = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let poller = {
        let (ended, watcher) = (std::sync::Arc::clone(&ended), server.experimenter());
        std::thread::spawn(move || {
            let started = Instant::now();
            while started.elapsed() < Duration::from_secs(60) {
                let (code, s) = watcher.get(&format!("/api/subjects/{subject}"));
                if code == 200 && s["trials"][0]["trial"]["status"] != "running" {
                    ended.store(true, std::sync::atomic::Ordering::Relaxed);
                    return;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };
    let start = Instant::now();
    let mut seq = 0u64;
    let mut live = Vec::new();
    while start.elapsed() < Duration::from_secs(60) {
        seq += 1;
        let msg = json!({ "type": "input", "trial_id": trial, "seq": seq, "position_mm": 12.5 })
            .to_string();
        if ws.send(tungstenite::Message::Text(msg.into())).is_err() {
            break;
        }
        // Input for another trial is dropped by the server.
        let _ = ws.send(tungstenite::Message::Text(
            json!({ "type": "input", "trial_id": trial + 1, "seq": seq, "position_mm": -500.0 })
                .to_string()
                .into(),
        ));
        while let Ok(tungstenite::Message::Text(t)) = ws.read() {
            let v: Value = serde_json::from_str(&t).unwrap();
            if v["type"] == "live" {
                live.push(v["sample"].clone());
            }
        }
        if ended.load(std::sync::atomic::Ordering::Relaxed) && live.len() > 10 {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    poller.join().unwrap();
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    assert_eq!(
        s["trials"][0]["trial"]["status"], "complete",
        "{}",
        s["trials"][0]
    );
    assert!(live.len() > 50, "live samples at ~100 Hz: {}", live.len());
    assert!(
        live.iter().any(|l| l["input_seq"].as_u64().unwrap() > 0),
        "input round trip visible"
    );
    // A person's next test cannot start while this test's survey is unanswered.
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let next = s["trials"][1]["trial"]["id"].as_i64().unwrap();
    let (code, body) = api.post(&format!("/api/trials/{next}/start"), json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(body["error"].as_str().unwrap().contains("survey"), "{body}");
    // The record shows our hand position and never the other trial's.
    let (_, text) = api.get_text(&format!("/api/studies/{study}/export/samples"));
    let (h, rows) = csv(&text);
    let hand = col(&h, "hand_mm");
    assert!(
        rows.iter().all(|r| r[hand] == "0" || r[hand] == "12.5"),
        "only our input drove the test"
    );
    assert!(rows.iter().filter(|r| r[hand] == "12.5").count() > 1000);
}

#[test]
fn a_pilot_of_two_subjects_checked_row_by_row() {
    let dir = TempDir::new("pilot");
    let db = dir.path().join("pilot.db");
    let db = db.to_str().unwrap();
    let out = server_command(["pilot", "--db", db, "--subjects", "2", "--seed", "7"]);
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["trials"], 22);
    assert_eq!(report["complete"], 22);
    let csv_path = dir.path().join("trials.csv");
    server_command([
        "export",
        "--db",
        db,
        "--kind",
        "trials",
        "--out",
        csv_path.to_str().unwrap(),
    ]);
    let (h, rows) = csv(&std::fs::read_to_string(&csv_path).unwrap());
    for c in [
        "subject_code",
        "subject_index",
        "synthetic",
        "starting_station",
        "station",
        "block",
        "position",
        "controller",
        "blinded_label",
        "phase",
        "status",
        "seed",
        "target_mean_mm",
        "target_std_mm",
        "mse_tracking_mm2",
        "ms_cab_accel_mm2_s4",
        "rating_accuracy_1to7",
        "rating_speed_1to7",
        "rating_smoothness_1to7",
        "rating_controllability_1to7",
        "comment",
        "protocol_hash",
        "started_at",
        "finished_at",
    ] {
        col(&h, c);
    }
    assert_eq!(
        h[h.len() - 12..],
        [
            "starting_seat",
            "seat",
            "compensator",
            "cancellation",
            "cancellation_off_at_s",
            "condition",
            "adapt_f_hz",
            "adapt_confident_since_s",
            "adapt_ratio",
            "adapt_retunes",
            "adapt_fallbacks",
            "adapt_confident"
        ],
        "the clear names come last, then the columns added after them"
    );
    assert_eq!(rows.len(), 22);
    let params = bdft_server::engine::study::schedule::default_params();
    let hash = bdft_server::engine::study::schedule::protocol_hash(&params);
    let get = |r: &Vec<String>, c: &str| r[col(&h, c)].clone();
    for (i, code) in ["S01", "S02"].iter().enumerate() {
        let mine: Vec<&Vec<String>> = rows
            .iter()
            .filter(|r| get(r, "subject_code") == *code)
            .collect();
        assert_eq!(mine.len(), 11);
        let start = if i == 0 { "on" } else { "off" };
        // The schedule is the one the protocol engine regenerates from the study seed.
        let schedule = bdft_server::engine::study::schedule::schedule(&params, 7, i as u32);
        for (r, t) in mine.iter().zip(&schedule) {
            assert_eq!(get(r, "subject_index"), (i + 1).to_string());
            assert_eq!(get(r, "synthetic"), "1");
            assert_eq!(get(r, "starting_station"), start);
            assert_eq!(get(r, "station"), t.seat.as_str());
            // Practice has no compensator, block or position: no row reads as a PID test.
            let test_only = |v: String| if t.phase.scored() { v } else { String::new() };
            assert_eq!(get(r, "controller"), test_only(t.compensator.name().into()));
            // The clear names, last, beside the old ones kept for a release: the same values.
            for (clear, old) in [
                ("starting_seat", "starting_station"),
                ("seat", "station"),
                ("compensator", "controller"),
            ] {
                assert_eq!(get(r, clear), get(r, old), "{clear}");
            }
            assert_eq!(get(r, "blinded_label"), test_only(t.blinded_label.clone()));
            assert_eq!(get(r, "block"), test_only(t.block.to_string()));
            assert_eq!(get(r, "position"), test_only(t.position.to_string()));
            assert_eq!(get(r, "phase"), t.phase.as_str());
            assert_eq!(get(r, "seed"), t.target_seed.to_string());
            assert_eq!(get(r, "status"), "complete");
            assert_eq!(get(r, "protocol_hash"), hash);
            let mean: f64 = get(r, "target_mean_mm").parse().unwrap();
            let std: f64 = get(r, "target_std_mm").parse().unwrap();
            // The default target: 12 mm (docs/synthetic-subjects.md, the model card).
            assert!(mean.abs() <= 1.0 && (std / 12.0 - 1.0).abs() <= 0.05);
            let mse: f64 = get(r, "mse_tracking_mm2").parse().unwrap();
            assert!(mse > 0.0 && mse < 2000.0, "{mse}");
            // Each synthetic subject answers the survey of every scored test on the
            // study's 7-point scale, as a person would; the practice has none.
            if !t.phase.scored() {
                assert!(get(r, "rating_accuracy_1to7").is_empty() && get(r, "comment").is_empty());
            } else {
                for item in ["accuracy", "speed", "smoothness", "controllability"] {
                    let rating: u8 = get(r, &format!("rating_{item}_1to7")).parse().unwrap();
                    assert!((1..=7).contains(&rating), "{item}: {rating}");
                }
                assert!(
                    get(r, "comment").starts_with("(synthetic)"),
                    "{}",
                    get(r, "comment")
                );
            }
            assert!(
                get(r, "started_at") <= get(r, "finished_at"),
                "{} > {}",
                get(r, "started_at"),
                get(r, "finished_at")
            );
        }
        assert_eq!(
            mine[1..6]
                .iter()
                .filter(|r| get(r, "station") == start)
                .count(),
            5
        );
    }
    // The summary has one line per controller × station × variable with n = 2.
    let sum_path = dir.path().join("summary.csv");
    server_command([
        "export",
        "--db",
        db,
        "--kind",
        "summary",
        "--out",
        sum_path.to_str().unwrap(),
    ]);
    let (sh, srows) = csv(&std::fs::read_to_string(&sum_path).unwrap());
    let metric_rows: Vec<_> = srows
        .iter()
        .filter(|r| r[col(&sh, "variable")] == "mse_tracking_mm2")
        .collect();
    assert_eq!(metric_rows.len(), 10);
    assert!(metric_rows.iter().all(|r| r[col(&sh, "n")] == "2"));
    assert!(
        srows
            .iter()
            .all(|r| r[col(&sh, "compensator")] == r[col(&sh, "controller")]
                && r[col(&sh, "seat")] == r[col(&sh, "station")])
    );
    // A bad export kind is refused with the valid ones named.
    let out = server_output([
        "export",
        "--db",
        db,
        "--kind",
        "everything",
        "--out",
        "/dev/null",
    ]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("trials, samples, subjects, codebook, summary")
    );
    let _ = Proc::controller; // the pilot needs no controller process
}

/// Every parameter the OpenAPI document lists is where the server reads it: a path
/// parameter is a `{name}` of its path (`site` and `k_bf` are query parameters), and an
/// address or query that does not parse is answered with the documented JSON error, never
/// axum's plain text.
#[test]
fn the_documented_parameters_are_where_they_are_read_and_bad_ones_get_the_json_error() {
    let server = Server::start("api-params");
    let api = server.experimenter();
    let (code, doc) = api.get("/api/openapi.json");
    assert_eq!(code, 200);
    let param = |path: &str, method: &str, name: &str| -> Value {
        doc["paths"][path][method]["parameters"]
            .as_array()
            .and_then(|ps| ps.iter().find(|p| p["name"] == name).cloned())
            .unwrap_or_else(|| panic!("{method} {path} lists no parameter {name}"))
    };
    assert_eq!(param("/api/estop/reset", "post", "site")["in"], "query");
    assert_eq!(param("/api/estop", "post", "site")["in"], "query");
    assert_eq!(
        param("/api/subjects/{id}/stability", "get", "k_bf")["in"],
        "query"
    );
    let mut misplaced = Vec::new();
    let mut with_id = Vec::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            for p in op["parameters"].as_array().into_iter().flatten() {
                let name = p["name"].as_str().unwrap();
                let in_path = path.contains(&format!("{{{name}}}"));
                if (p["in"] == "path") != in_path {
                    misplaced.push(format!("{method} {path}: {name} in {}", p["in"]));
                }
            }
            if path.contains("{id}") {
                with_id.push((method.to_uppercase(), path.clone()));
            }
        }
    }
    assert!(misplaced.is_empty(), "{misplaced:#?}");

    // An id that is no number, on every route with one: the JSON error.
    assert!(with_id.len() > 30, "{with_id:?}");
    for (method, path) in &with_id {
        let path = path
            .replace("{id}", "abc")
            .replace("{kind}", "trials")
            .replace("{file}", "mse_tracking_mm2.svg");
        // No body: the address is refused before one would be read, and a body left unread
        // would cost the pooled connection.
        let (code, answer) = api.call(method, &path, None);
        assert!(
            (400..500).contains(&code) && answer["error"].is_string(),
            "{method} {path}: {code} {answer}"
        );
    }
    let (code, e) = api.get("/api/studies/abc");
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().contains("abc"), "{e}");
    // A query that does not parse: the JSON error naming the field.
    let study = short_study(&api, 1.0, 0.5);
    for path in [
        "/api/audit?limit=abc".to_string(),
        "/api/subjects/1/stability?k_bf=abc".to_string(),
        format!("/api/studies/{study}/export/trials?format=abc"),
        format!("/api/studies/{study}/workbench/frequency?subject=abc"),
    ] {
        let (code, e) = api.get(&path);
        assert_eq!(code, 422, "{path}: {e}");
        assert!(e["error"].is_string(), "{path}: {e}");
    }
    let (code, e) = api.post("/api/estop/reset?site=1&site=2", json!({}));
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].is_string(), "{e}");
}

/// Names (a study's, a station's, a configuration version's, an account's) are counted in
/// characters, as their messages say, and refuse what would make them read or export other
/// than they are: control characters and bidirectional marks, overrides and isolates.
#[test]
fn names_count_characters_and_refuse_controls_and_bidirectional_overrides() {
    let server = Server::start("api-names");
    let api = server.experimenter();
    let (_, params) = api.get("/api/defaults");
    let study = |name: &str| api.post("/api/studies", json!({ "name": name, "params": params }));
    // 200 characters of two bytes each: a name; 201: too long, by characters.
    let (code, s) = study(&"é".repeat(200));
    assert_eq!(code, 200, "{s}");
    assert_eq!(s["name"].as_str().unwrap().chars().count(), 200);
    let (code, e) = study(&"é".repeat(201));
    assert_eq!(code, 422, "{e}");
    assert!(
        e["error"].as_str().unwrap().contains("200 characters"),
        "{e}"
    );
    for (name, says) in [
        ("nul\u{0}here", "U+0000"),
        ("two\nlines", "U+000A"),
        ("carriage\rreturn", "U+000D"),
        ("tab\there", "U+0009"),
        ("c1\u{85}next line", "U+0085"),
        ("\u{202E}desrever", "U+202E"),
        ("embedded\u{202A}x", "U+202A"),
        ("isolate\u{2066}x\u{2069}", "U+2066"),
        ("mark\u{200F}", "U+200F"),
        ("mark\u{200E}", "U+200E"),
    ] {
        let (code, e) = study(name);
        assert_eq!(code, 422, "{name:?}: {e}");
        let e = e["error"].as_str().unwrap();
        assert!(e.starts_with("name: ") && e.contains(says), "{name:?}: {e}");
        assert!(
            e.contains("control characters") && e.contains("bidirectional"),
            "{e}"
        );
    }
    let (code, _) = study("Ünïcode is fine — 試験 ✓");
    assert_eq!(code, 200);
    let id = s["id"].as_i64().unwrap();
    // A station's name and a configuration version's are the same kind of name.
    let reg = Api::anonymous(&api.base).ok("/api/station/register", json!({}));
    let (code, e) = api.post(
        &format!("/api/studies/{id}/stations"),
        json!({ "pairing_code": reg["pairing_code"], "name": "desk\u{202E}1", "role": "on" }),
    );
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().contains("U+202E"), "{e}");
    let spec = params["controllers"][0].clone();
    let (code, e) = api.post("/api/configs", json!({ "name": "tuned\r\n", "spec": spec }));
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().contains("U+000D"), "{e}");
    // A username keeps its own stricter characters, with the same checks first.
    let (code, e) = api.post(
        "/api/accounts",
        json!({ "username": "bob\u{0}", "password": "0123456789ab", "role": "analyst" }),
    );
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().contains("U+0000"), "{e}");
}
