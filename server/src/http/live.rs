//! The live sockets: the station's (operator input in; live samples of its running test,
//! changes and the E-stop latch out) and the dashboard's monitor feed (every live sample
//! and every change).
//!
//! Both are bounded. A station has one socket at a time, the newest (see
//! `engine::station_sockets`, which also holds the input rate limit); its messages are
//! size-capped. Every socket reads its peer all the time, pings it, and ends when the peer
//! closes, goes silent or stops reading, so a closed or vanished browser leaves no task and
//! no file descriptor behind.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::extract::State;
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::http::HeaderMap;
use axum::response::Response;
use bdft_protocol::browser_to_server::StationMessage;
use bdft_protocol::server_to_browser::{MonitorEvent, StationEvent, station_close};
use futures_util::stream::{SplitSink, SplitStream};
use futures_util::{SinkExt, StreamExt};
use serde::Deserialize;
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::{Notify, mpsc, oneshot, watch};
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::AppError;
use super::extract::{AppQuery, Experimenter};
use crate::engine::machine::controller_link::{ControllerEvent, ControllerLink};
use crate::engine::procedure::station_sockets::{
    Admit, FLOOD_SECONDS, INPUT_RATE, InputLimit, OPENINGS_PER_SECOND, Opened, READ_RATE,
    ReadBudget,
};
use crate::engine::procedure::stations::running_trial;
use crate::engine::procedure::validity::{self, DisplayReport, DisplayWatch};
use crate::state::AppState;
use crate::store;

/// The station's socket (it authenticates with the token in the query).
pub fn station() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(station_ws))
}

pub fn experimenter() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(live_ws))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct TokenQuery {
    /// The station's bearer token (browsers cannot set headers on WebSockets).
    token: String,
}

/// Largest operator position accepted (mm of device travel).
const MAX_POSITION_MM: f64 = 1000.0;
/// Largest message a station may send: an input message is under 100 bytes. A larger one
/// closes the socket with `station_close::TOO_BIG`.
const MAX_MESSAGE_BYTES: usize = 1024;
/// What the WebSocket layer itself buffers of one message at most (anything larger fails
/// the socket before it is read); above [`MAX_MESSAGE_BYTES`] so that the usual too-large
/// message is refused with its reason.
const TRANSPORT_LIMIT: usize = 16 * 1024;
/// How often a socket pings its browser (which answers by itself).
const PING_EVERY: Duration = Duration::from_secs(15);
/// A peer heard from for this long (not even a pong) is gone.
const SILENCE_LIMIT: Duration = Duration::from_secs(45);
/// A browser that does not take a message within this has stopped reading.
const SEND_LIMIT: Duration = Duration::from_secs(10);
/// Live samples waiting for a slow station browser (dropped beyond: only the newest matter).
const LIVE_QUEUE: usize = 256;
/// How long a closed station's browser has to answer the close frame.
const CLOSE_GRACE: Duration = Duration::from_secs(2);
/// How often a station socket looks for a test the experimenter started and for a latch
/// set without the controller (it hears both at once from the controller otherwise).
const LOOK_EVERY: Duration = Duration::from_millis(500);
/// Input for a test not known to be running looks the station's running test up again at
/// most this often.
const RECHECK_EVERY: Duration = Duration::from_millis(10);
/// How often the display watch of a running person's test looks at the time (hidden for
/// too long, or silent): well inside the display limits (at least 250 ms).
const WATCH_EVERY: Duration = Duration::from_millis(50);

/// WebSocket of a paired station: `input` messages in; `live` samples of its running test,
/// `changed` notices and the `estop` latch out. A newer socket of the station replaces
/// this one.
#[utoipa::path(get, path = "/api/station/ws", tag = "station", params(TokenQuery),
    responses((status = 101, description = "WebSocket: StationMessage in, StationEvent out")))]
async fn station_ws(
    State(s): State<AppState>,
    AppQuery(q): AppQuery<TokenQuery>,
    ws: WebSocketUpgrade,
) -> Result<Response, AppError> {
    // Refused before the upgrade: a station opening socket after socket (each replacing the
    // last) costs no query a try once it is over the limit.
    let too_many = || AppError::TooManyRequests {
        message: format!(
            "this station opened too many sockets: at most {OPENINGS_PER_SECOND} a second after the first few"
        ),
        retry_after: Duration::from_secs(1),
    };
    if s.sockets.known_over_limit(&q.token, Instant::now()) {
        return Err(too_many());
    }
    let station = store::stations::by_token(&s.pool, &q.token)
        .await?
        .ok_or(AppError::Unauthorized)?;
    if !s.sockets.may_open(station.id, &q.token, Instant::now()) {
        return Err(too_many());
    }
    Ok(ws
        .max_message_size(TRANSPORT_LIMIT)
        .max_frame_size(TRANSPORT_LIMIT)
        .on_upgrade(move |socket| station_socket(s, station.id, socket)))
}

fn text(event: &impl serde::Serialize) -> Message {
    Message::Text(
        serde_json::to_string(event)
            .expect("browser messages serialize")
            .into(),
    )
}

/// Sends `msg` unless the browser has stopped taking messages.
async fn send(sink: &mut SplitSink<WebSocket, Message>, msg: Message) -> bool {
    matches!(
        tokio::time::timeout(SEND_LIMIT, sink.send(msg)).await,
        Ok(Ok(()))
    )
}

/// Why the server closes a socket: the close code and the reason the page is told.
type Closing = (u16, String);

/// What the station's reader hands its writer: live samples (dropped when the browser is
/// behind), a coalescing "changed", the latest latch, and the close frame.
struct Outbox {
    live: mpsc::Sender<Message>,
    changed: Arc<Notify>,
    latch: watch::Sender<bool>,
    close: Option<oneshot::Sender<Closing>>,
}

async fn station_socket(s: AppState, station_id: i64, socket: WebSocket) {
    let mut opened = s.sockets.open(station_id);
    let (sink, mut stream) = socket.split();
    let (live, live_rx) = mpsc::channel(LIVE_QUEUE);
    let changed = Arc::new(Notify::new());
    let link = station_link(&s, station_id).await;
    let (latch, latch_rx) = watch::channel(latched(link.as_ref()));
    let (close, close_rx) = oneshot::channel();
    let mut out = Outbox {
        live,
        changed: Arc::clone(&changed),
        latch,
        close: Some(close),
    };
    // Sending runs in its own task: a slow browser must never delay the operator input
    // read here (stale input stops the machine after 100 ms).
    let mut writer = tokio::spawn(station_writer(sink, live_rx, changed, latch_rx, close_rx));
    let closing = station_reader(
        &s,
        link.as_ref(),
        station_id,
        &mut stream,
        &mut out,
        &mut opened,
        &mut writer,
    )
    .await;
    if let Some(closing) = &closing {
        tracing::info!(
            station = station_id,
            code = closing.0,
            reason = closing.1,
            "station socket closed by the server"
        );
        if let Some(close) = out.close.take() {
            let _ = close.send(closing.clone());
        }
        // The closing handshake: what the browser still sends is read and dropped until it
        // answers the close frame, so that it reads the reason before the connection ends
        // (within the station's read budget: a peer that sends on costs no more closing).
        let _ = tokio::time::timeout(CLOSE_GRACE, async {
            loop {
                match next_within(&opened.budget, &mut stream).await {
                    Some(Ok(Message::Close(_)) | Err(_)) | None => break,
                    Some(Ok(_)) => {
                        opened.budget.read(Instant::now());
                    }
                }
            }
        })
        .await;
    }
    drop(out);
    // The writer sends the close frame (or notices the channels closed) and ends.
    if !writer.is_finished() && tokio::time::timeout(SEND_LIMIT, &mut writer).await.is_err() {
        writer.abort();
    }
    s.sockets.closed(&opened, closing.map(|(_, why)| why));
}

/// The socket's next message, within its station's read budget: over the budget the socket
/// is not read until the budget is back, so the rest waits in the network (TCP flow control
/// slows the sender) instead of costing the server a read each.
async fn next_within(
    budget: &ReadBudget,
    stream: &mut SplitStream<WebSocket>,
) -> Option<Result<Message, axum::Error>> {
    if let Some(until) = budget.hold_until(Instant::now()) {
        tokio::time::sleep_until(until.into()).await;
    }
    stream.next().await
}

/// The controller link of the station's site; none when its site is not served here (or
/// the station cannot be read): the station then shows Stopped and feeds nothing.
async fn station_link(s: &AppState, station_id: i64) -> Option<ControllerLink> {
    let station = store::stations::get(&s.pool, station_id).await.ok()?;
    s.sites.stored(station.site.as_deref()).cloned()
}

/// The E-stop latch as the station shows it: set when its site's latch on the server or on
/// the controller is. A site not served here counts as latched.
fn latched(link: Option<&ControllerLink>) -> bool {
    link.is_none_or(ControllerLink::stopped)
}

/// Reads the station until it closes or must be closed; returns why the server closes it.
async fn station_reader(
    s: &AppState,
    link: Option<&ControllerLink>,
    station_id: i64,
    stream: &mut SplitStream<WebSocket>,
    out: &mut Outbox,
    opened: &mut Opened,
    writer: &mut tokio::task::JoinHandle<()>,
) -> Option<Closing> {
    let mut events = s.sites.subscribe();
    // The trial this station may feed: its subject's running test at a seat it serves.
    let current = || async { running_trial(&s.pool, station_id).await.ok().flatten() };
    let mut running = current().await;
    let mut display = Display::default();
    display.follow(s, running).await;
    let mut limit = InputLimit::new(Arc::clone(&opened.budget), Instant::now());
    let mut look = tokio::time::interval(LOOK_EVERY);
    let mut guard = tokio::time::interval(WATCH_EVERY);
    let mut last_recheck = Instant::now();
    let mut last_heard = tokio::time::Instant::now();
    loop {
        display.follow(s, running).await;
        tokio::select! {
            // Biased: a replaced socket is not read once more (the newer one is read
            // instead, never both).
            biased;
            _ = &mut opened.replaced => {
                return Some((station_close::REPLACED, "this station was opened again elsewhere; that page is the live one now".into()));
            }
            // The writer ended: the browser stopped reading.
            _ = &mut *writer => return None,
            () = tokio::time::sleep_until(last_heard + SILENCE_LIMIT) => {
                return Some((station_close::IDLE, format!("nothing heard for {} s", SILENCE_LIMIT.as_secs())));
            }
            msg = next_within(&opened.budget, stream) => {
                let msg = match msg {
                    None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return None,
                    Some(Ok(msg)) => msg,
                };
                last_heard = tokio::time::Instant::now();
                let counts = &opened.counts;
                match limit.admit(Instant::now()) {
                    Admit::Accept => counts.accepted.fetch_add(1, Ordering::Relaxed),
                    Admit::Drop => {
                        counts.dropped.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    Admit::Disconnect => {
                        counts.dropped.fetch_add(1, Ordering::Relaxed);
                        return Some((station_close::FLOOD, format!(
                            "input flood: more than {READ_RATE} messages a second for {FLOOD_SECONDS} s (the limit is {INPUT_RATE} a second)"
                        )));
                    }
                };
                let Message::Text(body) = msg else { continue };
                if body.len() > MAX_MESSAGE_BYTES {
                    return Some((station_close::TOO_BIG, format!(
                        "a message of {} bytes (at most {MAX_MESSAGE_BYTES})", body.len()
                    )));
                }
                let input = serde_json::from_str::<StationMessage>(&body);
                // Input for a test this socket does not know to be running: the test may have
                // just started (its first input must reach the controller within the
                // stale-input limit, not at the next look), so look again, at most every
                // RECHECK_EVERY so that stray input cannot turn into a query each.
                if let Ok(StationMessage::Input { trial_id, .. }) = &input
                    && Some(*trial_id) != running
                    && last_recheck.elapsed() >= RECHECK_EVERY
                {
                    last_recheck = Instant::now();
                    let now = current().await;
                    if now != running {
                        running = now;
                        out.changed.notify_one();
                    }
                }
                match input {
                    // (A socket replaced while this message was read forwards nothing.)
                    Ok(StationMessage::Input { trial_id, seq, position_mm })
                        if Some(trial_id) == running
                            && position_mm.is_finite()
                            && position_mm.abs() <= MAX_POSITION_MM
                            && !opened.is_replaced() =>
                    {
                        if let Some(link) = link {
                            link.send_input(trial_id as u64, seq, position_mm);
                        }
                    }
                    Ok(StationMessage::Display { trial_id, hidden, longest_gap_ms, hidden_ms, .. })
                        if Some(trial_id) == running
                            && longest_gap_ms.is_finite()
                            && hidden_ms.is_finite() =>
                    {
                        let report = DisplayReport { hidden, longest_gap_ms, hidden_ms };
                        display.report(s, Instant::now(), report).await;
                    }
                    // Input for a trial that is not this station's running one, or garbage: dropped.
                    _ => {}
                }
            }
            ev = events.recv() => match ev {
                Ok(ControllerEvent::Live(sample)) if Some(sample.trial_id as i64) == running => {
                    // A live sample that cannot be queued is dropped, never waited for.
                    let _ = out.live.try_send(text(&StationEvent::Live { sample }));
                }
                Ok(ControllerEvent::Live(_)) => {}
                Ok(ControllerEvent::EStop { latched: true, site })
                    if link.is_some_and(|l| l.site() == &*site) =>
                {
                    // At once: the page shows "Stopped" before anything is read again.
                    out.latch.send_if_modified(|l| !std::mem::replace(l, true));
                    running = current().await;
                    out.changed.notify_one();
                }
                Ok(ControllerEvent::TrialChanged { .. } | ControllerEvent::Link { .. } | ControllerEvent::EStop { .. }) | Err(RecvError::Lagged(_)) => {
                    let now = latched(link);
                    out.latch.send_if_modified(|l| std::mem::replace(l, now) != now);
                    running = current().await;
                    out.changed.notify_one();
                }
                Err(RecvError::Closed) => return None,
            },
            // A person's display hidden for too long, or silent.
            _ = guard.tick() => display.check(s, Instant::now()).await,
            // A trial started by the experimenter, a latch set while the controller was away.
            _ = look.tick() => {
                let now = latched(link);
                out.latch.send_if_modified(|l| std::mem::replace(l, now) != now);
                if running.is_none() {
                    let now = current().await;
                    if now != running {
                        running = now;
                        out.changed.notify_one();
                    }
                }
            }
        }
    }
}

/// The display watch of the station's running test, when it is a person's.
#[derive(Default)]
struct Display {
    /// The running test it follows (watched or not).
    trial: Option<i64>,
    watch: Option<DisplayWatch>,
}

impl Display {
    /// Follows the station's running test: a new test is watched from now (a synthetic
    /// subject's is not).
    async fn follow(&mut self, s: &AppState, running: Option<i64>) {
        if running == self.trial {
            return;
        }
        self.trial = running;
        self.watch = None;
        if let Some(id) = running {
            match validity::limits_of(&s.pool, id).await {
                Ok(limits) => {
                    self.watch = limits.map(|l| DisplayWatch::new(id, l, Instant::now()));
                }
                Err(e) => tracing::error!(trial = id, "display limits: {e}"),
            }
        }
    }

    async fn report(&mut self, s: &AppState, now: Instant, report: DisplayReport) {
        let verdict = self.watch.as_mut().and_then(|w| w.report(now, report));
        self.judge(s, verdict).await;
    }

    async fn check(&mut self, s: &AppState, now: Instant) {
        let verdict = self.watch.as_ref().and_then(|w| w.check(now));
        self.judge(s, verdict).await;
    }

    /// Beyond a limit: the test is stopped and filed invalid, once (it stays followed, so
    /// it is not watched again while the controller stops it).
    async fn judge(&mut self, s: &AppState, verdict: Option<String>) {
        let Some(reason) = verdict else { return };
        let Some(w) = self.watch.take() else { return };
        tracing::warn!(
            trial = w.trial_id,
            reason,
            "display beyond the study's limits"
        );
        if let Err(e) = validity::invalidate(
            &s.pool,
            &s.sites,
            "system:display-watch",
            w.trial_id,
            &reason,
        )
        .await
        {
            tracing::error!(trial = w.trial_id, "filing an invalid trial: {e}");
        }
    }
}

/// Sends the station its messages, the E-stop latch first; ends with the close frame.
async fn station_writer(
    mut sink: SplitSink<WebSocket, Message>,
    mut live: mpsc::Receiver<Message>,
    changed: Arc<Notify>,
    mut latch: watch::Receiver<bool>,
    mut close: oneshot::Receiver<Closing>,
) {
    // The page learns the latch as soon as it connects.
    latch.mark_changed();
    let mut ping = tokio::time::interval_at(tokio::time::Instant::now() + PING_EVERY, PING_EVERY);
    loop {
        let msg = tokio::select! {
            biased;
            closing = &mut close => {
                let frame = closing.ok().map(|(code, reason)| CloseFrame { code, reason: reason.into() });
                let _ = send(&mut sink, Message::Close(frame)).await;
                return;
            }
            Ok(()) = latch.changed() => text(&StationEvent::EStop { latched: *latch.borrow_and_update() }),
            () = changed.notified() => text(&StationEvent::Changed),
            Some(msg) = live.recv() => msg,
            _ = ping.tick() => Message::Ping(Default::default()),
        };
        if !send(&mut sink, msg).await {
            return;
        }
    }
}

/// The dashboard's live feed: every live sample and every change (MonitorEvent messages).
/// Same-origin only: a cookie-authenticated WebSocket is otherwise open to cross-site
/// hijacking.
#[utoipa::path(get, path = "/api/live", tag = "monitor",
    responses((status = 101, description = "WebSocket: MonitorEvent out")))]
async fn live_ws(
    State(s): State<AppState>,
    _who: Experimenter,
    headers: HeaderMap,
    ws: WebSocketUpgrade,
) -> Result<Response, AppError> {
    if let (Some(origin), Some(host)) = (headers.get("origin"), headers.get("host")) {
        let origin = origin.to_str().unwrap_or("");
        let host = host.to_str().unwrap_or("");
        if origin.split("://").nth(1) != Some(host) {
            return Err(AppError::Forbidden("cross-origin WebSocket refused".into()));
        }
    }
    Ok(ws
        .max_message_size(MAX_MESSAGE_BYTES)
        .max_frame_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| dashboard_socket(s, socket)))
}

/// Feeds one dashboard until it closes, goes silent or stops reading. The browser sends
/// nothing but pongs and the close; reading them is how a closed dashboard is noticed even
/// when nothing happens to send.
async fn dashboard_socket(s: AppState, socket: WebSocket) {
    let (mut sink, mut stream) = socket.split();
    let mut events = s.sites.subscribe();
    let mut ping = tokio::time::interval_at(tokio::time::Instant::now() + PING_EVERY, PING_EVERY);
    loop {
        let event = tokio::select! {
            msg = tokio::time::timeout(SILENCE_LIMIT, stream.next()) => match msg {
                Ok(Some(Ok(Message::Close(_)) | Err(_)) | None) | Err(_) => return,
                Ok(Some(Ok(_))) => continue,
            },
            _ = ping.tick() => Message::Ping(Default::default()),
            ev = events.recv() => text(&match ev {
                Ok(ControllerEvent::Live(sample)) => MonitorEvent::Live { sample },
                Ok(ControllerEvent::TrialChanged { trial_id }) => MonitorEvent::Trial { trial_id },
                // The dashboard's one light and latch: every site connected, any site latched.
                Ok(ControllerEvent::Link { .. }) => MonitorEvent::Controller { connected: s.sites.all_connected() },
                Ok(ControllerEvent::EStop { .. }) => MonitorEvent::EStop { latched: s.sites.any_latched() },
                Err(RecvError::Lagged(_)) => continue,
                Err(RecvError::Closed) => return,
            }),
        };
        if !send(&mut sink, event).await {
            return;
        }
    }
}
