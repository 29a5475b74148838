//! A station's page as the tests and benchmarks play it: its WebSocket, its messages, and
//! operator input fed at a fixed rate with every input timed until the live sample that
//! echoes it.

use std::collections::VecDeque;
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

pub type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

/// The station socket's address for `token` on the server at `base` (`http://…`).
pub fn socket_url(base: &str, token: &str) -> String {
    format!(
        "{}/api/station/ws?token={token}",
        base.replace("http://", "ws://")
    )
}

/// Opens the station's socket (with TCP_NODELAY, as a browser's).
pub fn connect(base: &str, token: &str) -> Socket {
    let (mut ws, _) = tungstenite::connect(socket_url(base, token)).expect("station socket");
    if let MaybeTlsStream::Plain(s) = ws.get_mut() {
        s.set_nodelay(true).unwrap();
    }
    ws
}

/// How long a `read` waits at most (a blocking read that never ends would hang the test).
pub fn read_timeout(ws: &mut Socket, limit: Duration) {
    match ws.get_mut() {
        MaybeTlsStream::Plain(s) => s.set_read_timeout(Some(limit)).unwrap(),
        _ => unreachable!("plain TCP"),
    }
}

/// An operator input message.
pub fn input(trial: i64, seq: u64, position_mm: f64) -> Message {
    Message::Text(
        json!({ "type": "input", "trial_id": trial, "seq": seq, "position_mm": position_mm })
            .to_string()
            .into(),
    )
}

/// A visible display's report: `inputs` sent, a frame every 16 ms.
pub fn display(trial: i64, inputs: u64) -> Message {
    Message::Text(
        json!({ "type": "display", "trial_id": trial, "hidden": false, "frames": inputs,
                "longest_gap_ms": 17.0, "hidden_ms": 0.0, "inputs": inputs })
        .to_string()
        .into(),
    )
}

/// What feeding a running test measured.
#[derive(Debug, Default)]
pub struct Fed {
    /// Each input's time to its echo (ms), from the first echo on.
    pub echo_ms: Vec<f64>,
    /// The longest gap between two of our own sends (ms): how well-behaved the client was.
    pub longest_send_gap_ms: f64,
    /// Why the socket ended early, if it did.
    pub ended: Option<String>,
}

/// Feeds `trial` (already started, or starting) on `ws` at `rate` Hz, with a display report
/// every 250 ms as a visible page sends, for `seconds` from its first echo (or until
/// `seconds` + 10 s without one); times each input until the live sample whose `input_seq`
/// covers it (client clock).
pub fn feed(ws: &mut Socket, trial: i64, rate: f64, seconds: f64) -> Fed {
    let began = Instant::now();
    feed_while(ws, trial, rate, |started| match started {
        Some(t) => t.elapsed() <= Duration::from_secs_f64(seconds),
        None => began.elapsed() <= Duration::from_secs_f64(seconds + 10.0),
    })
}

/// `feed`, until `stop` is set — by whoever watches the test end, so that a test slowed by a
/// loaded machine is fed to its end (an unfed test stops as stale) — or `limit` passes.
pub fn feed_until(
    ws: &mut Socket,
    trial: i64,
    rate: f64,
    stop: &AtomicBool,
    limit: Duration,
) -> Fed {
    let began = Instant::now();
    feed_while(ws, trial, rate, |_| {
        !stop.load(Ordering::Relaxed) && began.elapsed() <= limit
    })
}

/// The feeding itself, while `go_on(when the first echo came)`.
fn feed_while(
    ws: &mut Socket,
    trial: i64,
    rate: f64,
    mut go_on: impl FnMut(Option<Instant>) -> bool,
) -> Fed {
    // Short reads, so that sends keep their schedule; 0.2 ms is the timing's resolution.
    read_timeout(ws, Duration::from_micros(200));
    let period = Duration::from_secs_f64(1.0 / rate);
    let (mut seq, mut pending) = (0u64, VecDeque::<(u64, Instant)>::new());
    let mut fed = Fed::default();
    let mut started: Option<Instant> = None;
    let mut next = Instant::now();
    let mut last_send: Option<Instant> = None;
    let mut last_display: Option<Instant> = None;
    let mut send = |ws: &mut Socket, msg: Message, fed: &mut Fed| {
        let now = Instant::now();
        if let Some(t) = last_send {
            let gap = now.duration_since(t).as_secs_f64() * 1000.0;
            fed.longest_send_gap_ms = fed.longest_send_gap_ms.max(gap);
        }
        last_send = Some(now);
        ws.send(msg).map_err(|e| e.to_string())
    };
    loop {
        if !go_on(started) {
            break;
        }
        if last_display.is_none_or(|t| t.elapsed() >= Duration::from_millis(250)) {
            last_display = Some(Instant::now());
            if let Err(e) = send(ws, display(trial, seq), &mut fed) {
                fed.ended = Some(e);
                break;
            }
        }
        if Instant::now() >= next {
            seq += 1;
            pending.push_back((seq, Instant::now()));
            let position = (seq as f64 * 0.05).sin() * 20.0;
            if let Err(e) = send(ws, input(trial, seq, position), &mut fed) {
                fed.ended = Some(e);
                break;
            }
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
                    fed.echo_ms
                        .push(now.duration_since(sent).as_secs_f64() * 1000.0);
                }
            }
            Ok(Message::Close(f)) => {
                fed.ended = Some(format!("closed by the server: {f:?}"));
                break;
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => {
                fed.ended = Some(e.to_string());
                break;
            }
        }
    }
    fed
}

/// Floods `ws` with input for `trial` as fast as the socket takes it (a blocking write:
/// when the server stops reading, the flood waits) until the connection is gone or `limit`
/// passes — a hostile page, which sends on after the server's close frame —, reading what the
/// server sends all along on a thread of its own as a browser does: (messages written, the
/// close frame's code and reason or why there was none).
pub fn flood_until_closed(
    mut ws: Socket,
    trial: i64,
    limit: Duration,
) -> (u64, Result<(u16, String), String>) {
    let MaybeTlsStream::Plain(tcp) = ws.get_mut() else {
        unreachable!("plain TCP")
    };
    // (Neither waits forever if the server never closes it.)
    tcp.set_write_timeout(Some(limit)).unwrap();
    let reading = tcp.try_clone().unwrap();
    reading.set_read_timeout(Some(limit)).unwrap();
    let reader = std::thread::spawn(move || {
        // The server's frames, read off the same connection (the writer only writes).
        let mut rx = WebSocket::from_raw_socket(reading, tungstenite::protocol::Role::Client, None);
        loop {
            match rx.read() {
                Ok(Message::Close(Some(f))) => return Ok((f.code.into(), f.reason.to_string())),
                Ok(Message::Close(None)) => return Err("closed without a code".to_string()),
                Ok(_) => {}
                Err(e) => return Err(format!("reading: {e}")),
            }
        }
    });
    let mut seq = 0u64;
    loop {
        seq += 1;
        if ws.send(input(trial, seq, 5.0)).is_err() {
            break;
        }
    }
    (seq, reader.join().unwrap())
}

/// The `p` quantile (0–1) of `sorted` (ascending, not empty): the value at ⌊n·p⌋.
pub fn quantile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() as f64 * p) as usize).min(sorted.len() - 1)]
}

/// p50, p95, p99 and max of `values` (ms), as JSON; `null` when there are none.
pub fn summary(mut values: Vec<f64>) -> Value {
    if values.is_empty() {
        return Value::Null;
    }
    values.sort_by(f64::total_cmp);
    let round = |v: f64| (v * 1000.0).round() / 1000.0;
    json!({
        "n": values.len(),
        "p50": round(quantile(&values, 0.5)),
        "p95": round(quantile(&values, 0.95)),
        "p99": round(quantile(&values, 0.99)),
        "max": round(quantile(&values, 1.0)),
    })
}
