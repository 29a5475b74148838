//! A browser-like station: what `web/station.js` does, from two threads. The page thread
//! asks for the station's state (every second, and at once when the socket says "changed")
//! and answers consent and surveys after a moment's thought; the socket thread streams
//! operator input at the station's rate (60–250 Hz) during the shown test, tracking the
//! target it sees in the live samples, draws "frames" at 60 Hz, sends the display report
//! every 250 ms of a running test and hands the display's timing figures to the page thread
//! when the test ends. Faults come in as commands: a reload, a network gone, a hidden
//! page, a flood.

use std::collections::VecDeque;
use std::net::{Shutdown, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bdft_controller::rng::Rng;
use serde_json::{Value, json};
use tungstenite::protocol::CloseFrame;
use tungstenite::protocol::frame::coding::CloseCode;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

use super::journal::Journal;
use crate::server::Api;

type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

/// How often the page asks for its state without being told (station.js: POLL_MS).
const POLL_EVERY: Duration = Duration::from_secs(1);
/// Display reports of a running test (station.js), and of a hidden page, whose timers the
/// browser throttles to about one a second.
const REPORT_EVERY: Duration = Duration::from_millis(250);
const HIDDEN_REPORT_EVERY: Duration = Duration::from_secs(1);
/// The display's frame period (60 Hz), and what counts as a long frame.
const FRAME: Duration = Duration::from_micros(16_667);
const LONG_FRAME_MS: f64 = 20.0;
/// Reconnecting after a closed socket (station.js), and after one closed for flooding.
const RECONNECT: Duration = Duration::from_secs(1);
const RECONNECT_AFTER_FLOOD: Duration = Duration::from_secs(5);
/// The close code of a socket the server closed for a flood (`station_close::FLOOD`), and of
/// one a newer socket replaced (`station_close::REPLACED`).
const CLOSE_FLOOD: u16 = 1008;
const CLOSE_REPLACED: u16 = 4001;
/// The subject's hand follows the target with this time constant.
const HAND_LAG_S: f64 = 0.2;

/// How a station is set up.
#[derive(Debug, Clone)]
pub struct StationSpec {
    pub index: usize,
    pub id: i64,
    pub token: String,
    /// Operator input messages a second while a test is shown.
    pub rate_hz: f64,
    /// Whether its subject answers the consent form here (one station of a pair does).
    pub answers_consent: bool,
}

/// A fault for the station's page.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// The page is reloaded: its socket closes (going away), the new page loads for `load`,
    /// then asks for its state and opens a new socket. A reload forgets the running test's
    /// display figures (the old page is gone before it could send them).
    Reload { load: Duration },
    /// The network is gone for `off`: the socket dies without a close frame, nothing
    /// reaches the server, then the page reconnects.
    Offline { off: Duration },
    /// The page is hidden until its running test ends (at most `at_most`); whether the
    /// subject's input still arrives meanwhile (a device the hidden page still reads) or
    /// stops (a pointer over another window).
    Hide { at_most: Duration, keep_input: bool },
    /// The page sends input as fast as it can for at most `at_most`, or until the server
    /// closes its socket.
    Flood { at_most: Duration },
}

/// What the page shows now (from its last state).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Shown {
    pub phase: String,
    pub subject: Option<String>,
    pub test: Option<ShownTest>,
    /// The test whose survey is shown.
    pub survey: Option<i64>,
    /// The survey's scale (points).
    pub scale: i64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShownTest {
    pub trial_id: i64,
    pub running: bool,
    pub k_bf: f64,
    pub duration_s: f64,
    pub started_at: Option<i64>,
}

/// What the station's threads share.
#[derive(Debug)]
struct Shared {
    spec: StationSpec,
    base: Arc<RwLock<String>>,
    journal: Arc<Journal>,
    shown: Mutex<Shown>,
    /// The socket said "changed": ask for the state at once.
    changed: AtomicBool,
    commands: Mutex<VecDeque<Command>>,
    /// The page is closed (a quiet point): no socket, no requests, until it opens again.
    away: AtomicBool,
    stop: AtomicBool,
    /// The network is gone until then (no requests either).
    offline_until: Mutex<Option<Instant>>,
    /// The page reloads until then: a new page (a new HTTP client) asks for its state after.
    reload_until: Mutex<Option<Instant>>,
    /// Display timing figures of ended tests, for the page thread to send.
    reports: Mutex<Vec<Value>>,
    /// Whether a socket is open now.
    connected: AtomicBool,
}

/// A running browser-like station.
#[derive(Debug)]
pub struct Station {
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

impl Station {
    /// Opens the station's page (its two threads); `seed` drives its subject's choices.
    pub fn open(
        spec: StationSpec,
        base: Arc<RwLock<String>>,
        journal: Arc<Journal>,
        seed: u64,
    ) -> Self {
        let shared = Arc::new(Shared {
            spec,
            base,
            journal,
            shown: Mutex::new(Shown::default()),
            changed: AtomicBool::new(true),
            commands: Mutex::new(VecDeque::new()),
            away: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            offline_until: Mutex::new(None),
            reload_until: Mutex::new(None),
            reports: Mutex::new(Vec::new()),
            connected: AtomicBool::new(false),
        });
        let index = shared.spec.index as u64;
        let page = {
            let s = Arc::clone(&shared);
            let rng = Rng::derive(seed, 0x9a6e_0000 + index);
            std::thread::spawn(move || page_loop(&s, rng, seed))
        };
        let socket = {
            let s = Arc::clone(&shared);
            std::thread::spawn(move || socket_loop(&s))
        };
        Self {
            shared,
            threads: vec![page, socket],
        }
    }

    pub fn spec(&self) -> &StationSpec {
        &self.shared.spec
    }

    pub fn connected(&self) -> bool {
        self.shared.connected.load(Ordering::Relaxed)
    }

    pub fn command(&self, c: Command) {
        lock(&self.shared.commands).push_back(c);
    }

    /// Closes the page (`true`) or opens it again.
    pub fn set_away(&self, away: bool) {
        self.shared.away.store(away, Ordering::Relaxed);
        if !away {
            self.shared.changed.store(true, Ordering::Relaxed);
        }
    }

    /// Closes the page for good and waits for its threads.
    pub fn close(self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads {
            let _ = t.join();
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

fn until_passed(m: &Mutex<Option<Instant>>, now: Instant) -> bool {
    lock(m).is_some_and(|t| now < t)
}

/// The page's requests: its state, consent, surveys and timing figures.
fn page_loop(s: &Shared, mut rng: Rng, seed: u64) {
    let spec = &s.spec;
    let new_api = || {
        Api::with_bearer(
            &s.base.read().unwrap_or_else(|p| p.into_inner()),
            &spec.token,
        )
    };
    let mut api: Option<Api> = None;
    let mut polled: Option<Instant> = None;
    let mut consented: Option<String> = None;
    let mut answered: Vec<i64> = Vec::new();
    // What the subject is about to do, and when (a moment's thought).
    let mut thinking: Option<(&'static str, i64, Instant)> = None;
    while !s.stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(10));
        let now = Instant::now();
        if s.away.load(Ordering::Relaxed) {
            // A closed page holds no connection.
            api = None;
            continue;
        }
        if until_passed(&s.offline_until, now) {
            continue;
        }
        if until_passed(&s.reload_until, now) {
            // The old page is gone with its connections; the new one starts from scratch.
            api = None;
            polled = None;
            continue;
        }
        let api = api.get_or_insert_with(new_api);
        let base = s.base.read().unwrap_or_else(|p| p.into_inner()).clone();
        if api.base != base {
            api.base = base;
        }
        if s.changed.swap(false, Ordering::Relaxed)
            || polled.is_none_or(|t| t.elapsed() >= POLL_EVERY)
        {
            polled = Some(now);
            if let Ok((200, view)) = api.try_call("GET", "/api/station/state", None) {
                *lock(&s.shown) = shown_of(&view);
            }
        }
        let shown = lock(&s.shown).clone();
        match (shown.phase.as_str(), &shown.subject) {
            ("consent", Some(code)) if spec.answers_consent && consented.as_ref() != Some(code) => {
                let id = code_number(code);
                match thinking {
                    Some(("consent", who, at)) if who == id => {
                        if now >= at {
                            thinking = None;
                            // Now and then a subject declines (once: a request
                            // that fails is sent again with the same decision).
                            let declines =
                                Rng::derive(seed, 0xc025_e000 + id as u64).next_f64() < 0.08;
                            let decision = if declines { "declined" } else { "agreed" };
                            let answer = api.try_call(
                                "POST",
                                "/api/station/consent",
                                Some(json!({ "decision": decision })),
                            );
                            s.journal.request(
                                "consent",
                                json!({ "station": spec.index, "subject": code, "decision": decision }),
                                &answer,
                            );
                            if matches!(answer, Ok((c, _)) if c < 500) {
                                consented = Some(code.clone());
                            }
                            s.changed.store(true, Ordering::Relaxed);
                        }
                    }
                    _ => thinking = Some(("consent", id, now + think(&mut rng))),
                }
            }
            ("survey", _) => {
                let trial = shown.survey.unwrap_or_default();
                if !answered.contains(&trial) {
                    match thinking {
                        Some(("survey", t, at)) if t == trial => {
                            if now >= at {
                                thinking = None;
                                let body = survey_answers(&mut rng, trial, shown.scale);
                                let answer =
                                    api.try_call("POST", "/api/station/survey", Some(body.clone()));
                                s.journal.request(
                                    "survey",
                                    json!({ "station": spec.index, "trial": trial, "answers": body }),
                                    &answer,
                                );
                                if matches!(answer, Ok((c, _)) if c < 500) {
                                    answered.push(trial);
                                }
                                s.changed.store(true, Ordering::Relaxed);
                            }
                        }
                        _ => thinking = Some(("survey", trial, now + think(&mut rng))),
                    }
                }
            }
            _ => {}
        }
        let reports = std::mem::take(&mut *lock(&s.reports));
        for report in reports {
            let answer = api.try_call("POST", "/api/station/timing", Some(report.clone()));
            s.journal.request(
                "timing",
                json!({ "station": spec.index, "trial": report["trial_id"], "frames": report["frames"] }),
                &answer,
            );
        }
    }
}

/// A subject's moment of thought before answering.
fn think(rng: &mut Rng) -> Duration {
    Duration::from_secs_f64(rng.uniform(0.2, 1.0))
}

/// S07 → 7 (the subject's number, to tell subjects apart cheaply).
fn code_number(code: &str) -> i64 {
    code.trim_start_matches(|c: char| !c.is_ascii_digit())
        .parse()
        .unwrap_or(-1)
}

/// A subject's survey of `trial`: ratings on the study's scale, sometimes a comment.
fn survey_answers(rng: &mut Rng, trial: i64, scale: i64) -> Value {
    let scale = scale.max(2) as u64;
    let mut rating = || 1 + (rng.next_u64() % scale) as i64;
    let (accuracy, speed, smoothness, controllability) = (rating(), rating(), rating(), rating());
    let comments = [
        "",
        "",
        "it shook a lot",
        "smooth — easy to follow",
        "zu träge, 振动",
    ];
    let comment = comments[(rng.next_u64() % comments.len() as u64) as usize];
    json!({ "trial_id": trial, "accuracy": accuracy, "speed": speed, "smoothness": smoothness,
        "controllability": controllability, "comment": comment })
}

/// What a `StationView` shows, in short.
fn shown_of(view: &Value) -> Shown {
    let test = view
        .get("test")
        .filter(|t| t.is_object())
        .map(|t| ShownTest {
            trial_id: t["trial_id"].as_i64().unwrap_or_default(),
            running: view["phase"] == "running",
            k_bf: t["k_bf"].as_f64().unwrap_or(1.0),
            duration_s: t["duration_s"].as_f64().unwrap_or_default(),
            started_at: t["started_at"].as_i64(),
        });
    Shown {
        phase: view["phase"].as_str().unwrap_or_default().to_string(),
        subject: view["subject"].as_str().map(str::to_string),
        test,
        survey: (view["phase"] == "survey")
            .then(|| view["trial_id"].as_i64())
            .flatten(),
        scale: view["survey"]["scale_points"].as_i64().unwrap_or(7),
    }
}

/// A test the page shows as running: the display's figures since it started (station.js's
/// `run`).
#[derive(Debug)]
struct Run {
    trial_id: i64,
    started: Instant,
    frames: u64,
    long_frames: u64,
    last_frame: Option<Instant>,
    longest_gap_ms: f64,
    hidden_ms: f64,
    hidden_since: Option<Instant>,
    inputs: u64,
    rtts_ms: Vec<f64>,
    next_report: Instant,
}

impl Run {
    fn start(trial_id: i64, now: Instant, hidden: bool) -> Self {
        Self {
            trial_id,
            started: now,
            frames: 0,
            long_frames: 0,
            last_frame: None,
            longest_gap_ms: 0.0,
            hidden_ms: 0.0,
            hidden_since: hidden.then_some(now),
            inputs: 0,
            rtts_ms: Vec::new(),
            next_report: now,
        }
    }

    /// Draws a frame when one is due (a visible page only).
    fn draw(&mut self, now: Instant) {
        if self.hidden_since.is_some() {
            return;
        }
        let last = self.last_frame.unwrap_or(self.started);
        if now.duration_since(last) >= FRAME {
            let gap = ms(now.duration_since(last));
            self.longest_gap_ms = self.longest_gap_ms.max(gap);
            if gap > LONG_FRAME_MS {
                self.long_frames += 1;
            }
            self.frames += 1;
            self.last_frame = Some(now);
        }
    }

    fn set_hidden(&mut self, hidden: bool, now: Instant) {
        match (hidden, self.hidden_since) {
            (true, None) => self.hidden_since = Some(now),
            (false, Some(since)) => {
                self.hidden_ms += ms(now.duration_since(since));
                self.hidden_since = None;
                // The hidden spell is no frame gap of a visible display.
                self.last_frame = Some(now);
            }
            _ => {}
        }
    }

    /// The display report now (the open gap and hidden spell count).
    fn display(&self, now: Instant) -> Value {
        let open_gap = if self.hidden_since.is_some() {
            0.0
        } else {
            ms(now.duration_since(self.last_frame.unwrap_or(self.started)))
        };
        let hidden_ms =
            self.hidden_ms + self.hidden_since.map_or(0.0, |t| ms(now.duration_since(t)));
        json!({ "type": "display", "trial_id": self.trial_id, "hidden": self.hidden_since.is_some(),
            "frames": self.frames, "longest_gap_ms": round(self.longest_gap_ms.max(open_gap), 10.0),
            "hidden_ms": round(hidden_ms, 10.0), "inputs": self.inputs })
    }

    /// The timing figures the page sends when the test ends (`POST /api/station/timing`).
    fn timing(&self, now: Instant) -> Value {
        let mut rtts = self.rtts_ms.clone();
        rtts.sort_by(f64::total_cmp);
        let pick = |p: f64| {
            if rtts.is_empty() {
                0.0
            } else {
                rtts[((p * rtts.len() as f64).ceil() as usize).clamp(1, rtts.len()) - 1]
            }
        };
        let d = self.display(now);
        let secs = now.duration_since(self.started).as_secs_f64().max(1e-3);
        json!({ "trial_id": self.trial_id, "frames": self.frames,
            "long_frames": self.long_frames.min(self.frames),
            "longest_gap_ms": round(d["longest_gap_ms"].as_f64().unwrap_or(0.0).min(600_000.0), 100.0),
            "hidden_ms": round(d["hidden_ms"].as_f64().unwrap_or(0.0).min(600_000.0), 100.0),
            "input_hz": round((self.inputs as f64 / secs).min(1000.0), 10.0),
            "rtt_ms": { "p50": round(pick(0.5), 100.0), "p95": round(pick(0.95), 100.0),
                "max": round(rtts.last().copied().unwrap_or(0.0), 100.0) } })
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

fn round(x: f64, per: f64) -> f64 {
    (x * per).round() / per
}

/// The hidden page, while it is.
#[derive(Debug, Clone, Copy)]
struct Hidden {
    until: Instant,
    keep_input: bool,
    /// The test it was hidden in: it shows again when that test ends.
    trial_id: Option<i64>,
}

/// The socket thread's state.
struct Page {
    ws: Option<Socket>,
    reconnect_at: Instant,
    /// Input sequence numbers restart with each test (station.js).
    seq_trial: i64,
    seq: u64,
    next_input: Instant,
    hand_mm: f64,
    target_mm: f64,
    moved_at: Instant,
    sent: VecDeque<(u64, Instant)>,
    latched: bool,
    run: Option<Run>,
    hidden: Option<Hidden>,
    flood_until: Option<Instant>,
}

fn socket_loop(s: &Shared) {
    let now = Instant::now();
    let mut p = Page {
        ws: None,
        reconnect_at: now,
        seq_trial: -1,
        seq: 0,
        next_input: now,
        hand_mm: 0.0,
        target_mm: 0.0,
        moved_at: now,
        sent: VecDeque::new(),
        latched: false,
        run: None,
        hidden: None,
        flood_until: None,
    };
    let period = Duration::from_secs_f64(1.0 / s.spec.rate_hz);
    while !s.stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        let commands: Vec<Command> = lock(&s.commands).drain(..).collect();
        for c in commands {
            p.apply(s, c, now);
        }
        if s.away.load(Ordering::Relaxed) || until_passed(&s.offline_until, now) {
            if s.away.load(Ordering::Relaxed) {
                p.close(s, now);
            }
            std::thread::sleep(Duration::from_millis(5));
            continue;
        }
        if p.ws.is_none() {
            if now >= p.reconnect_at && !until_passed(&s.reload_until, now) {
                p.connect(s, now);
            }
            if p.ws.is_none() {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
        }
        if p.flood_until.is_some_and(|t| now < t) {
            p.flood(s, now);
            continue;
        }
        p.flood_until = None;
        p.read(s, now);
        let shown = lock(&s.shown).clone();
        let test = shown
            .test
            .filter(|_| shown.phase == "ready" || shown.phase == "running");
        p.follow_run(s, test, now);
        let input_on = p.hidden.is_none_or(|h| h.keep_input);
        if let Some(t) = test
            && !p.latched
            && input_on
            && now >= p.next_input
        {
            p.send_input(s, t, now);
            p.next_input = if now.duration_since(p.next_input) > period {
                now + period
            } else {
                p.next_input + period
            };
        }
    }
    p.close(s, Instant::now());
}

impl Page {
    fn apply(&mut self, s: &Shared, c: Command, now: Instant) {
        match c {
            Command::Reload { load } => {
                self.close(s, now);
                self.run = None;
                self.hidden = None;
                self.flood_until = None;
                self.seq_trial = -1;
                // The new page knows nothing until it has asked for its state.
                *lock(&s.shown) = Shown::default();
                *lock(&s.reload_until) = Some(now + load);
                self.reconnect_at = now + load;
            }
            Command::Offline { off } => {
                if let Some(ws) = self.ws.take() {
                    // The connection dies under the page: no close frame, no goodbye.
                    if let MaybeTlsStream::Plain(tcp) = ws.get_ref() {
                        let _ = tcp.shutdown(Shutdown::Both);
                    }
                }
                s.connected.store(false, Ordering::Relaxed);
                *lock(&s.offline_until) = Some(now + off);
                self.reconnect_at = now + off;
            }
            Command::Hide {
                at_most,
                keep_input,
            } => {
                self.hidden = Some(Hidden {
                    until: now + at_most,
                    keep_input,
                    trial_id: self.run.as_ref().map(|r| r.trial_id),
                });
                if let Some(r) = self.run.as_mut() {
                    r.set_hidden(true, now);
                    let d = r.display(now);
                    r.next_report = now + HIDDEN_REPORT_EVERY;
                    self.send(s, d);
                }
            }
            Command::Flood { at_most } => self.flood_until = Some(now + at_most),
        }
    }

    fn connect(&mut self, s: &Shared, now: Instant) {
        let base = s.base.read().unwrap_or_else(|p| p.into_inner()).clone();
        let url = format!(
            "{}/api/station/ws?token={}",
            base.replace("http://", "ws://"),
            s.spec.token
        );
        match tungstenite::connect(url) {
            Ok((ws, _)) => {
                if let MaybeTlsStream::Plain(tcp) = ws.get_ref() {
                    let _ = tcp.set_read_timeout(Some(Duration::from_millis(1)));
                    let _ = tcp.set_write_timeout(Some(Duration::from_secs(2)));
                    let _ = tcp.set_nodelay(true);
                }
                self.ws = Some(ws);
                s.connected.store(true, Ordering::Relaxed);
                s.changed.store(true, Ordering::Relaxed);
            }
            Err(_) => self.reconnect_at = now + RECONNECT,
        }
    }

    /// Closes the socket as a page going away does (close frame, answer awaited briefly).
    fn close(&mut self, s: &Shared, now: Instant) {
        if let Some(mut ws) = self.ws.take() {
            let _ = ws.close(Some(CloseFrame {
                code: CloseCode::Away,
                reason: "page closed".into(),
            }));
            let until = now + Duration::from_millis(500);
            while Instant::now() < until {
                match ws.read() {
                    Ok(_) => {}
                    Err(e) if crate::read_timed_out(&e) => {}
                    Err(_) => break,
                }
            }
        }
        s.connected.store(false, Ordering::Relaxed);
    }

    /// The socket ended (closed by the server, or broken): reconnect later, as the page does.
    fn lost(&mut self, s: &Shared, now: Instant, close: Option<(u16, String)>) {
        self.ws = None;
        s.connected.store(false, Ordering::Relaxed);
        let code = close.as_ref().map(|c| c.0);
        if let Some((code, reason)) = close {
            s.journal.log(
                "socket.closed_by_server",
                json!({ "station": s.spec.index, "code": code, "reason": reason }),
            );
        }
        if code == Some(CLOSE_REPLACED) {
            // The soak opens one page per station: nothing should have replaced it.
            s.journal.violation(format!(
                "station {}'s socket was replaced though no other page of it was open",
                s.spec.index
            ));
        }
        self.reconnect_at = now
            + if code == Some(CLOSE_FLOOD) {
                RECONNECT_AFTER_FLOOD
            } else {
                RECONNECT
            };
        self.flood_until = None;
    }

    fn send(&mut self, s: &Shared, msg: Value) {
        let Some(ws) = self.ws.as_mut() else { return };
        if ws.send(Message::Text(msg.to_string().into())).is_err() {
            self.lost(s, Instant::now(), None);
        }
    }

    fn read(&mut self, s: &Shared, now: Instant) {
        let Some(ws) = self.ws.as_mut() else { return };
        let msg = match ws.read() {
            Ok(Message::Text(t)) => t,
            Ok(Message::Close(frame)) => {
                let close = frame.map(|f| (u16::from(f.code), f.reason.to_string()));
                return self.lost(s, now, close);
            }
            Ok(_) => return,
            Err(e) if crate::read_timed_out(&e) => {
                return;
            }
            Err(_) => return self.lost(s, now, None),
        };
        let Ok(v) = serde_json::from_str::<Value>(&msg) else {
            return;
        };
        match v["type"].as_str() {
            Some("changed") => s.changed.store(true, Ordering::Relaxed),
            Some("estop") => {
                self.latched = v["latched"] == true;
                s.changed.store(true, Ordering::Relaxed);
            }
            Some("live") => {
                let sample = &v["sample"];
                if let Some(target) = sample["target_mm"].as_f64() {
                    self.target_mm = target;
                }
                let echoed = sample["input_seq"].as_u64().unwrap_or(0);
                while self.sent.front().is_some_and(|(seq, _)| *seq <= echoed) {
                    let (seq, at) = self.sent.pop_front().expect("front exists");
                    if seq == echoed
                        && let Some(r) = self.run.as_mut()
                        && sample["trial_id"].as_i64() == Some(r.trial_id)
                    {
                        r.rtts_ms.push(ms(now.duration_since(at)));
                    }
                }
            }
            _ => {}
        }
    }

    /// Starts, keeps and ends the display's run of the test the page shows running.
    fn follow_run(&mut self, s: &Shared, test: Option<ShownTest>, now: Instant) {
        let running = test.filter(|t| t.running).map(|t| t.trial_id);
        if let Some(r) = &self.run
            && running != Some(r.trial_id)
        {
            let r = self.run.take().expect("checked");
            lock(&s.reports).push(r.timing(now));
            if self.hidden.is_some_and(|h| h.trial_id == Some(r.trial_id)) {
                self.hidden = None;
            }
        }
        if let Some(h) = self.hidden
            && now >= h.until
        {
            self.hidden = None;
            if let Some(r) = self.run.as_mut() {
                r.set_hidden(false, now);
                let d = r.display(now);
                self.send(s, d);
            }
        }
        if let (Some(id), None) = (running, &self.run) {
            let mut r = Run::start(id, now, self.hidden.is_some());
            r.next_report = now + REPORT_EVERY;
            let d = r.display(now);
            self.run = Some(r);
            self.send(s, d);
            return;
        }
        let Some(r) = self.run.as_mut() else { return };
        r.draw(now);
        if now >= r.next_report {
            let every = if r.hidden_since.is_some() {
                HIDDEN_REPORT_EVERY
            } else {
                REPORT_EVERY
            };
            r.next_report = now + every;
            let d = r.display(now);
            self.send(s, d);
        }
    }

    fn send_input(&mut self, s: &Shared, t: ShownTest, now: Instant) {
        if self.seq_trial != t.trial_id {
            self.seq_trial = t.trial_id;
            self.seq = 0;
            self.sent.clear();
        }
        // The hand follows the target it sees, with a lag.
        let dt = now.duration_since(self.moved_at).as_secs_f64();
        self.moved_at = now;
        self.hand_mm += (self.target_mm - self.hand_mm) * (1.0 - (-dt / HAND_LAG_S).exp());
        let kbf = if t.k_bf > 0.0 { t.k_bf } else { 1.0 };
        self.seq += 1;
        let msg = json!({ "type": "input", "trial_id": t.trial_id, "seq": self.seq,
            "position_mm": (self.hand_mm / kbf).clamp(-100.0, 100.0) });
        self.sent.push_back((self.seq, now));
        if self.sent.len() > 4096 {
            self.sent.pop_front();
        }
        if let Some(r) = self.run.as_mut()
            && r.trial_id == t.trial_id
        {
            r.inputs += 1;
        }
        self.send(s, msg);
    }

    /// A broken page: input frames back to back, as fast as the socket takes them.
    fn flood(&mut self, s: &Shared, now: Instant) {
        let trial = lock(&s.shown).test.map_or(0, |t| t.trial_id);
        let Some(ws) = self.ws.as_mut() else { return };
        for _ in 0..200 {
            self.seq += 1;
            let msg =
                json!({ "type": "input", "trial_id": trial, "seq": self.seq, "position_mm": 0.0 });
            if ws.write(Message::Text(msg.to_string().into())).is_err() {
                return self.lost(s, now, None);
            }
        }
        if ws.flush().is_err() {
            return self.lost(s, now, None);
        }
        // What the server says back (its close frame, when it has had enough).
        self.read(s, now);
    }
}
