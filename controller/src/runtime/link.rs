//! The I/O side of `bdft-controller serve`: the TCP link to the server (one at a time,
//! framed by `bdft_protocol::framing::ControllerCodec`), the optional UDP input port of a
//! haptic-device host, and the pump that forwards the loop's events. Runs on a
//! single-threaded tokio runtime beside the real-time thread.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use bdft_protocol::PROTOCOL_VERSION;
use bdft_protocol::controller_to_server::{ControllerToServer, RecordChunk, Status, TrialResult};
use bdft_protocol::framing::FrameError;
use bdft_protocol::link_auth::{LinkKey, LinkRole};
use bdft_protocol::server_to_controller::{ServerToController, StartTrial};
use bdft_protocol::trial::{FaultKind, InputSource, Outcome, TimingSummary, TrialId};
use futures_util::{SinkExt, StreamExt};
use tokio::net::{TcpListener, TcpStream, UdpSocket};
use tokio::sync::mpsc;

use super::estop_path;
use super::handoff::{InputCell, InputSample};
use super::handshake::{self, Pending, PendingGate, Reader, Writer};
use super::input_port;
use super::rt_loop::{Command, Event, LoopHandle};
use super::setup::build_slot;
use super::slot::TrialSlot;

/// Samples per record chunk.
const CHUNK: usize = 1000;
/// Largest |operator input| accepted (mm of device travel).
pub(super) const MAX_INPUT_MM: f64 = 1000.0;

#[derive(Debug, Clone)]
pub struct LinkConfig {
    pub dt: f64,
    pub lockstep: bool,
    pub real_rig: bool,
    pub max_trials: usize,
    /// Silence from the server for this long counts as a lost link.
    pub link_timeout: Duration,
    pub input_udp: bool,
    /// The key a server must prove before anything it sends is read.
    pub key: LinkKey,
}

/// Messages queued for a connection's writer, which frames them ([`ControllerCodec`]).
type Outbox = mpsc::Sender<ControllerToServer>;

struct Conn {
    id: u64,
    tx: Outbox,
}

struct TrialEntry {
    conn: u64,
    input: Option<Arc<InputCell>>,
    channel: Option<u32>,
    abort_reason: Option<String>,
    uses_rig: bool,
}

pub(super) struct Io {
    cfg: LinkConfig,
    pub(super) rt: LoopHandle,
    conn: Option<Conn>,
    next_conn: u64,
    trials: HashMap<TrialId, TrialEntry>,
    pub(super) channels: HashMap<u32, Arc<InputCell>>,
    rejected_messages: u64,
    rejected_inputs: u64,
    pub(super) rejected_datagrams: u64,
    last_rx: Instant,
}

pub(super) type Shared = Arc<Mutex<Io>>;

pub(super) fn lock(io: &Shared) -> MutexGuard<'_, Io> {
    io.lock().unwrap_or_else(|p| p.into_inner())
}

impl Io {
    /// The current connection, if any, with its outbox.
    fn sender(&self) -> Option<(u64, Outbox)> {
        self.conn.as_ref().map(|c| (c.id, c.tx.clone()))
    }

    fn link_lost(&mut self, conn: u64, why: &str) {
        if self.conn.as_ref().is_some_and(|c| c.id == conn) {
            tracing::warn!(conn, why, "server link lost: stopping every running trial");
            self.conn = None;
            // Forget the lost link's trials now (their results have nowhere to go), so a new
            // server sees a free controller at once.
            let lost: Vec<TrialId> = self
                .trials
                .iter()
                .filter(|(_, t)| t.conn == conn)
                .map(|(id, _)| *id)
                .collect();
            for id in lost {
                if let Some(ch) = self.trials.remove(&id).and_then(|t| t.channel) {
                    self.channels.remove(&ch);
                }
            }
            if self.rt.send(Command::StopAll(FaultKind::LinkLost)).is_err() {
                tracing::error!("command queue full while stopping trials after link loss");
            }
        }
    }

    fn status(&self) -> ControllerToServer {
        let sh = &self.rt.shared;
        let mut running: Vec<TrialId> = self.trials.keys().copied().collect();
        running.sort_unstable();
        ControllerToServer::Status(Box::new(Status {
            estop_latched: sh.estop.load(Ordering::SeqCst),
            running_trials: running,
            tick: sh.tick.load(Ordering::Relaxed),
            overruns: sh.overruns.load(Ordering::Relaxed),
            rejected_messages: self.rejected_messages + self.rejected_inputs,
            rejected_datagrams: self.rejected_datagrams + sh.rig_rejected.load(Ordering::Relaxed),
            realtime: sh.realtime.get().cloned().unwrap_or_default(),
            rig: if self.cfg.real_rig { "udp" } else { "sim" }.into(),
            lockstep: self.cfg.lockstep,
        }))
    }

    fn reject(&mut self, reason: String) -> Vec<ControllerToServer> {
        self.reject_trial(None, reason)
    }

    fn reject_trial(
        &mut self,
        trial_id: Option<TrialId>,
        reason: String,
    ) -> Vec<ControllerToServer> {
        self.rejected_messages += 1;
        tracing::info!(reason, "rejected a message from the server");
        vec![ControllerToServer::Rejected { trial_id, reason }]
    }

    /// Acts on one message from connection `conn`; returns the messages to answer with.
    fn handle(&mut self, conn: u64, msg: ServerToController) -> Vec<ControllerToServer> {
        self.last_rx = Instant::now();
        match msg {
            ServerToController::Hello { .. } => self.reject("hello was already exchanged".into()),
            ServerToController::StartTrial(st) => self.start(conn, &st),
            ServerToController::AbortTrial { trial_id, reason } => {
                match self.trials.get_mut(&trial_id) {
                    Some(t) => {
                        t.abort_reason = Some(reason);
                        match self.rt.send(Command::Abort(trial_id)) {
                            Ok(()) => vec![],
                            Err(_) => {
                                self.reject("the controller is overloaded; abort not queued".into())
                            }
                        }
                    }
                    None => self.reject(format!("abort: trial {trial_id} is not running")),
                }
            }
            ServerToController::OperatorInput {
                trial_id,
                seq,
                position_mm,
            } => {
                let cell = self.trials.get(&trial_id).and_then(|t| t.input.clone());
                match cell {
                    Some(cell) if position_mm.is_finite() && position_mm.abs() <= MAX_INPUT_MM => {
                        let tick = self.rt.shared.tick.load(Ordering::Acquire);
                        cell.write(InputSample {
                            position_mm,
                            seq,
                            arrival_tick: tick,
                        });
                    }
                    // Counted, not answered: a page streaming at 250 Hz past a trial's end
                    // would otherwise flood the link with rejections.
                    _ => self.rejected_inputs += 1,
                }
                vec![]
            }
            ServerToController::Heartbeat { .. } => vec![],
            ServerToController::EStop {} => {
                self.rt.shared.estop.store(true, Ordering::SeqCst);
                let _ = self.rt.send(Command::EStop);
                tracing::warn!("E-STOP: every valve to zero, trials stopped, latched until reset");
                vec![estop_path::confirmation()]
            }
            ServerToController::ResetEStop {} => {
                match self.rt.send(Command::ResetEStop) {
                    Ok(()) => self.rt.shared.estop.store(false, Ordering::SeqCst),
                    Err(_) => {
                        return self.reject(
                            "the controller is overloaded; e-stop reset not queued".into(),
                        );
                    }
                }
                tracing::info!("e-stop reset");
                vec![self.status()]
            }
            ServerToController::Status {} => vec![self.status()],
            ServerToController::Step { ticks } => {
                if !self.cfg.lockstep {
                    return self.reject(
                        "step is only accepted in lockstep mode (serve --lockstep)".into(),
                    );
                }
                match self.rt.send(Command::Step(ticks)) {
                    Ok(()) => vec![],
                    Err(_) => self.reject("the controller is overloaded; step not queued".into()),
                }
            }
        }
    }

    fn start(&mut self, conn: u64, st: &StartTrial) -> Vec<ControllerToServer> {
        let id = st.trial_id;
        if self.rt.shared.estop.load(Ordering::SeqCst) {
            return self.reject_trial(
                Some(id),
                format!("start trial {id}: e-stop is latched; send reset_e_stop first"),
            );
        }
        if self.trials.contains_key(&id) {
            return self.reject_trial(
                Some(id),
                format!("start trial {id}: a trial with this id is running"),
            );
        }
        if self.trials.len() >= self.cfg.max_trials {
            return self.reject_trial(Some(id), format!(
                "start trial {id}: {} trials are running, the most this controller runs at once",
                self.cfg.max_trials
            ));
        }
        if self.cfg.real_rig && self.trials.values().any(|t| t.uses_rig) {
            return self.reject_trial(
                Some(id),
                format!("start trial {id}: the real rig is in use by another trial"),
            );
        }
        let channel = match st.input {
            InputSource::Udp { channel } => {
                if !self.cfg.input_udp {
                    return self.reject_trial(
                        Some(id),
                        format!("start trial {id}: UDP input needs serve --input-udp ADDR"),
                    );
                }
                if self.channels.contains_key(&channel) {
                    return self.reject_trial(
                        Some(id),
                        format!("start trial {id}: input channel {channel} is in use"),
                    );
                }
                Some(channel)
            }
            _ => None,
        };
        let built = match build_slot(st, self.cfg.dt, self.cfg.real_rig) {
            Ok(b) => b,
            Err(e) => return self.reject_trial(Some(id), format!("start trial {id}: {e}")),
        };
        let uses_rig = built.slot.uses_rig();
        if let (Some(ch), Some(cell)) = (channel, &built.input) {
            self.channels.insert(ch, Arc::clone(cell));
        }
        if let Err(Command::Start(_)) = self.rt.send(Command::Start(built.slot)) {
            if let Some(ch) = channel {
                self.channels.remove(&ch);
            }
            return self.reject_trial(
                Some(id),
                format!("start trial {id}: the controller is overloaded"),
            );
        }
        let input = if channel.is_some() { None } else { built.input };
        self.trials.insert(
            id,
            TrialEntry {
                conn,
                input,
                channel,
                abort_reason: None,
                uses_rig,
            },
        );
        tracing::info!(trial = id, compensator = %st.compensator.kind(), seat = st.station.as_str(), k_bf = st.k_bf, "trial starting");
        vec![]
    }

    /// The messages that report an ended trial: its record in chunks, then the result.
    fn finished(&mut self, slot: Box<TrialSlot>) -> (Option<u64>, Vec<ControllerToServer>) {
        let entry = self.trials.remove(&slot.trial_id);
        if let Some(ch) = entry.as_ref().and_then(|e| e.channel) {
            self.channels.remove(&ch);
        }
        let outcome = slot.outcome(
            self.cfg.dt,
            entry.as_ref().and_then(|e| e.abort_reason.clone()),
        );
        tracing::info!(trial = slot.trial_id, ?outcome, "trial ended");
        let mut msgs = Vec::with_capacity(slot.record.len() / CHUNK + 2);
        if let (Outcome::Faulted { fault, message }, Some(_)) = (&outcome, entry.as_ref()) {
            if *fault != FaultKind::EStop && *fault != FaultKind::LinkLost {
                msgs.push(ControllerToServer::Fault {
                    trial_id: Some(slot.trial_id),
                    kind: *fault,
                    message: message.clone(),
                });
            }
        }
        let n_chunks = slot.record.len().div_ceil(CHUNK);
        for index in 0..n_chunks {
            let from = index * CHUNK;
            msgs.push(ControllerToServer::RecordChunk(RecordChunk {
                trial_id: slot.trial_id,
                index: index as u32,
                start_tick: from as u64,
                channels: slot.record_channels(from, (from + CHUNK).min(slot.record.len())),
            }));
        }
        let result = TrialResult {
            trial_id: slot.trial_id,
            outcome,
            metrics: slot.runner.metrics(),
            timing: TimingSummary {
                ticks: slot.wake.count(),
                overruns: slot.overruns,
                wake_latency_us: slot.wake.percentiles_us(),
                compute_us: slot.compute.percentiles_us(),
            },
            dt: self.cfg.dt,
            record_chunks: n_chunks as u32,
        };
        msgs.push(ControllerToServer::TrialResult(Box::new(result)));
        (entry.map(|e| e.conn), msgs)
    }
}

/// Runs the I/O side until `shutdown` resolves.
pub async fn run(
    cfg: LinkConfig,
    rt: LoopHandle,
    listener: TcpListener,
    input_udp: Option<UdpSocket>,
    shutdown: impl std::future::Future<Output = ()>,
) {
    let io: Shared = Arc::new(Mutex::new(Io {
        cfg,
        rt,
        conn: None,
        next_conn: 1,
        trials: HashMap::new(),
        channels: HashMap::new(),
        rejected_messages: 0,
        rejected_inputs: 0,
        rejected_datagrams: 0,
        last_rx: Instant::now(),
    }));
    let tasks = [
        tokio::spawn(accept(Arc::clone(&io), listener)),
        tokio::spawn(pump(Arc::clone(&io))),
        tokio::spawn(heartbeat(Arc::clone(&io))),
    ];
    let udp = input_udp.map(|s| tokio::spawn(input_port::run(Arc::clone(&io), s)));
    shutdown.await;
    for t in tasks.iter().chain(udp.iter()) {
        t.abort();
    }
    for t in tasks {
        let _ = t.await;
    }
    if let Some(t) = udp {
        let _ = t.await;
    }
    // Connection tasks may still hold the state; stop the loop through it (every trial ends,
    // valves to zero) rather than waiting for them.
    let mut g = lock(&io);
    if g.rt.send(Command::Shutdown).is_err() {
        tracing::error!("could not queue the loop's shutdown");
    }
}

async fn accept(io: Shared, listener: TcpListener) {
    let gate = Arc::new(PendingGate::default());
    let estop_open = Arc::new(AtomicUsize::new(0));
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        // Over the cap the socket is closed unread: nobody unauthenticated gets more.
        let Some(pending) = gate.admit(peer.ip()) else {
            tracing::debug!(%peer, "too many connections in the handshake; closed");
            continue;
        };
        let _ = stream.set_nodelay(true);
        tokio::spawn(connection(
            Arc::clone(&io),
            Arc::clone(&estop_open),
            stream,
            peer,
            pending,
        ));
    }
}

async fn connection(
    io: Shared,
    estop_open: Arc<AtomicUsize>,
    stream: TcpStream,
    peer: SocketAddr,
    pending: Pending,
) {
    let (mut rd, mut wr) = handshake::frame(stream);
    let key = lock(&io).cfg.key.clone();
    let auth = match handshake::authenticate(&mut rd, &mut wr, &key).await {
        Ok(auth) => auth,
        Err(why) => {
            tracing::warn!(%peer, why, "connection refused");
            return;
        }
    };
    drop(pending);
    let ack = {
        let g = lock(&io);
        ControllerToServer::HelloAck {
            protocol_version: PROTOCOL_VERSION,
            proof: auth.proof,
            controller: format!("bdft-controller {}", env!("CARGO_PKG_VERSION")),
            loop_rate_hz: 1.0 / g.cfg.dt,
            rig: if g.cfg.real_rig { "udp" } else { "sim" }.into(),
            lockstep: g.cfg.lockstep,
        }
    };
    match auth.role {
        LinkRole::Control => control(io, rd, wr, peer, auth.client, ack).await,
        LinkRole::EStop => {
            if wr.send(ack).await.is_err() {
                return;
            }
            tracing::info!(%peer, client = auth.client, "e-stop path connected");
            let (loop_state, silence) = {
                let g = lock(&io);
                (Arc::clone(&g.rt.shared), g.cfg.link_timeout)
            };
            estop_path::serve(loop_state, estop_open, rd, wr, silence, || {
                lock(&io).status()
            })
            .await;
        }
    }
}

/// The control connection: one at a time; trials, input, records, the latch.
async fn control(
    io: Shared,
    mut rd: Reader,
    mut wr: Writer,
    peer: SocketAddr,
    client: String,
    ack: ControllerToServer,
) {
    let (tx, mut rx) = mpsc::channel::<ControllerToServer>(16_384);
    let accepted = {
        let mut g = lock(&io);
        if g.conn.is_some() {
            None
        } else {
            let id = g.next_conn;
            g.next_conn += 1;
            g.conn = Some(Conn { id, tx: tx.clone() });
            g.last_rx = Instant::now();
            tracing::info!(%peer, client, conn = id, "server connected");
            Some(id)
        }
    };
    let Some(conn) = accepted else {
        let _ = wr
            .send(ControllerToServer::Rejected {
                trial_id: None,
                reason: "another server is connected to this controller".into(),
            })
            .await;
        return;
    };
    let writer_io = Arc::clone(&io);
    let writer = tokio::spawn(async move {
        if wr.send(ack).await.is_err() {
            return;
        }
        // Frame everything queued, then flush once: a record's chunks go out together.
        while let Some(msg) = rx.recv().await {
            let mut sent = wr.feed(msg).await;
            while sent.is_ok() {
                match rx.try_recv() {
                    Ok(msg) => sent = wr.feed(msg).await,
                    Err(_) => break,
                }
            }
            if let Err(e) = sent.and(wr.flush().await) {
                lock(&writer_io).link_lost(conn, &format!("write failed: {e}"));
                return;
            }
        }
    });
    drop(tx);
    let mut since_yield = 0u32;
    loop {
        // A flood of frames is always ready to read; hand the runtime back now and then so
        // the E-stop path (same thread) is never kept waiting behind it.
        since_yield += 1;
        if since_yield == 32 {
            since_yield = 0;
            tokio::task::yield_now().await;
        }
        let replies = match rd.next().await {
            Some(Ok(Ok(msg))) => {
                let mut g = lock(&io);
                if g.conn.as_ref().is_none_or(|c| c.id != conn) {
                    break; // replaced or timed out
                }
                let replies = g.handle(conn, msg);
                (replies, g.sender())
            }
            // A frame that is not a message: answered, and the link goes on.
            Some(Ok(Err(malformed))) => {
                let mut g = lock(&io);
                (g.reject(malformed.to_string()), g.sender())
            }
            None => {
                lock(&io).link_lost(conn, "connection closed");
                break;
            }
            Some(Err(FrameError::Io(e))) => {
                lock(&io).link_lost(conn, &format!("connection failed: {e}"));
                break;
            }
            // A frame we cannot delimit leaves the stream unusable.
            Some(Err(e)) => {
                lock(&io).link_lost(conn, &format!("bad frame: {e}"));
                break;
            }
        };
        if let (replies, Some((_, tx))) = replies {
            for msg in replies {
                let _ = tx.send(msg).await;
            }
        }
    }
    writer.abort();
}

/// Forwards the loop's events every millisecond.
async fn pump(io: Shared) {
    let mut every = tokio::time::interval(Duration::from_millis(1));
    every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        every.tick().await;
        let mut outgoing: Vec<(u64, Vec<ControllerToServer>)> = Vec::new();
        let sender = {
            let mut g = lock(&io);
            let sender = g.sender();
            while let Ok(ev) = g.rt.events.pop() {
                match ev {
                    Event::Started { trial_id, tick } => {
                        if let Some(e) = g.trials.get(&trial_id) {
                            outgoing.push((
                                e.conn,
                                vec![ControllerToServer::TrialStarted { trial_id, tick }],
                            ));
                        }
                    }
                    Event::Live(s) => {
                        if let (Some((id, tx)), Some(e)) = (&sender, g.trials.get(&s.trial_id)) {
                            if e.conn == *id {
                                // Dropped rather than delayed when the link is congested.
                                let _ = tx.try_send(ControllerToServer::Live(s));
                            }
                        }
                    }
                    Event::Finished(slot) => {
                        let (conn, msgs) = g.finished(slot);
                        if let Some(conn) = conn {
                            outgoing.push((conn, msgs));
                        }
                    }
                    Event::Stepped { tick } => {
                        if let Some((id, _)) = &sender {
                            outgoing.push((*id, vec![ControllerToServer::Stepped { tick }]));
                        }
                    }
                }
            }
            sender
        };
        if let Some((id, tx)) = sender {
            for (conn, msgs) in outgoing {
                if conn == id {
                    for msg in msgs {
                        if tx.send(msg).await.is_err() {
                            break;
                        }
                    }
                }
            }
        }
    }
}

/// Sends a heartbeat every 25 ms (the server counts 75 ms of silence as a hang) and declares
/// the link lost after the configured silence.
async fn heartbeat(io: Shared) {
    let mut every = tokio::time::interval(Duration::from_millis(25));
    let mut seq = 0u64;
    loop {
        every.tick().await;
        seq += 1;
        let sender = {
            let mut g = lock(&io);
            if let Some((id, _)) = g.sender() {
                if g.last_rx.elapsed() > g.cfg.link_timeout {
                    let why = format!("no message for {} ms", g.cfg.link_timeout.as_millis());
                    g.link_lost(id, &why);
                }
            }
            g.sender()
        };
        if let Some((_, tx)) = sender {
            let _ = tx.try_send(ControllerToServer::Heartbeat { seq });
        }
    }
}
