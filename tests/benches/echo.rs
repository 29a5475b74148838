//! Input-to-echo latency: a station sends operator input over its WebSocket at a fixed rate
//! and waits for the live sample that carries it back (`input_seq` ≥ the input's `seq`), on
//! the real server and controller processes over loopback. The echo passes the server (socket
//! → controller link), the controller's 1 kHz loop and its live samples (100 Hz) back through
//! the server to the socket. Prints p50/p95/max per input rate as JSON.
//!
//! Run: `cargo build --workspace --bins && cargo bench --profile dev -p bdft-tests --bench echo`
//! (`--release` builds and `cargo bench` without `--profile` for optimized figures; env
//! RATES=60,250 and SECONDS=10 change the load).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use bdft_tests::server::{Api, Server, person_at_a_station, short_study};
use serde_json::{Value, json};
use tungstenite::Message;

fn env<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let rates: Vec<f64> = std::env::var("RATES")
        .unwrap_or_else(|_| "60,250".into())
        .split(',')
        .filter_map(|r| r.trim().parse().ok())
        .collect();
    let seconds: f64 = env("SECONDS", 10.0);
    let server = Server::start("bench-echo");
    let api = server.experimenter();
    let study = short_study(&api, seconds + 2.0, seconds + 2.0);
    let mut report = Vec::new();
    for rate in rates {
        let mut latencies = echo_latencies(&server, &api, study, rate, seconds);
        latencies.sort_by(f64::total_cmp);
        let q =
            |p: f64| latencies[((latencies.len() as f64 * p) as usize).min(latencies.len() - 1)];
        report.push(json!({
            "input_hz": rate,
            "echoes": latencies.len(),
            "echo_ms": { "p50": q(0.5), "p95": q(0.95), "max": q(1.0) },
        }));
    }
    println!("{}", json!({ "seconds": seconds, "rates": report }));
}

/// One subject's test at a station of its own, input at `rate` Hz for `seconds`: the echo
/// latency of every input (ms).
fn echo_latencies(server: &Server, api: &Api, study: i64, rate: f64, seconds: f64) -> Vec<f64> {
    let (_, _, token) = person_at_a_station(server, api, study);
    let me = Api::with_bearer(&server.base, &token);
    let (_, state) = me.get("/api/station/state");
    let trial = state["test"]["trial_id"].as_i64().unwrap();
    let url = format!(
        "{}/api/station/ws?token={token}",
        server.base.replace("http://", "ws://")
    );
    let (mut ws, _) = tungstenite::connect(url).unwrap();
    if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_mut() {
        // Short reads, so that sends keep their schedule; 0.2 ms is the timing's resolution.
        s.set_read_timeout(Some(Duration::from_micros(200)))
            .unwrap();
        s.set_nodelay(true).unwrap();
    }
    api.ok(&format!("/api/trials/{trial}/start"), json!({}));
    let period = Duration::from_secs_f64(1.0 / rate);
    let (mut seq, mut pending) = (0u64, VecDeque::<(u64, Instant)>::new());
    let mut latencies = Vec::new();
    let mut started: Option<Instant> = None;
    let mut next = Instant::now();
    // The display's health, as a visible page reports it (the server stops a test whose
    // display goes silent).
    let mut last_display: Option<Instant> = None;
    loop {
        if last_display.is_none_or(|t| t.elapsed() >= Duration::from_millis(250)) {
            last_display = Some(Instant::now());
            let m = json!({ "type": "display", "trial_id": trial, "hidden": false,
                "frames": seq, "longest_gap_ms": 17.0, "hidden_ms": 0.0, "inputs": seq });
            ws.send(Message::Text(m.to_string().into())).unwrap();
        }
        if started.is_some_and(|t| t.elapsed() > Duration::from_secs_f64(seconds)) {
            break;
        }
        if Instant::now() >= next {
            seq += 1;
            let m = json!({ "type": "input", "trial_id": trial, "seq": seq, "position_mm": (seq as f64 * 0.05).sin() * 20.0 });
            pending.push_back((seq, Instant::now()));
            ws.send(Message::Text(m.to_string().into())).unwrap();
            next += period;
        }
        match ws.read() {
            Ok(Message::Text(t)) => {
                let now = Instant::now();
                let v: Value = serde_json::from_str(&t).unwrap();
                if v["type"] != "live" {
                    continue;
                }
                let echoed = v["sample"]["input_seq"].as_u64().unwrap_or(0);
                if echoed > 0 && started.is_none() {
                    // The trial runs: count from here, and drop what was sent before it.
                    started = Some(now);
                    pending.retain(|(s, _)| *s > echoed);
                    continue;
                }
                while pending.front().is_some_and(|(s, _)| *s <= echoed) {
                    let (_, sent) = pending.pop_front().unwrap();
                    latencies.push(now.duration_since(sent).as_secs_f64() * 1000.0);
                }
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => panic!("station socket: {e}"),
        }
    }
    let _ = ws.close(None);
    latencies
}
