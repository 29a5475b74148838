//! What the I/O side's tasks share, behind one mutex ([`Shared`]): the link's configuration,
//! the one control connection, the running trials and their UDP input channels, and the
//! counts of what was rejected; with the loss of the link (every trial stopped), the status
//! report and the rejection answer, which every task uses.

use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use bdft_protocol::controller_to_server::{ControllerToServer, Status};
use bdft_protocol::link_auth::LinkKey;
use bdft_protocol::trial::{FaultKind, TrialId};
use tokio::sync::mpsc;

use crate::lsl::publisher::Publisher;
use crate::runtime::handoff::InputCell;
use crate::runtime::rt_loop::{Command, LoopHandle};

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
    /// The stations' LSL signal streams (`--lsl`).
    pub lsl: Option<Arc<Publisher>>,
}

/// Messages queued for a connection's writer, which frames them ([`ControllerCodec`]).
pub(super) type Outbox = mpsc::Sender<ControllerToServer>;

pub(super) struct Conn {
    pub(super) id: u64,
    pub(super) tx: Outbox,
}

pub(super) struct TrialEntry {
    pub(super) conn: u64,
    pub(super) input: Option<Arc<InputCell>>,
    pub(super) channel: Option<u32>,
    pub(super) abort_reason: Option<String>,
    pub(super) uses_rig: bool,
}

pub(super) struct Io {
    pub(super) cfg: LinkConfig,
    pub(super) rt: LoopHandle,
    /// The one control connection, if a server is connected.
    pub(super) conn: Option<Conn>,
    pub(super) next_conn: u64,
    pub(super) trials: HashMap<TrialId, TrialEntry>,
    /// The UDP input channels in use, each feeding its trial's input cell.
    pub(super) channels: HashMap<u32, Arc<InputCell>>,
    rejected_messages: u64,
    pub(super) rejected_inputs: u64,
    pub(super) rejected_datagrams: u64,
    /// When the server last sent anything (the link watchdog's clock).
    pub(super) last_rx: Instant,
}

pub(super) type Shared = Arc<Mutex<Io>>;

pub(super) fn lock(io: &Shared) -> MutexGuard<'_, Io> {
    io.lock().unwrap_or_else(|p| p.into_inner())
}

impl Io {
    pub(super) fn new(cfg: LinkConfig, rt: LoopHandle) -> Self {
        Self {
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
        }
    }

    /// The current connection, if any, with its outbox.
    pub(super) fn sender(&self) -> Option<(u64, Outbox)> {
        self.conn.as_ref().map(|c| (c.id, c.tx.clone()))
    }

    pub(super) fn link_lost(&mut self, conn: u64, why: &str) {
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

    pub(super) fn status(&self) -> ControllerToServer {
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

    pub(super) fn reject(&mut self, reason: String) -> Vec<ControllerToServer> {
        self.reject_trial(None, reason)
    }

    pub(super) fn reject_trial(
        &mut self,
        trial_id: Option<TrialId>,
        reason: String,
    ) -> Vec<ControllerToServer> {
        self.rejected_messages += 1;
        tracing::info!(reason, "rejected a message from the server");
        vec![ControllerToServer::Rejected { trial_id, reason }]
    }
}
