//! The experimenter at the dashboard: enrols a subject for every free station (or pair of
//! stations), starts each test a moment after its station shows it ready, accepts as
//! incomplete a test that failed as often as the server repeats it, and unassigns a subject
//! who is done; the dashboard's live feed stays open meanwhile. Every request goes into the
//! journal with its answer.

use std::collections::HashMap;
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bdft_controller::rng::Rng;
use serde_json::{Value, json};
use tungstenite::client::IntoClientRequest;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

use super::journal::Journal;
use crate::server::Api;

/// How often the dashboard looks at the stations.
const LOOK_EVERY: Duration = Duration::from_millis(100);
/// A refused start is tried again after this.
const RETRY_START: Duration = Duration::from_millis(500);

/// What the experimenter's thread shares with the soak.
#[derive(Debug)]
struct Shared {
    base: Arc<RwLock<String>>,
    journal: Arc<Journal>,
    study: i64,
    /// Each group's stations (ids): a station serving both seats, or an on/off pair.
    groups: Vec<Vec<i64>>,
    /// No requests at all (a quiet point); `idle` says the thread has stopped making them.
    paused: AtomicBool,
    idle: AtomicBool,
    /// No new subject and no new start (the end of the run).
    draining: AtomicBool,
    stop: AtomicBool,
    /// Messages the dashboard's live feed received.
    live_messages: AtomicU64,
}

/// The experimenter's threads: the dashboard and its live feed.
#[derive(Debug)]
pub struct Experimenter {
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

impl Experimenter {
    /// Starts the experimenter on `study` with `api` (logged in) and the stations `groups`.
    pub fn start(
        api: Api,
        base: Arc<RwLock<String>>,
        journal: Arc<Journal>,
        study: i64,
        groups: Vec<Vec<i64>>,
        seed: u64,
    ) -> Self {
        let cookie = api.cookie_header();
        let shared = Arc::new(Shared {
            base,
            journal,
            study,
            groups,
            paused: AtomicBool::new(false),
            idle: AtomicBool::new(false),
            draining: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            live_messages: AtomicU64::new(0),
        });
        let desk = {
            let s = Arc::clone(&shared);
            std::thread::spawn(move || desk_loop(&s, api, Rng::derive(seed, 0xde5c)))
        };
        let feed = {
            let s = Arc::clone(&shared);
            std::thread::spawn(move || feed_loop(&s, &cookie))
        };
        Self {
            shared,
            threads: vec![desk, feed],
        }
    }

    /// Pauses every request (`true`, a quiet point) or resumes.
    pub fn set_paused(&self, paused: bool) {
        self.shared.paused.store(paused, Ordering::Relaxed);
    }

    /// Whether the paused dashboard has stopped making requests.
    pub fn idle(&self) -> bool {
        self.shared.idle.load(Ordering::Relaxed)
    }

    /// No new subjects and no new starts from now on.
    pub fn drain(&self) {
        self.shared.draining.store(true, Ordering::Relaxed);
    }

    pub fn live_messages(&self) -> u64 {
        self.shared.live_messages.load(Ordering::Relaxed)
    }

    pub fn stop(self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads {
            let _ = t.join();
        }
    }
}

/// What a group of stations shows, taken together.
#[derive(Debug, PartialEq)]
enum GroupPhase {
    /// No subject: enrol one.
    Free,
    /// A subject is assigned to some of the group's stations only.
    Partly(i64),
    Ready {
        subject: i64,
        trial: i64,
    },
    Held(i64),
    Done(i64),
    /// Consent, a test running, a survey, a move: the subject's turn.
    Busy,
}

fn group_phase(views: &[Value]) -> GroupPhase {
    let subject = views
        .iter()
        .find_map(|v| v["station"]["subject_id"].as_i64());
    let Some(subject) = subject else {
        return GroupPhase::Free;
    };
    if views
        .iter()
        .any(|v| v["station"]["subject_id"].as_i64() != Some(subject))
    {
        return GroupPhase::Partly(subject);
    }
    let phase = |p: &str| views.iter().find(|v| v["phase"] == p);
    if phase("running").is_some() {
        return GroupPhase::Busy;
    }
    if let Some(v) = phase("ready") {
        return GroupPhase::Ready {
            subject,
            trial: v["test"]["trial_id"].as_i64().unwrap_or_default(),
        };
    }
    if phase("held").is_some() {
        return GroupPhase::Held(subject);
    }
    if views.iter().all(|v| v["phase"] == "done") {
        return GroupPhase::Done(subject);
    }
    GroupPhase::Busy
}

fn desk_loop(s: &Shared, mut api: Api, mut rng: Rng) {
    // When each test first showed ready: it is started a moment later (the subject reads
    // the instructions), and again after a refusal.
    let mut start_at: HashMap<i64, Instant> = HashMap::new();
    while !s.stop.load(Ordering::Relaxed) {
        std::thread::sleep(LOOK_EVERY);
        if s.paused.load(Ordering::Relaxed) {
            s.idle.store(true, Ordering::Relaxed);
            continue;
        }
        s.idle.store(false, Ordering::Relaxed);
        let base = s.base.read().unwrap_or_else(|p| p.into_inner()).clone();
        if api.base != base {
            api.base = base;
        }
        let draining = s.draining.load(Ordering::Relaxed);
        for (g, ids) in s.groups.iter().enumerate() {
            if s.paused.load(Ordering::Relaxed) {
                break;
            }
            let views: Option<Vec<Value>> = ids
                .iter()
                .map(
                    |id| match api.try_call("GET", &format!("/api/stations/{id}/state"), None) {
                        Ok((200, v)) => Some(v),
                        _ => None,
                    },
                )
                .collect();
            let Some(views) = views else { continue };
            match group_phase(&views) {
                GroupPhase::Free if !draining => enrol(s, &api, g, ids),
                GroupPhase::Partly(subject) => assign(s, &api, g, ids, Some(subject)),
                GroupPhase::Ready { subject, trial } if !draining => {
                    let at = *start_at.entry(trial).or_insert_with(|| {
                        Instant::now() + Duration::from_secs_f64(rng.uniform(0.2, 1.2))
                    });
                    if Instant::now() >= at {
                        let answer = api.try_call(
                            "POST",
                            &format!("/api/trials/{trial}/start"),
                            Some(json!({})),
                        );
                        s.journal.request(
                            "trial.start",
                            json!({ "group": g, "subject": subject, "trial": trial }),
                            &answer,
                        );
                        if !matches!(answer, Ok((200, _))) {
                            start_at.insert(trial, Instant::now() + RETRY_START);
                        }
                    }
                }
                GroupPhase::Held(subject) => accept_failed(s, &api, g, subject),
                GroupPhase::Done(_) => assign(s, &api, g, ids, None),
                _ => {}
            }
        }
    }
}

fn enrol(s: &Shared, api: &Api, group: usize, ids: &[i64]) {
    let answer = api.try_call(
        "POST",
        &format!("/api/studies/{}/subjects", s.study),
        Some(json!({})),
    );
    let subject = answer
        .as_ref()
        .ok()
        .and_then(|(_, b)| b["subject"]["id"].as_i64());
    let code = answer
        .as_ref()
        .ok()
        .and_then(|(_, b)| b["subject"]["code"].as_str().map(str::to_string));
    s.journal.request(
        "subject.enrol",
        json!({ "group": group, "subject": subject, "code": code }),
        &answer,
    );
    if let Some(subject) = subject {
        assign(s, api, group, ids, Some(subject));
    }
}

fn assign(s: &Shared, api: &Api, group: usize, ids: &[i64], subject: Option<i64>) {
    for id in ids {
        let answer = api.try_call(
            "POST",
            &format!("/api/stations/{id}/assign"),
            Some(json!({ "subject_id": subject })),
        );
        s.journal.request(
            "station.assign",
            json!({ "group": group, "station": id, "subject": subject }),
            &answer,
        );
    }
}

/// A test failed as often as the server repeats it: the experimenter accepts its latest
/// attempt as incomplete, with a reason.
fn accept_failed(s: &Shared, api: &Api, group: usize, subject: i64) {
    let Ok((200, detail)) = api.try_call("GET", &format!("/api/subjects/{subject}"), None) else {
        return;
    };
    let trials: Vec<&Value> = detail["trials"]
        .as_array()
        .map(|a| a.iter().map(|t| &t["trial"]).collect())
        .unwrap_or_default();
    let latest = |t: &Value| {
        !trials
            .iter()
            .any(|o| o["slot"] == t["slot"] && o["attempt"].as_i64() > t["attempt"].as_i64())
    };
    let failed = trials.iter().find(|t| {
        latest(t)
            && ["aborted", "incomplete", "invalid"].contains(&t["status"].as_str().unwrap_or(""))
            && t["accepted_reason"].is_null()
    });
    let Some(t) = failed else { return };
    let trial = t["id"].as_i64().unwrap_or_default();
    let answer = api.try_call(
        "POST",
        &format!("/api/trials/{trial}/incomplete"),
        Some(json!({ "reason": "soak: failed as often as the server repeats it" })),
    );
    s.journal.request(
        "trial.accept_incomplete",
        json!({ "group": group, "subject": subject, "trial": trial }),
        &answer,
    );
}

/// The dashboard's live feed (`/api/live`), reconnected whenever it drops; closed in a
/// quiet point.
fn feed_loop(s: &Shared, cookie: &str) {
    let mut ws: Option<WebSocket<MaybeTlsStream<TcpStream>>> = None;
    let mut retry_at = Instant::now();
    while !s.stop.load(Ordering::Relaxed) {
        if s.paused.load(Ordering::Relaxed) {
            if let Some(mut w) = ws.take() {
                let _ = w.close(None);
                let _ = w.flush();
            }
            std::thread::sleep(Duration::from_millis(20));
            continue;
        }
        let Some(w) = ws.as_mut() else {
            if Instant::now() >= retry_at {
                ws = open_feed(s, cookie);
                retry_at = Instant::now() + Duration::from_secs(1);
            } else {
                std::thread::sleep(Duration::from_millis(20));
            }
            continue;
        };
        match w.read() {
            Ok(Message::Text(_)) => {
                s.live_messages.fetch_add(1, Ordering::Relaxed);
            }
            Ok(_) => {}
            Err(e) if crate::read_timed_out(&e) => {}
            Err(_) => ws = None,
        }
    }
    if let Some(mut w) = ws {
        let _ = w.close(None);
        let _ = w.flush();
    }
}

fn open_feed(s: &Shared, cookie: &str) -> Option<WebSocket<MaybeTlsStream<TcpStream>>> {
    let base = s.base.read().unwrap_or_else(|p| p.into_inner()).clone();
    let mut req = format!("{}/api/live", base.replace("http://", "ws://"))
        .into_client_request()
        .ok()?;
    req.headers_mut().insert("cookie", cookie.parse().ok()?);
    req.headers_mut().insert("origin", base.parse().ok()?);
    let (ws, _) = tungstenite::connect(req).ok()?;
    if let MaybeTlsStream::Plain(tcp) = ws.get_ref() {
        let _ = tcp.set_read_timeout(Some(Duration::from_millis(100)));
    }
    Some(ws)
}
