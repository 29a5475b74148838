//! Bounded clients (issue 37): one anonymous address floods the server with slow request
//! bodies and with idle connections that reconnect when closed, while a new client from
//! another address logs in and calls the API and the experimenter presses the E-stop.
//!
//! The flood comes from 127.0.0.2 (its sockets bound there before connecting: another
//! client as the server's per-address limits see it), from a process of its own on one
//! thread: `SLOW` connections (600) each announcing a 100,000-byte login body and sending a
//! byte a second, and `IDLE` connections (2,000) that say nothing; every one of them opens
//! a new connection as soon as the server answers or closes it. Measured, first without the
//! flood and then with it, on the real server and controller over loopback:
//!
//! - a new client's login (`POST /api/login`, a connection of its own each time, from
//!   127.0.0.3), `LOGINS` (10) a round;
//! - its API calls (`GET /api/me` with that session, a new connection each), `CALLS` (50) a
//!   round;
//! - `PRESSES` (5) E-stop presses a round (`POST /api/estop`) from the experimenter's
//!   session open since before the flood (reset between): the controller's confirmation
//!   and the answer's time;
//!
//! rounds until `SECONDS` (30) have passed in each phase (past the body deadline, so that the
//! slow bodies are cut off and reopened meanwhile);
//! - the server's resident memory, and the CPU the server and the flooder used.
//!
//! Prints one JSON object. Run: `cargo build --workspace --bins && cargo bench --profile dev
//! -p bdft-tests --bench bounded_clients` (env SLOW, IDLE, LOGINS, CALLS, PRESSES, SECONDS,
//! FLOOD_NICE — the flooder's `nice`, 19 for an attacker whose CPU is not the server's — and
//! SERVER_ARGS — extra `serve` arguments, space-separated — change it). Needs about
//! SLOW + IDLE + 1,000 file descriptors (the flooder's and the server's; raise `ulimit -n`
//! past that, or scale the flood down). The flooder is this executable again, started with
//! `BDFT_BOUNDED_FLOOD` set.

use std::io::{BufRead, Read, Write};
use std::net::{IpAddr, SocketAddr};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use bdft_tests::raw::{self, loopback};
use bdft_tests::server::{ADMIN_PASSWORD, Api, Server, eventually, wait_latched};
use bdft_tests::setting;
use bdft_tests::station::summary;
use serde_json::{Value, json};

/// Set (to "ADDRESS SLOW IDLE") in the flooder's environment.
const FLOOD: &str = "BDFT_BOUNDED_FLOOD";

fn main() {
    if let Ok(spec) = std::env::var(FLOOD) {
        flood(&spec);
        return;
    }
    let slow: usize = setting("SLOW", 600);
    let idle: usize = setting("IDLE", 2000);
    let logins: usize = setting("LOGINS", 10);
    let calls: usize = setting("CALLS", 50);
    let presses: usize = setting("PRESSES", 5);
    let seconds: f64 = setting("SECONDS", 30.0);
    let nice: u32 = setting("FLOOD_NICE", 0);
    let extra = std::env::var("SERVER_ARGS").unwrap_or_default();
    let mut args = vec!["--admin-password", ADMIN_PASSWORD];
    args.extend(extra.split_whitespace());
    let server = Server::start_with("bench-bounded", &args);
    // The experimenter's session, open before anything else.
    let experimenter = server.experimenter();
    eventually(Duration::from_secs(30), || {
        (experimenter.get("/api/controller").1["connected"] == true).then_some(())
    });
    let quiet = rounds(&server, &experimenter, (logins, calls, presses), seconds);

    let mut flooder = start_flooder(server.proc.addr, slow, idle, nice);
    // Under way: every flooding connection has been opened at least once.
    let began = Instant::now();
    let mut line = String::new();
    let mut out = std::io::BufReader::new(flooder.stdout.take().unwrap());
    out.read_line(&mut line).unwrap();
    let ramp_s = began.elapsed().as_secs_f64();
    let processes = [
        ("server", server.proc.child.id()),
        ("flooder", flooder.id()),
    ];
    let meter = bdft_tests::CpuMeter::start(&processes);
    let flooded = rounds(&server, &experimenter, (logins, calls, presses), seconds);
    let cpu = meter.shares();
    let server_rss_mb = resident_mb(server.proc.child.id());
    let flood = stop_flooder(&mut flooder, out);
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "{}",
        json!({
            "slow": slow,
            "idle": idle,
            "flood_nice": nice,
            "server_args": extra,
            "loadavg": load.trim(),
            "quiet": quiet,
            "flooded": flooded,
            "flood_ramp_s": (ramp_s * 100.0).round() / 100.0,
            "cpu_percent_flooded": cpu,
            "server_rss_mb_flooded": server_rss_mb,
            "flood": flood,
        })
    );
}

/// What a phase measured.
#[derive(Default)]
struct Measured {
    login_ms: Vec<f64>,
    api_ms: Vec<f64>,
    confirmed: Vec<f64>,
    answered: Vec<f64>,
    failed: Vec<String>,
}

/// Rounds of [`measure`] (`counts`: logins, calls, presses a round) until `seconds` have
/// passed: so that the flood's slow bodies meet their deadline meanwhile.
fn rounds(
    server: &Server,
    experimenter: &Api,
    counts: (usize, usize, usize),
    seconds: f64,
) -> Value {
    let began = Instant::now();
    let mut m = Measured::default();
    let mut n = 0;
    while n == 0 || began.elapsed().as_secs_f64() < seconds {
        measure(server, experimenter, counts, &mut m);
        n += 1;
    }
    m.failed.truncate(10);
    json!({
        "rounds": n,
        "seconds": (began.elapsed().as_secs_f64() * 10.0).round() / 10.0,
        "login_ms": summary(m.login_ms),
        "api_ms": summary(m.api_ms),
        "estop_confirmed_ms": summary(m.confirmed),
        "estop_answered_ms": summary(m.answered),
        "failed": m.failed,
    })
}

/// The new client's logins and calls, and the experimenter's E-stop presses, into `m`.
fn measure(
    server: &Server,
    experimenter: &Api,
    (logins, calls, presses): (usize, usize, usize),
    m: &mut Measured,
) {
    let newcomer = loopback(3);
    let to = server.proc.addr;
    let Measured {
        login_ms,
        api_ms,
        confirmed,
        answered,
        failed,
    } = m;
    let mut cookie = None;
    let credentials = json!({ "username": "admin", "password": ADMIN_PASSWORD }).to_string();
    for _ in 0..logins {
        let t = Instant::now();
        let answer = raw::request(newcomer, to, "POST", "/api/login", &[], Some(&credentials));
        login_ms.push(ms(t));
        match answer {
            Ok(a) if a.status == 200 => {
                cookie = a
                    .headers
                    .iter()
                    .filter(|(n, _)| n == "set-cookie")
                    .filter_map(|(_, v)| v.split(';').next())
                    .map(str::to_string)
                    .reduce(|a, b| format!("{a}; {b}"));
            }
            Ok(a) => failed.push(format!("login {}: {}", a.status, a.body)),
            Err(e) => failed.push(format!("login: {e}")),
        }
    }
    let Some(cookie) = cookie else {
        failed.push("no login succeeded in this round".into());
        return;
    };
    for _ in 0..calls {
        let t = Instant::now();
        let answer = raw::request(newcomer, to, "GET", "/api/me", &[("cookie", &cookie)], None);
        api_ms.push(ms(t));
        match answer {
            Ok(a) if a.status == 200 => {}
            Ok(a) => failed.push(format!("api {}: {}", a.status, a.body)),
            Err(e) => failed.push(format!("api: {e}")),
        }
    }
    for _ in 0..presses {
        let t = Instant::now();
        let (code, body) = experimenter.post("/api/estop", json!({}));
        answered.push(ms(t));
        match body["confirmed_ms"].as_f64() {
            Some(c) if code == 200 => confirmed.push(c),
            _ => failed.push(format!("estop {code}: {body}")),
        }
        eventually(Duration::from_secs(30), || {
            (experimenter.post("/api/estop/reset", json!({})).0 == 200).then_some(())
        });
        wait_latched(experimenter, false);
    }
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1000.0
}

/// Resident memory of process `pid`, MB (from /proc).
fn resident_mb(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0.0);
    (kb / 1024.0 * 10.0).round() / 10.0
}

/// The flooder, at `nice` (0: the bench's own priority; 19: it only gets what the server
/// and the clients leave, as an attacker on another machine would).
fn start_flooder(to: SocketAddr, slow: usize, idle: usize, nice: u32) -> Child {
    let exe = std::env::current_exe().unwrap();
    let mut command = if nice > 0 {
        let mut c = Command::new("nice");
        c.arg("-n").arg(nice.to_string()).arg(exe);
        c
    } else {
        Command::new(exe)
    };
    command
        .env(FLOOD, format!("{to} {slow} {idle}"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the flooder")
}

/// Ends the flooder (it stops when its stdin closes) and returns what it reported.
fn stop_flooder(child: &mut Child, mut out: impl Read) -> Value {
    drop(child.stdin.take());
    let mut text = String::new();
    out.read_to_string(&mut text).unwrap();
    let _ = child.wait();
    serde_json::from_str(text.trim()).unwrap_or(Value::String(text))
}

/// What the flood's connections met.
#[derive(Default)]
struct Tally {
    opened: AtomicU64,
    connect_failed: AtomicU64,
    /// Answers by status: 408, 429, other.
    timed_out: AtomicU64,
    refused: AtomicU64,
    other: AtomicU64,
    /// Closed without an answer.
    closed: AtomicU64,
}

impl Tally {
    fn answered(&self, head: &[u8]) {
        let counter = if head.starts_with(b"HTTP/1.1 408") {
            &self.timed_out
        } else if head.starts_with(b"HTTP/1.1 429") {
            &self.refused
        } else if head.is_empty() {
            &self.closed
        } else {
            &self.other
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

/// The flooder: on one thread, `slow` slow-body and `idle` idle connections from `ADDRESS`
/// (loopback 127.0.0.2), each reopened when the server answers or closes it; prints a line
/// once each has been opened, and what they met when its stdin closes.
fn flood(spec: &str) {
    let parts: Vec<&str> = spec.split(' ').collect();
    let [to, slow, idle] = parts[..] else {
        panic!("{FLOOD}: ADDRESS SLOW IDLE, got {spec}")
    };
    let to: SocketAddr = to.parse().unwrap();
    let slow: usize = slow.parse().unwrap();
    let idle: usize = idle.parse().unwrap();
    let from = loopback(2);
    let tally = Arc::new(Tally::default());
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let began = Instant::now();
    rt.block_on(async {
        let started = Arc::new(tokio::sync::Barrier::new(slow + idle + 1));
        for i in 0..slow + idle {
            let (tally, started) = (Arc::clone(&tally), Arc::clone(&started));
            tokio::spawn(async move {
                let mut first = Some(started);
                loop {
                    let is_slow = i < slow;
                    one_connection(from, to, is_slow, &tally, &mut first).await;
                }
            });
        }
        started.wait().await;
        println!("flooding");
        let _ = std::io::stdout().flush();
        // Until stdin closes (read on a thread of its own: the flood keeps this one).
        tokio::task::spawn_blocking(|| {
            let mut sink = String::new();
            let _ = std::io::stdin().read_to_string(&mut sink);
        })
        .await
        .unwrap();
    });
    let secs = began.elapsed().as_secs_f64();
    let n = |c: &AtomicU64| c.load(Ordering::Relaxed);
    let report = json!({
        "seconds": (secs * 10.0).round() / 10.0,
        "connections_opened": n(&tally.opened),
        "opened_per_s": (n(&tally.opened) as f64 / secs).round(),
        "connect_failed": n(&tally.connect_failed),
        "answered_408": n(&tally.timed_out),
        "answered_429": n(&tally.refused),
        "answered_other": n(&tally.other),
        "closed_unanswered": n(&tally.closed),
    });
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{report}").and_then(|()| out.flush());
    std::process::exit(0);
}

/// One flooding connection from `from`, until the server answers or closes it: a slow one
/// sends a login head announcing 100,000 bytes and then a byte a second, an idle one nothing.
/// `first` is waited on once connected (the flood is under way when every task has).
async fn one_connection(
    from: IpAddr,
    to: SocketAddr,
    slow: bool,
    tally: &Tally,
    first: &mut Option<Arc<tokio::sync::Barrier>>,
) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let connected = async {
        let socket = tokio::net::TcpSocket::new_v4()?;
        socket.bind(SocketAddr::new(from, 0))?;
        socket.connect(to).await
    };
    let mut stream = match connected.await {
        Ok(s) => s,
        Err(_) => {
            tally.connect_failed.fetch_add(1, Ordering::Relaxed);
            // Out of ports or descriptors: a moment before the next try.
            tokio::time::sleep(Duration::from_millis(10)).await;
            return;
        }
    };
    tally.opened.fetch_add(1, Ordering::Relaxed);
    if let Some(barrier) = first.take() {
        barrier.wait().await;
    }
    let mut head = [0u8; 64];
    let mut got = 0;
    if slow {
        let request = raw::head(
            "POST",
            "/api/login",
            &[("content-type", "application/json")],
            Some(100_000),
        );
        if stream.write_all(request.as_bytes()).await.is_err() {
            tally.answered(&[]);
            return;
        }
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        loop {
            tokio::select! {
                n = stream.read(&mut head) => {
                    got = n.unwrap_or(0);
                    break;
                }
                _ = tick.tick() => {
                    if stream.write_all(b" ").await.is_err() {
                        break;
                    }
                }
            }
        }
    } else {
        got = stream.read(&mut head).await.unwrap_or(0);
    }
    tally.answered(&head[..got]);
}
