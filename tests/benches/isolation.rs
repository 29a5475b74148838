//! One station cannot hurt another (issue 20): a victim station feeds its running test at
//! 60 Hz while another station's token floods the server from a process of its own, with 1,
//! 4 and 16 WebSockets each writing operator input as fast as the socket takes it (a closed
//! one is opened again at once). Per flood, on the real server and controller over
//! loopback:
//!
//! - the victim's input-to-echo latency (p50/p95/p99/max) and whether its test was stopped;
//! - the dashboard API's latency meanwhile (`GET /api/stations/{id}/state`, every 20 ms),
//!   and the CPU the server, its controller and the flooder used meanwhile;
//! - then, the flood still running, E-stop presses (`POST /api/estop`, reset between):
//!   the controller's confirmation (`confirmed_ms`) and the answer's time at the client.
//!
//! Prints one JSON object. Run: `cargo build --workspace --bins && cargo bench --profile dev
//! -p bdft-tests --bench isolation` (env SOCKETS=1,4,16, SECONDS=10 and PRESSES=20 change the
//! load). The flooder is this executable again, started with `BDFT_FLOOD` set.

use std::io::{BufRead, Read, Write};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use bdft_tests::server::{Api, Server, eventually, person_at_a_station, short_study, wait_latched};
use bdft_tests::station::{self, summary};
use bdft_tests::{setting, setting_list};
use serde_json::{Value, json};

/// Set (to "BASE TOKEN TRIAL SOCKETS") in the flooder's environment.
const FLOOD: &str = "BDFT_FLOOD";

fn main() {
    if let Ok(spec) = std::env::var(FLOOD) {
        flood(&spec);
        return;
    }
    let floods: Vec<usize> = setting_list("SOCKETS", "1,4,16");
    let seconds: f64 = setting("SECONDS", 10.0);
    let presses: usize = setting("PRESSES", 20);
    let server = Server::start("bench-isolation");
    let api = server.experimenter();
    // Tests long enough to outlast the measurement (they end with the E-stop presses).
    let study = short_study(&api, seconds + 60.0, seconds + 60.0);
    let mut report = Vec::new();
    for sockets in floods {
        report.push(scenario(&server, &api, study, sockets, seconds, presses));
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "{}",
        json!({ "seconds": seconds, "victim_hz": 60, "loadavg": load.trim(), "floods": report })
    );
}

/// Starts `trial` (waiting for a controller restarted under the flood to be back).
fn start(api: &Api, trial: i64) {
    eventually(Duration::from_secs(30), || {
        let (code, body) = api.post(&format!("/api/trials/{trial}/start"), json!({}));
        assert!(code == 200 || code == 503, "start {trial}: {body}");
        (code == 200).then_some(())
    });
}

/// A person's running test at a station: (subject, station, token, trial).
fn running_test(server: &Server, api: &Api, study: i64) -> (i64, i64, String, i64) {
    let (subject, station, token) = person_at_a_station(server, api, study);
    let (_, state) = Api::with_bearer(&server.base, &token).get("/api/station/state");
    let trial = state["test"]["trial_id"].as_i64().unwrap();
    (subject, station, token, trial)
}

fn scenario(
    server: &Server,
    api: &Api,
    study: i64,
    sockets: usize,
    seconds: f64,
    presses: usize,
) -> Value {
    // The flooder's own test runs too, so its input is read as far as a test's input goes.
    let (_, _, flood_token, flood_trial) = running_test(server, api, study);
    start(api, flood_trial);
    let mut flooder = start_flooder(&server.base, &flood_token, flood_trial, sockets);
    // The flood is under way before the victim's test starts.
    std::thread::sleep(Duration::from_secs(1));

    let (subject, station, token, trial) = running_test(server, api, study);
    let mut ws = station::connect(&server.base, &token);
    let controller = api.get("/api/controller").1["pid"].as_u64().unwrap_or(0) as u32;
    let processes = [
        ("server", server.proc.child.id()),
        ("controller", controller),
        ("flooder", flooder.id()),
    ];
    let meter = bdft_tests::CpuMeter::start(&processes);
    let polling = Arc::new(AtomicBool::new(true));
    let poller = {
        // The dashboard's own session and connection.
        let (api, polling) = (server.experimenter(), Arc::clone(&polling));
        std::thread::spawn(move || {
            let (mut took, mut failed) = (Vec::new(), 0u32);
            while polling.load(Ordering::Relaxed) {
                let t = Instant::now();
                let (code, _) = api.get(&format!("/api/stations/{station}/state"));
                took.push(t.elapsed().as_secs_f64() * 1000.0);
                failed += u32::from(code != 200);
                std::thread::sleep(Duration::from_millis(20));
            }
            (took, failed)
        })
    };
    start(api, trial);
    let fed = station::feed(&mut ws, trial, 60.0, seconds);
    let cpu = meter.shares();
    polling.store(false, Ordering::Relaxed);
    let (api_ms, api_failed) = poller.join().unwrap();
    let row = api.get(&format!("/api/subjects/{subject}")).1["trials"][0]["trial"].clone();
    let stopped = (row["status"] != "running")
        .then(|| format!("{}: {}", row["status"], row["status_reason"]));

    // The E-stop, the flood still running (it stops both tests).
    let (mut confirmed, mut answered) = (Vec::new(), Vec::new());
    for _ in 0..presses {
        let t = Instant::now();
        let (code, body) = api.post("/api/estop", json!({}));
        answered.push(t.elapsed().as_secs_f64() * 1000.0);
        if code == 200 {
            confirmed.push(body["confirmed_ms"].as_f64().unwrap());
        } else {
            eprintln!("E-stop not confirmed ({code}): {body}");
        }
        // (A controller restarted meanwhile must be connected again to be reset.)
        eventually(Duration::from_secs(30), || {
            (api.post("/api/estop/reset", json!({})).0 == 200).then_some(())
        });
        wait_latched(api, false);
    }
    let flood = stop_flooder(&mut flooder);
    let _ = ws.close(None);
    json!({
        "flooding_sockets": sockets,
        "flood": flood,
        "victim": {
            "echo_ms": summary(fed.echo_ms),
            "longest_send_gap_ms": (fed.longest_send_gap_ms * 1000.0).round() / 1000.0,
            "socket_ended": fed.ended,
            "test_stopped": stopped,
        },
        "cpu_percent_meanwhile": cpu,
        "api_ms": summary(api_ms),
        "api_failed": api_failed,
        "estop_confirmed_ms": summary(confirmed),
        "estop_answered_ms": summary(answered),
    })
}

fn start_flooder(base: &str, token: &str, trial: i64, sockets: usize) -> Child {
    Command::new(std::env::current_exe().unwrap())
        .env(FLOOD, format!("{base} {token} {trial} {sockets}"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the flooder")
}

/// Ends the flooder (it stops when its stdin closes) and returns what it reported.
fn stop_flooder(child: &mut Child) -> Value {
    drop(child.stdin.take());
    let mut out = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    let _ = child.wait();
    serde_json::from_str(out.trim()).unwrap_or(Value::String(out))
}

/// The flooder: `sockets` threads, each keeping a socket of the station open and writing
/// input for its test as fast as the socket takes it; prints what it sent when its stdin
/// closes.
fn flood(spec: &str) {
    let parts: Vec<&str> = spec.split(' ').collect();
    let [base, token, trial, sockets] = parts[..] else {
        panic!("{FLOOD}: BASE TOKEN TRIAL SOCKETS, got {spec}")
    };
    let trial: i64 = trial.parse().unwrap();
    let sockets: usize = sockets.parse().unwrap();
    let sent = Arc::new(AtomicU64::new(0));
    let opened = Arc::new(AtomicU64::new(0));
    for _ in 0..sockets {
        let (base, token) = (base.to_string(), token.to_string());
        let (sent, opened) = (Arc::clone(&sent), Arc::clone(&opened));
        std::thread::spawn(move || {
            let mut seq = 0u64;
            loop {
                let Ok((mut ws, _)) = tungstenite::connect(station::socket_url(&base, &token))
                else {
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                };
                opened.fetch_add(1, Ordering::Relaxed);
                loop {
                    seq += 1;
                    // Written in batches of 32 frames: as fast as the socket takes them.
                    if ws.write(station::input(trial, seq, 5.0)).is_err()
                        || (seq.is_multiple_of(32) && ws.flush().is_err())
                    {
                        break;
                    }
                    sent.fetch_add(1, Ordering::Relaxed);
                }
            }
        });
    }
    let began = Instant::now();
    let mut stdin = std::io::stdin().lock();
    let mut line = String::new();
    while stdin.read_line(&mut line).is_ok_and(|n| n > 0) {
        line.clear();
    }
    let secs = began.elapsed().as_secs_f64();
    let sent = sent.load(Ordering::Relaxed);
    let report = json!({
        "sockets_opened": opened.load(Ordering::Relaxed),
        "frames_written": sent,
        "frames_per_s": (sent as f64 / secs).round(),
    });
    let mut out = std::io::stdout().lock();
    // (Nobody may be reading any more.)
    let _ = writeln!(out, "{report}").and_then(|()| out.flush());
    std::process::exit(0);
}
