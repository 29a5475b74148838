//! What a server asks of the controller, checked before it is acted on: every message of the
//! control link (abort, operator input, E-stop and its reset, status, lockstep steps) and
//! the rules a trial must pass to start (no latched E-stop, a free id, a free slot, the one
//! real rig, a free UDP input channel, parameters that build).

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::server_to_controller::{LslStation, ServerToController, StartTrial};
use bdft_protocol::trial::InputSource;

use super::state::{Io, TrialEntry};
use crate::lsl::streams::StreamTags;
use crate::runtime::estop_path;
use crate::runtime::handoff::InputSample;
use crate::runtime::rt_loop::Command;
use crate::runtime::setup::build_slot;

/// Largest |operator input| accepted (mm of device travel), from the server or a haptic host.
pub(super) const MAX_INPUT_MM: f64 = 1000.0;

impl Io {
    /// Acts on one message from connection `conn`; returns the messages to answer with.
    pub(super) fn handle(&mut self, conn: u64, msg: ServerToController) -> Vec<ControllerToServer> {
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
            ServerToController::LslStation(station) => self.lsl_station(&station),
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

    /// Publishes the station's LSL signal stream and routes the named trial to it. A
    /// controller without `--lsl` refuses: it opens no LSL socket.
    fn lsl_station(&mut self, station: &LslStation) -> Vec<ControllerToServer> {
        let Some(publisher) = self.cfg.lsl.clone() else {
            return self.reject("LSL is off on this controller (serve --lsl)".into());
        };
        if let Err(e) = station.check() {
            return self.reject(e);
        }
        let tags = StreamTags {
            station_id: station.station_id,
            station: station.station.clone(),
            study_id: station.study_id,
            study: station.study.clone(),
            subject: station.subject.clone(),
        };
        if let Err(e) = publisher.station(tags) {
            return self.reject(format!("the LSL stream could not be published: {e}"));
        }
        if let Some(trial) = station.trial_id {
            publisher.route(trial, station.station_id);
        }
        vec![]
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
        tracing::info!(trial = id, compensator = %st.compensator.kind(), seat = st.seat.as_str(), k_bf = st.k_bf, "trial starting");
        vec![]
    }
}
