//! The event pump: every millisecond the loop's events go to the connection whose trials
//! they belong to — a trial's start, its live samples (dropped rather than delayed when the
//! link is congested), a finished trial's record in chunks and its result, lockstep steps.

use std::time::Duration;

use bdft_protocol::controller_to_server::{ControllerToServer, RecordChunk, TrialResult};
use bdft_protocol::trial::{FaultKind, Outcome, TimingSummary};

use super::state::{Io, Shared, lock};
use crate::runtime::rt_loop::Event;
use crate::runtime::slot::TrialSlot;

/// Samples per record chunk.
const CHUNK: usize = 1000;

/// Forwards the loop's events every millisecond.
pub(super) async fn pump(io: Shared) {
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

impl Io {
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
            exposure: Some(slot.runner.exposure().0),
            cancellation_off_at_s: slot.runner.cancellation_off_at_s(),
            adaptation: slot.adaptation(),
        };
        msgs.push(ControllerToServer::TrialResult(Box::new(result)));
        (entry.map(|e| e.conn), msgs)
    }
}
