//! Input-to-echo latency: a station sends operator input over its WebSocket at a fixed rate
//! and waits for the live sample that carries it back (`input_seq` ≥ the input's `seq`), on
//! the real server and controller processes over loopback. The echo passes the server (socket
//! → controller link), the controller's 1 kHz loop and its live samples (100 Hz) back through
//! the server to the socket. Prints p50/p95/max per input rate as JSON.
//!
//! Run: `cargo build --workspace --bins && cargo bench --profile dev -p bdft-tests --bench echo`
//! (`--release` builds and `cargo bench` without `--profile` for optimized figures; env
//! RATES=60,250 and SECONDS=10 change the load).

use bdft_tests::server::{Api, Server, person_at_a_station, short_study};
use bdft_tests::station::{self, summary};
use bdft_tests::{setting, setting_list};
use serde_json::json;

fn main() {
    let rates: Vec<f64> = setting_list("RATES", "60,250");
    let seconds: f64 = setting("SECONDS", 10.0);
    let server = Server::start("bench-echo");
    let api = server.experimenter();
    let study = short_study(&api, seconds + 2.0, seconds + 2.0);
    let mut report = Vec::new();
    for rate in rates {
        let latencies = echo_latencies(&server, &api, study, rate, seconds);
        report.push(json!({
            "input_hz": rate,
            "echoes": latencies.len(),
            "echo_ms": summary(latencies),
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
    let mut ws = station::connect(&server.base, &token);
    api.ok(&format!("/api/trials/{trial}/start"), json!({}));
    let fed = station::feed(&mut ws, trial, rate, seconds);
    if let Some(why) = fed.ended {
        panic!("station socket: {why}");
    }
    let _ = ws.close(None);
    fed.echo_ms
}
