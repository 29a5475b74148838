//! The server's side of the controller link: spawns and supervises `bdft-controller serve`
//! ([`process`]) or connects to a given address, authenticates both ends with the shared
//! link key, keeps the control connection ([`session`]: forwards messages, gathers record
//! chunks, commits each trial's result in one transaction) and the E-stop's own connection
//! ([`estop_path`]). When the controller dies or the link drops, running trials are marked
//! incomplete at once and the controller is restarted. What only the protocol can file — a
//! trial's result, the trials a lost controller will not finish — goes to the [`Filing`] the
//! server hands the link at start, so the machine room never imports the procedure's rules.

mod connection;
mod estop_path;
mod process;
mod reader;
mod session;

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bdft_protocol::controller_to_server::{LiveSample, TrialResult};
use bdft_protocol::framing;
use bdft_protocol::link_auth::LinkKey;
use bdft_protocol::server_to_controller::{ServerToController, StartTrial};
use bdft_protocol::trial::TrialId;
use tokio::sync::{broadcast, mpsc, oneshot, watch};

use super::estop_latch::EStopLatch;
use crate::store::records::Record;
use connection::frame;

/// Where the controller comes from.
#[derive(Debug, Clone)]
pub enum ControllerSource {
    /// Start a controller as a child process (restarted if it dies): `bin args… --listen
    /// 127.0.0.1:0 --exit-with-stdin`, where `args` name the subcommand (`serve` for
    /// bdft-controller, `controller` for this server's own executable).
    Spawn { bin: PathBuf, args: Vec<String> },
    /// Connect to a controller that runs elsewhere (e.g. a real-time PC).
    Connect(SocketAddr),
}

/// How often the controller heartbeats (`bdft-controller serve`; it also sends live samples
/// every 10 ms while a trial runs): the controller's own constant, not a copy of it.
pub use bdft_controller::runtime::link::HEARTBEAT;

/// How long the controller may stay silent before the link counts as lost: two heartbeats
/// missing and the third 25 ms late. A hung controller (stopped, deadlocked, its machine
/// frozen) is noticed this long after its last message and its running trials are filed
/// incomplete within 100 ms of it (the filing takes the rest); an E-stop meanwhile is
/// reported undelivered instead of answering ok.
pub const DEFAULT_SILENCE: Duration = Duration::from_millis(75);

/// What the rest of the server hears from the controller.
#[derive(Debug, Clone)]
pub enum ControllerEvent {
    Live(LiveSample),
    /// A trial's result is committed (or it was interrupted): its row changed.
    TrialChanged {
        trial_id: i64,
    },
    /// A site's link went up or down.
    Link {
        site: Arc<str>,
        connected: bool,
    },
    /// A site's e-stop latch was set or cleared.
    EStop {
        site: Arc<str>,
        latched: bool,
    },
}

/// A boxed future, as a trait object's async method returns it.
pub type BoxFuture<'a, T> = std::pin::Pin<Box<dyn std::future::Future<Output = T> + Send + 'a>>;

/// Where the link hands what only the protocol can file (`procedure::filing::LinkFiling`
/// in the server; the rooms' direction keeps the machine below the procedure).
pub trait Filing: Send + Sync + std::fmt::Debug {
    /// Files a finished trial's result and record; `false` when the trial was no longer
    /// running (nothing stored).
    fn result<'a>(
        &'a self,
        result: &'a TrialResult,
        record: &'a Record,
    ) -> BoxFuture<'a, crate::error::Result<bool>>;
    /// Marks every trial the lost controller of `site` was running incomplete with `reason`;
    /// their ids.
    fn interrupted<'a>(
        &'a self,
        site: &'a str,
        reason: &'a str,
    ) -> BoxFuture<'a, crate::error::Result<Vec<i64>>>;
}

#[derive(Clone, Debug)]
pub struct ControllerLink {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    /// The site whose machine this controller drives.
    site: Arc<str>,
    tx: Mutex<Option<mpsc::Sender<Vec<u8>>>>,
    events: broadcast::Sender<ControllerEvent>,
    connected: watch::Sender<bool>,
    pending: Mutex<HashMap<TrialId, oneshot::Sender<Result<(), String>>>>,
    /// Bench trials (not rows of `trials`) waiting for their result and record.
    bench: Mutex<HashMap<TrialId, oneshot::Sender<(TrialResult, Record)>>>,
    /// Process id of the controller this server started, if any.
    pid: Mutex<Option<u32>>,
    /// The connected controller's rig: "sim" or "udp".
    rig: Mutex<Option<String>>,
    /// Whether the controller's e-stop is latched (as it last told us).
    estop: std::sync::atomic::AtomicBool,
    /// The E-stop's place on the control connection, written ahead of everything else.
    urgent: Mutex<Option<mpsc::Sender<Vec<u8>>>>,
    /// Why the link is down (or last went down), for the dashboard.
    down_because: Mutex<Option<String>>,
    /// The E-stop's own connection, when it is up.
    estop_path: Mutex<Option<mpsc::Sender<()>>>,
    /// Who waits for the controller to confirm an E-stop.
    estop_waiters: Mutex<Vec<oneshot::Sender<()>>>,
    /// The newest operator input of each trial not yet written: a flood of input coalesces
    /// here instead of queueing in front of anything (at most one entry per running trial).
    inputs: Mutex<HashMap<TrialId, (u64, f64)>>,
    input_ready: tokio::sync::Notify,
    /// Where results and lost trials are filed.
    filing: Arc<dyn Filing>,
    /// The server's E-stop latch, told to every new connection.
    latch: EStopLatch,
}

/// Samples per trial kept while its record arrives, channel by channel.
type Partial = HashMap<TrialId, Vec<Vec<f32>>>;

/// What every site's link tells the rest of the server, on one channel (the dashboard
/// hears them all; a station picks its trials' and its site's).
pub fn event_channel() -> broadcast::Sender<ControllerEvent> {
    broadcast::channel(16_384).0
}

/// How a site's controller is reached and authenticated, and how long it may be silent.
#[derive(Debug)]
pub struct LinkConfig {
    pub site: String,
    pub source: ControllerSource,
    /// The link key both ends prove (handed to a controller this server starts).
    pub key: LinkKey,
    pub silence: Duration,
}

impl ControllerLink {
    /// Starts the supervisor of `config.site`'s controller; the link comes up in the
    /// background and tells `events` what happens on it.
    pub fn start(
        config: LinkConfig,
        events: broadcast::Sender<ControllerEvent>,
        filing: Arc<dyn Filing>,
        latch: EStopLatch,
    ) -> Self {
        let LinkConfig {
            site,
            source,
            key,
            silence,
        } = config;
        let (connected, _) = watch::channel(false);
        let link = Self {
            inner: Arc::new(Inner {
                site: site.into(),
                tx: Mutex::new(None),
                events,
                connected,
                pending: Mutex::new(HashMap::new()),
                bench: Mutex::new(HashMap::new()),
                pid: Mutex::new(None),
                rig: Mutex::new(None),
                estop: std::sync::atomic::AtomicBool::new(false),
                urgent: Mutex::new(None),
                estop_path: Mutex::new(None),
                down_because: Mutex::new(None),
                estop_waiters: Mutex::new(Vec::new()),
                inputs: Mutex::new(HashMap::new()),
                input_ready: tokio::sync::Notify::new(),
                filing,
                latch,
            }),
        };
        tokio::spawn(supervise(link.clone(), source, key, silence));
        link
    }

    /// The site whose machine this controller drives.
    pub fn site(&self) -> &str {
        &self.inner.site
    }

    /// The site's name, to tell listeners which site an event is about.
    pub fn site_name(&self) -> Arc<str> {
        self.inner.site.clone()
    }

    /// Whether this site's machine must not move: the server's latch for it (of the site, or
    /// of every site) or the controller's, as it last told us.
    pub fn stopped(&self) -> bool {
        self.inner.latch.latched(self.site()) || self.estop_latched()
    }

    /// Whether the controller's E-stop is latched, as it last told us.
    pub fn estop_latched(&self) -> bool {
        self.inner.estop.load(std::sync::atomic::Ordering::SeqCst)
    }

    fn set_estop(&self, latched: bool) {
        if self
            .inner
            .estop
            .swap(latched, std::sync::atomic::Ordering::SeqCst)
            != latched
        {
            self.emit(ControllerEvent::EStop {
                site: self.site_name(),
                latched,
            });
        }
    }

    /// The rig of the connected controller ("sim" or "udp").
    pub fn rig(&self) -> Option<String> {
        self.inner
            .rig
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    pub fn pid(&self) -> Option<u32> {
        *self.inner.pid.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn is_connected(&self) -> bool {
        *self.inner.connected.borrow()
    }

    /// Operator input for a running trial: only the newest per trial waits to be written.
    pub fn send_input(&self, trial_id: TrialId, seq: u64, position_mm: f64) {
        if !self.is_connected() {
            return;
        }
        self.inner
            .inputs
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(trial_id, (seq, position_mm));
        self.inner.input_ready.notify_one();
    }

    /// The E-stop, sent on its own connection and, ahead of everything queued, on the
    /// control connection; `Ok` once the controller confirms it (its `e-stop` fault) on
    /// either, an error saying why when it could not be delivered or was not confirmed
    /// within `wait`.
    ///
    /// `Ok` holds the time from this call to the confirmation.
    pub async fn estop(&self, wait: Duration) -> Result<Duration, String> {
        let pressed = std::time::Instant::now();
        let (done, confirmed) = oneshot::channel();
        self.inner
            .estop_waiters
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(done);
        let own = self
            .inner
            .estop_path
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
            .is_some_and(|path| path.try_send(()).is_ok());
        let control = self
            .inner
            .urgent
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
            .is_some_and(|u| u.try_send(frame(&ServerToController::EStop {})).is_ok());
        if !own && !control {
            return Err("the controller is not connected".into());
        }
        match tokio::time::timeout(wait, confirmed).await {
            Ok(Ok(())) => Ok(pressed.elapsed()),
            Ok(Err(_)) => Err("the controller link went down before it confirmed".into()),
            Err(_) => Err(format!(
                "the controller did not confirm within {} ms",
                wait.as_millis()
            )),
        }
    }

    /// Why the link went down last (e.g. the controller failed authentication).
    pub fn down_because(&self) -> Option<String> {
        self.inner
            .down_because
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Whether the E-stop's own connection is up (the control connection carries it too).
    pub fn estop_path_up(&self) -> bool {
        self.inner
            .estop_path
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .is_some()
    }

    fn set_estop_path(&self, path: Option<mpsc::Sender<()>>) {
        *self
            .inner
            .estop_path
            .lock()
            .unwrap_or_else(|p| p.into_inner()) = path;
    }

    fn confirm_estop(&self) {
        for done in self
            .inner
            .estop_waiters
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .drain(..)
        {
            let _ = done.send(());
        }
    }

    /// Sends a message; fails if the controller is not connected.
    pub fn send(&self, msg: &ServerToController) -> Result<(), String> {
        let tx = self
            .inner
            .tx
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone();
        let tx = tx.ok_or_else(|| "the controller is not connected".to_string())?;
        let frame = framing::encode(msg).map_err(|e| e.to_string())?;
        tx.try_send(frame)
            .map_err(|_| "the controller link is congested".to_string())
    }

    /// Starts a trial and waits for the controller to confirm it (or say why not).
    pub async fn start_trial(&self, st: &StartTrial) -> Result<(), String> {
        let (done, wait) = oneshot::channel();
        self.inner
            .pending
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(st.trial_id, done);
        if let Err(e) = self.send(&ServerToController::StartTrial(Box::new(st.clone()))) {
            self.inner
                .pending
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .remove(&st.trial_id);
            return Err(e);
        }
        match tokio::time::timeout(Duration::from_secs(10), wait).await {
            Ok(Ok(r)) => r,
            _ => {
                self.inner
                    .pending
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .remove(&st.trial_id);
                Err("the controller did not confirm the start".into())
            }
        }
    }

    /// Runs a bench trial, which is not a row of `trials`: its result and record come back
    /// here instead of being filed. Fails if the link goes down before the result.
    pub async fn run_bench_trial(&self, st: &StartTrial) -> Result<(TrialResult, Record), String> {
        let (done, result) = oneshot::channel();
        self.bench_waiters().insert(st.trial_id, done);
        if let Err(e) = self.start_trial(st).await {
            self.bench_waiters().remove(&st.trial_id);
            return Err(e);
        }
        // The trial runs in real time; the record follows its end within seconds.
        let limit = Duration::from_secs_f64(st.duration_s + 30.0);
        match tokio::time::timeout(limit, result).await {
            Ok(Ok(r)) => Ok(r),
            Ok(Err(_)) => Err("the controller link went down during the run".into()),
            Err(_) => {
                self.bench_waiters().remove(&st.trial_id);
                Err("the controller sent no result".into())
            }
        }
    }

    fn bench_waiters(
        &self,
    ) -> std::sync::MutexGuard<'_, HashMap<TrialId, oneshot::Sender<(TrialResult, Record)>>> {
        self.inner.bench.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn resolve(&self, trial_id: TrialId, r: Result<(), String>) {
        if let Some(done) = self
            .inner
            .pending
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .remove(&trial_id)
        {
            let _ = done.send(r);
        }
    }

    /// Tells every listener (station and dashboard sockets) about an event.
    pub fn emit(&self, ev: ControllerEvent) {
        let _ = self.inner.events.send(ev);
    }
}

async fn supervise(
    link: ControllerLink,
    source: ControllerSource,
    key: LinkKey,
    silence: Duration,
) {
    let mut backoff = Duration::from_millis(100);
    loop {
        let (addr, mut child) = match &source {
            ControllerSource::Connect(a) => (*a, None),
            ControllerSource::Spawn { bin, args } => match process::spawn(bin, args, &key).await {
                Ok((a, c)) => {
                    *link.inner.pid.lock().unwrap_or_else(|p| p.into_inner()) = c.child.id();
                    (a, Some(c))
                }
                Err(e) => {
                    tracing::error!("could not start the controller ({}): {e:#}", bin.display());
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(5));
                    continue;
                }
            },
        };
        let run = session::control(&link, addr, &key, silence);
        let why = match &mut child {
            Some(c) => tokio::select! {
                why = run => why,
                status = c.child.wait() => format!("the controller process exited ({})", status.map(|s| s.to_string()).unwrap_or_else(|e| e.to_string())),
            },
            None => run.await,
        };
        if link.is_connected() {
            backoff = Duration::from_millis(100);
        }
        *link.inner.tx.lock().unwrap_or_else(|p| p.into_inner()) = None;
        *link.inner.urgent.lock().unwrap_or_else(|p| p.into_inner()) = None;
        link.set_estop_path(None);
        // Nobody waits for a confirmation that cannot come (their E-stop reports it).
        link.inner
            .estop_waiters
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clear();
        link.inner
            .inputs
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clear();
        if link.is_connected() {
            link.inner.connected.send_replace(false);
            link.emit(ControllerEvent::Link {
                site: link.site_name(),
                connected: false,
            });
        }
        tracing::error!(site = link.site(), "controller link down: {why}");
        *link
            .inner
            .down_because
            .lock()
            .unwrap_or_else(|p| p.into_inner()) = Some(why.clone());
        let pending: Vec<_> = link
            .inner
            .pending
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .drain()
            .collect();
        for (_, done) in pending {
            let _ = done.send(Err(why.clone()));
        }
        // A bench run waiting for a result that cannot come learns it now.
        link.bench_waiters().clear();
        match link
            .inner
            .filing
            .interrupted(link.site(), &format!("controller lost: {why}"))
            .await
        {
            Ok(ids) => {
                for id in ids {
                    tracing::warn!(trial = id, "trial marked incomplete: controller lost");
                    link.emit(ControllerEvent::TrialChanged { trial_id: id });
                }
            }
            Err(e) => tracing::error!("marking running trials incomplete: {e}"),
        }
        if let Some(mut c) = child {
            let _ = c.child.kill().await;
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(5));
    }
}
