//! The server's side of the controller link: spawns and supervises `bdft-controller serve`
//! (or connects to a given address), keeps the connection, forwards messages, gathers record
//! chunks and commits each trial's result in one transaction. When the controller dies or the
//! link drops, running trials are marked incomplete at once and the controller is restarted.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bdft_protocol::PROTOCOL_VERSION;
use bdft_protocol::controller_to_server::{ControllerToServer, LiveSample};
use bdft_protocol::framing;
use bdft_protocol::server_to_controller::{ServerToController, StartTrial};
use bdft_protocol::trial::{RECORD_CHANNELS, TrialId};
use sqlx::SqlitePool;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::sync::{broadcast, mpsc, oneshot, watch};

use super::filing;
use crate::store::records::Record;

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

/// How long the controller may stay silent before the link counts as lost: it sends a
/// heartbeat every 50 ms, so the default allows one to go missing. A hung controller
/// (stopped, deadlocked, its machine frozen) is noticed this fast: its trials are filed
/// incomplete and an E-stop is reported undelivered instead of answering ok.
pub const DEFAULT_SILENCE: Duration = Duration::from_millis(100);

/// How long a controller may take to answer the hello (it may still be starting).
const HELLO_TIMEOUT: Duration = Duration::from_secs(10);

/// What the rest of the server hears from the controller.
#[derive(Debug, Clone)]
pub enum ControllerEvent {
    Live(LiveSample),
    /// A trial's result is committed (or it was interrupted): its row changed.
    TrialChanged {
        trial_id: i64,
    },
    /// The link went up or down.
    Link {
        connected: bool,
    },
    /// The e-stop latch was set or cleared.
    EStop {
        latched: bool,
    },
}

#[derive(Clone, Debug)]
pub struct ControllerLink {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    tx: Mutex<Option<mpsc::Sender<Vec<u8>>>>,
    events: broadcast::Sender<ControllerEvent>,
    connected: watch::Sender<bool>,
    pending: Mutex<HashMap<TrialId, oneshot::Sender<Result<(), String>>>>,
    /// Process id of the controller this server started, if any.
    pid: Mutex<Option<u32>>,
    /// The connected controller's rig: "sim" or "udp".
    rig: Mutex<Option<String>>,
    /// Whether the controller's e-stop is latched (as it last told us).
    estop: std::sync::atomic::AtomicBool,
    /// The E-stop's own path to the writer, ahead of everything else.
    urgent: Mutex<Option<mpsc::Sender<Vec<u8>>>>,
    /// Who waits for the controller to confirm an E-stop.
    estop_waiters: Mutex<Vec<oneshot::Sender<()>>>,
    /// The newest operator input of each trial not yet written: a flood of input coalesces
    /// here instead of queueing in front of anything (at most one entry per running trial).
    inputs: Mutex<HashMap<TrialId, (u64, f64)>>,
    input_ready: tokio::sync::Notify,
}

/// Samples per trial kept while its record arrives, channel by channel.
type Partial = HashMap<TrialId, Vec<Vec<f32>>>;

impl ControllerLink {
    /// Starts the supervisor; the link comes up in the background.
    pub fn start(pool: SqlitePool, source: ControllerSource, silence: Duration) -> Self {
        let (events, _) = broadcast::channel(16_384);
        let (connected, _) = watch::channel(false);
        let link = Self {
            inner: Arc::new(Inner {
                tx: Mutex::new(None),
                events,
                connected,
                pending: Mutex::new(HashMap::new()),
                pid: Mutex::new(None),
                rig: Mutex::new(None),
                estop: std::sync::atomic::AtomicBool::new(false),
                urgent: Mutex::new(None),
                estop_waiters: Mutex::new(Vec::new()),
                inputs: Mutex::new(HashMap::new()),
                input_ready: tokio::sync::Notify::new(),
            }),
        };
        tokio::spawn(supervise(link.clone(), pool, source, silence));
        link
    }

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
            self.emit(ControllerEvent::EStop { latched });
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

    pub fn subscribe(&self) -> broadcast::Receiver<ControllerEvent> {
        self.inner.events.subscribe()
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

    /// The E-stop on its own path, written before anything queued; `Ok` once the controller
    /// confirms it (its `e-stop` fault), an error saying why when it could not be delivered
    /// or was not confirmed within `wait`.
    pub async fn estop(&self, wait: Duration) -> Result<(), String> {
        let (done, confirmed) = oneshot::channel();
        self.inner
            .estop_waiters
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(done);
        let urgent = self
            .inner
            .urgent
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
            .ok_or_else(|| "the controller is not connected".to_string())?;
        urgent
            .try_send(frame(&ServerToController::EStop {}))
            .map_err(|_| "the E-stop path is full".to_string())?;
        match tokio::time::timeout(wait, confirmed).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(_)) => Err("the controller link went down before it confirmed".into()),
            Err(_) => Err(format!(
                "the controller did not confirm within {} ms",
                wait.as_millis()
            )),
        }
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
    pool: SqlitePool,
    source: ControllerSource,
    silence: Duration,
) {
    let mut backoff = Duration::from_millis(100);
    loop {
        let (addr, mut child) = match &source {
            ControllerSource::Connect(a) => (*a, None),
            ControllerSource::Spawn { bin, args } => match spawn(bin, args).await {
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
        let why = match TcpStream::connect(addr).await {
            Ok(stream) => {
                backoff = Duration::from_millis(100);
                let run = connection(&link, &pool, stream, silence);
                match &mut child {
                    Some(c) => tokio::select! {
                        why = run => why,
                        status = c.child.wait() => format!("the controller process exited ({})", status.map(|s| s.to_string()).unwrap_or_else(|e| e.to_string())),
                    },
                    None => run.await,
                }
            }
            Err(e) => format!("cannot connect to the controller at {addr}: {e}"),
        };
        *link.inner.tx.lock().unwrap_or_else(|p| p.into_inner()) = None;
        *link.inner.urgent.lock().unwrap_or_else(|p| p.into_inner()) = None;
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
            link.emit(ControllerEvent::Link { connected: false });
        }
        tracing::error!("controller link down: {why}");
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
        match filing::interrupt_running(&pool, &format!("controller lost: {why}")).await {
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

/// Starts the controller on a free loopback port and reads the port it announces.
async fn spawn(bin: &PathBuf, args: &[String]) -> anyhow::Result<(SocketAddr, Supervised)> {
    let mut child = tokio::process::Command::new(bin)
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        // The controller exits when this pipe closes: if the server dies (even by SIGKILL),
        // no orphan keeps a machine's valve.
        .arg("--exit-with-stdin")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()?;
    let out = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
    let mut lines = BufReader::new(out).lines();
    let addr = tokio::time::timeout(Duration::from_secs(20), async {
        while let Some(line) = lines.next_line().await? {
            if let Some(a) = line.strip_prefix("listening on ") {
                return anyhow::Ok(a.trim().parse::<SocketAddr>()?);
            }
        }
        anyhow::bail!("the controller exited before announcing its address")
    })
    .await??;
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    tracing::info!(%addr, pid = child.id(), "controller started");
    let stdin = child.stdin.take();
    Ok((
        addr,
        Supervised {
            child,
            _stdin: stdin,
        },
    ))
}

/// A controller this server started. Holding its stdin open keeps it alive; when this
/// process dies, the pipe closes and the controller stops (`--exit-with-stdin`).
struct Supervised {
    child: tokio::process::Child,
    _stdin: Option<tokio::process::ChildStdin>,
}

/// The controller's messages, decoded by the protocol's one frame codec.
type Reader = tokio_util::codec::FramedRead<tokio::net::tcp::OwnedReadHalf, framing::ServerCodec>;

async fn read_frame(r: &mut Reader) -> Result<ControllerToServer, String> {
    use futures_util::StreamExt;
    match r.next().await {
        Some(Ok(Ok(msg))) => Ok(msg),
        Some(Ok(Err(malformed))) => Err(format!("the controller sent {malformed}")),
        Some(Err(e)) => Err(format!("link closed ({e})")),
        None => Err("link closed".to_string()),
    }
}

/// A message the server always sends, as a frame (they are a few bytes).
fn frame(msg: &ServerToController) -> Vec<u8> {
    framing::encode(msg).expect("a control message fits a frame")
}

/// Runs one connection until it fails; returns why.
async fn connection(
    link: &ControllerLink,
    pool: &SqlitePool,
    stream: TcpStream,
    silence: Duration,
) -> String {
    let _ = stream.set_nodelay(true);
    let (rd, mut wr) = stream.into_split();
    let mut rd: Reader = tokio_util::codec::FramedRead::new(rd, framing::ServerCodec::default());
    let hello = frame(&ServerToController::Hello {
        protocol_version: PROTOCOL_VERSION,
        client: format!("bdft-server {}", env!("CARGO_PKG_VERSION")),
    });
    if let Err(e) = wr.write_all(&hello).await {
        return format!("hello failed: {e}");
    }
    let ack = tokio::time::timeout(HELLO_TIMEOUT, read_frame(&mut rd))
        .await
        .unwrap_or_else(|_| Err(format!("no answer to hello within {HELLO_TIMEOUT:?}")));
    match ack {
        Ok(ControllerToServer::HelloAck {
            controller,
            rig,
            lockstep,
            ..
        }) => {
            tracing::info!(controller, rig, lockstep, "controller connected");
            *link.inner.rig.lock().unwrap_or_else(|p| p.into_inner()) = Some(rig);
            // The controller starts latched; the server's latch decides. If the database
            // cannot say, it stays latched.
            let latched = crate::store::latch::latched(pool).await.unwrap_or(true);
            let latch = if latched {
                ServerToController::EStop {}
            } else {
                ServerToController::ResetEStop {}
            };
            if let Err(e) = wr.write_all(&frame(&latch)).await {
                return format!("sending the E-stop latch failed: {e}");
            }
            // The answer tells the link the controller's latch.
            let _ = wr.write_all(&frame(&ServerToController::Status {})).await;
        }
        Ok(other) => return format!("unexpected answer to hello: {other:?}"),
        Err(e) => return e,
    }
    let (tx, mut rx) = mpsc::channel::<Vec<u8>>(1024);
    *link.inner.tx.lock().unwrap_or_else(|p| p.into_inner()) = Some(tx.clone());
    let (urgent_tx, mut urgent) = mpsc::channel::<Vec<u8>>(8);
    *link.inner.urgent.lock().unwrap_or_else(|p| p.into_inner()) = Some(urgent_tx);
    link.inner.connected.send_replace(true);
    link.emit(ControllerEvent::Link { connected: true });
    let writer = async {
        let mut beat = tokio::time::interval(Duration::from_millis(200));
        let mut seq = 0;
        loop {
            // Biased: the E-stop first, then the newest input, then everything else.
            tokio::select! {
                biased;
                Some(f) = urgent.recv() => if let Err(e) = wr.write_all(&f).await { return format!("write failed: {e}") },
                _ = link.inner.input_ready.notified() => {
                    let inputs: Vec<_> = link.inner.inputs.lock().unwrap_or_else(|p| p.into_inner()).drain().collect();
                    for (trial_id, (seq, position_mm)) in inputs {
                        let f = frame(&ServerToController::OperatorInput { trial_id, seq, position_mm });
                        if let Err(e) = wr.write_all(&f).await { return format!("write failed: {e}") }
                    }
                }
                f = rx.recv() => match f {
                    Some(f) => if let Err(e) = wr.write_all(&f).await { return format!("write failed: {e}") },
                    None => return "writer closed".to_string(),
                },
                _ = beat.tick() => {
                    seq += 1;
                    if let Err(e) = wr.write_all(&frame(&ServerToController::Heartbeat { seq })).await {
                        return format!("write failed: {e}");
                    }
                }
            }
        }
    };
    let reader = async {
        let mut partial: Partial = HashMap::new();
        loop {
            let msg = match tokio::time::timeout(silence, read_frame(&mut rd)).await {
                Ok(Ok(m)) => m,
                Ok(Err(e)) => return e,
                Err(_) => {
                    return format!(
                        "the controller sent nothing for {} ms (it heartbeats every 50 ms)",
                        silence.as_millis()
                    );
                }
            };
            handle(link, pool, &mut partial, msg).await;
        }
    };
    drop(tx);
    tokio::select! {
        why = writer => why,
        why = reader => why,
    }
}

async fn handle(
    link: &ControllerLink,
    pool: &SqlitePool,
    partial: &mut Partial,
    msg: ControllerToServer,
) {
    match msg {
        ControllerToServer::Live(s) => link.emit(ControllerEvent::Live(s)),
        ControllerToServer::TrialStarted { trial_id, .. } => link.resolve(trial_id, Ok(())),
        ControllerToServer::Rejected {
            trial_id: Some(id),
            reason,
        } => link.resolve(id, Err(reason)),
        ControllerToServer::Rejected {
            trial_id: None,
            reason,
        } => tracing::warn!(reason, "the controller rejected a message"),
        ControllerToServer::RecordChunk(c) => {
            let chans = partial
                .entry(c.trial_id)
                .or_insert_with(|| vec![Vec::new(); RECORD_CHANNELS.len()]);
            for (all, part) in chans.iter_mut().zip(c.channels) {
                all.extend(part);
            }
        }
        ControllerToServer::TrialResult(r) => {
            let channels = partial.remove(&r.trial_id).unwrap_or_default();
            let record = Record { dt: r.dt, channels };
            match filing::file_result(pool, "controller", &r, &record).await {
                Ok(true) => {
                    tracing::info!(trial = r.trial_id, outcome = ?r.outcome, "trial result stored")
                }
                Ok(false) => tracing::warn!(
                    trial = r.trial_id,
                    "result for a trial that is no longer running; dropped"
                ),
                Err(e) => tracing::error!(trial = r.trial_id, "storing the result failed: {e}"),
            }
            link.emit(ControllerEvent::TrialChanged {
                trial_id: r.trial_id as i64,
            });
        }
        ControllerToServer::Fault {
            trial_id,
            kind,
            message,
        } => {
            if trial_id.is_none() && kind == bdft_protocol::trial::FaultKind::EStop {
                link.set_estop(true);
                link.confirm_estop();
            }
            tracing::warn!(?trial_id, ?kind, message, "controller fault")
        }
        ControllerToServer::Status(st) => link.set_estop(st.estop_latched),
        ControllerToServer::Heartbeat { .. }
        | ControllerToServer::HelloAck { .. }
        | ControllerToServer::Stepped { .. } => {}
    }
}
