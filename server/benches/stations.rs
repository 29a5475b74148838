//! Load benchmark: 16 operator stations at once, each a browser's worth of WebSocket
//! traffic (operator input at 250 Hz in, live samples at 100 Hz out), on the real server and
//! controller processes. Reports controller overruns during the trials and the delivery
//! latency of live samples (controller tick → station socket), from the sample's
//! CLOCK_MONOTONIC stamp.
//!
//! Run: `cargo bench -p bdft-server --bench stations` (env STATIONS, TRIAL_S to change the
//! load; defaults 16 stations, 30 s tests).

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use bdft_controller::runtime::os::now_ns;
use serde_json::{Value, json};

fn main() {
    let stations: usize = std::env::var("STATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(16);
    let trial_s: f64 = std::env::var("TRIAL_S")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(30.0);
    let dir = std::env::temp_dir().join(format!("bdft-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let db = dir.join("bench.db");
    let mut server = Command::new(env!("CARGO_BIN_EXE_bdft-server"))
        .args([
            "serve",
            "--db",
            db.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
            "--admin-password",
            "bench-password-1",
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(server.stdout.take().unwrap()).lines();
    let base = loop {
        let l = lines.next().unwrap().unwrap();
        if let Some(a) = l.strip_prefix("bdft-lab server on ") {
            break a.to_string();
        }
    };
    std::thread::spawn(move || for _ in lines {});
    let agent = ureq::AgentBuilder::new().build();
    let post = |path: &str, csrf: &str, body: Value| -> Value {
        agent
            .post(&format!("{base}{path}"))
            .set("x-csrf-token", csrf)
            .send_json(body)
            .unwrap_or_else(|e| panic!("{path}: {e}"))
            .into_json()
            .unwrap()
    };
    let login: Value = agent
        .post(&format!("{base}/api/login"))
        .send_json(json!({ "username": "admin", "password": "bench-password-1" }))
        .unwrap()
        .into_json()
        .unwrap();
    let csrf = login["csrf"].as_str().unwrap().to_string();
    let mut params: Value = agent
        .get(&format!("{base}/api/defaults"))
        .call()
        .unwrap()
        .into_json()
        .unwrap();
    params["trial_s"] = json!(trial_s);
    params["practice_s"] = json!(0.0);
    let study = post(
        "/api/studies",
        &csrf,
        json!({ "name": "bench", "params": params }),
    )["id"]
        .as_i64()
        .unwrap();
    // Wait for the controller.
    let start = Instant::now();
    while agent
        .get(&format!("{base}/api/health"))
        .call()
        .unwrap()
        .into_json::<Value>()
        .unwrap()["controller_connected"]
        != true
    {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "controller did not connect"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let mut plan = Vec::new();
    for _ in 0..stations {
        let subject = post(&format!("/api/studies/{study}/subjects"), &csrf, json!({}))["subject"]
            ["id"]
            .as_i64()
            .unwrap();
        let reg: Value = agent
            .post(&format!("{base}/api/station/register"))
            .send_json(json!({}))
            .unwrap()
            .into_json()
            .unwrap();
        let token = reg["token"].as_str().unwrap().to_string();
        let st = post(
            &format!("/api/studies/{study}/stations"),
            &csrf,
            json!({ "pairing_code": reg["pairing_code"], "name": "s", "role": "both" }),
        )["id"]
            .as_i64()
            .unwrap();
        post(
            &format!("/api/stations/{st}/assign"),
            &csrf,
            json!({ "subject_id": subject }),
        );
        agent
            .post(&format!("{base}/api/station/consent"))
            .set("authorization", &format!("Bearer {token}"))
            .send_json(json!({ "decision": "agreed" }))
            .unwrap();
        let state: Value = agent
            .get(&format!("{base}/api/station/state"))
            .set("authorization", &format!("Bearer {token}"))
            .call()
            .unwrap()
            .into_json()
            .unwrap();
        plan.push((subject, token, state["test"]["trial_id"].as_i64().unwrap()));
    }
    // One thread per station: a browser's socket.
    let ws_base = base.replace("http://", "ws://");
    let clients: Vec<_> = plan
        .iter()
        .map(|(_, token, trial)| {
            let url = format!("{ws_base}/api/station/ws?token={token}");
            let trial = *trial;
            std::thread::spawn(move || {
                let (mut ws, _) = tungstenite::connect(url).unwrap();
                if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_mut() {
                    s.set_read_timeout(Some(Duration::from_millis(1))).unwrap();
                }
                let mut latencies_us = Vec::new();
                let begin = Instant::now();
                let mut next_input = Instant::now();
                let mut seq = 0u64;
                while begin.elapsed() < Duration::from_secs_f64(trial_s + 5.0) {
                    if Instant::now() >= next_input {
                        seq += 1;
                        let m = json!({ "type": "input", "trial_id": trial, "seq": seq, "position_mm": (seq as f64 * 0.01).sin() * 30.0 });
                        if ws.send(tungstenite::Message::Text(m.to_string().into())).is_err() {
                            break;
                        }
                        next_input += Duration::from_millis(4);
                    }
                    match ws.read() {
                        Ok(tungstenite::Message::Text(t)) => {
                            let now_us = now_ns() / 1000;
                            let v: Value = serde_json::from_str(&t).unwrap();
                            if v["type"] == "live" {
                                latencies_us.push(now_us.saturating_sub(v["sample"]["stamp_us"].as_u64().unwrap()));
                            }
                        }
                        Ok(_) => {}
                        Err(tungstenite::Error::Io(e)) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
                        Err(_) => break,
                    }
                }
                latencies_us
            })
        })
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    for (_, _, trial) in &plan {
        post(&format!("/api/trials/{trial}/start"), &csrf, json!({}));
    }
    let mut latencies: Vec<u64> = clients
        .into_iter()
        .flat_map(|c| c.join().unwrap())
        .collect();
    latencies.sort_unstable();
    let q = |p: f64| {
        latencies[((latencies.len() as f64 * p) as usize).min(latencies.len() - 1)] as f64 / 1000.0
    };
    let (mut overruns, mut complete, mut wake_p99) = (0, 0, 0.0f64);
    for (subject, _, _) in &plan {
        let s: Value = agent
            .get(&format!("{base}/api/subjects/{subject}"))
            .call()
            .unwrap()
            .into_json()
            .unwrap();
        let t = &s["trials"][0]["trial"];
        if t["status"] == "complete" {
            complete += 1;
        }
        if let Some(timing) = t["timing_json"].as_str() {
            let timing: Value = serde_json::from_str(timing).unwrap();
            overruns = overruns.max(timing["overruns"].as_u64().unwrap_or(0));
            wake_p99 = wake_p99.max(timing["wake_latency_us"]["p99"].as_f64().unwrap_or(0.0));
        }
    }
    let report = json!({
        "stations": stations,
        "trial_s": trial_s,
        "complete": complete,
        "controller_overruns": overruns,
        "worst_trial_wake_p99_us": wake_p99,
        "live_samples": latencies.len(),
        "live_delivery_ms": { "p50": q(0.5), "p99": q(0.99), "max": q(1.0) },
    });
    println!("{report}");
    let _ = server.kill();
    let _ = server.wait();
    let _ = std::fs::remove_dir_all(&dir);
}
