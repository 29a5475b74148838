//! The control connection: trials, operator input, record chunks and results, the latch,
//! heartbeats; the E-stop's own path is kept beside it for as long as it runs.

use std::collections::HashMap;
use std::time::Duration;

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::link_auth::{LinkKey, LinkRole};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::RECORD_CHANNELS;
use sqlx::AnyPool;
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

use super::connection::{frame, open, read_frame};
use super::{ControllerEvent, ControllerLink, HEARTBEAT, Partial, estop_path};
use crate::store::records::Record;

/// Runs the control connection until it fails; returns why.
pub(super) async fn control(
    link: &ControllerLink,
    pool: &AnyPool,
    addr: std::net::SocketAddr,
    key: &LinkKey,
    silence: Duration,
) -> String {
    let (mut rd, mut wr, controller) = match open(addr, key, LinkRole::Control).await {
        Ok(c) => c,
        Err(why) => return why,
    };
    tracing::info!(
        controller = controller.name,
        rig = controller.rig,
        lockstep = controller.lockstep,
        "controller connected"
    );
    *link.inner.rig.lock().unwrap_or_else(|p| p.into_inner()) = Some(controller.rig);
    // The controller starts latched; the server's latch decides. If the database cannot
    // say, it stays latched.
    let latched = crate::store::latch::latched(pool, link.site())
        .await
        .unwrap_or(true);
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
    let (tx, mut rx) = mpsc::channel::<Vec<u8>>(1024);
    *link.inner.tx.lock().unwrap_or_else(|p| p.into_inner()) = Some(tx.clone());
    let (urgent_tx, mut urgent) = mpsc::channel::<Vec<u8>>(8);
    *link.inner.urgent.lock().unwrap_or_else(|p| p.into_inner()) = Some(urgent_tx);
    link.inner.connected.send_replace(true);
    link.emit(ControllerEvent::Link {
        site: link.site_name(),
        connected: true,
    });
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
        // The watchdog: a deadline `silence` after the last message arrived (not a timeout
        // started after it was handled, which would add the handling to the silence).
        let mut heard = tokio::time::Instant::now();
        loop {
            let msg = tokio::select! {
                // Biased: a message that is there counts, however late this task runs.
                biased;
                msg = read_frame(&mut rd) => msg,
                () = tokio::time::sleep_until(heard + silence) => {
                    return format!(
                        "the controller sent nothing for {} ms (it heartbeats every {} ms)",
                        silence.as_millis(),
                        HEARTBEAT.as_millis()
                    );
                }
            };
            heard = tokio::time::Instant::now();
            match msg {
                Ok(msg) => handle(link, &mut partial, msg).await,
                Err(e) => return e,
            }
        }
    };
    drop(tx);
    tokio::select! {
        why = writer => why,
        why = reader => why,
        () = estop_path::keep(link, addr, key) => unreachable!("the e-stop path is kept until the link ends"),
    }
}

async fn handle(link: &ControllerLink, partial: &mut Partial, msg: ControllerToServer) {
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
            if let Some(done) = link.bench_waiters().remove(&r.trial_id) {
                let _ = done.send((*r, record));
                return;
            }
            match link.inner.filing.result(&r, &record).await {
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
        | ControllerToServer::Challenge { .. }
        | ControllerToServer::HelloAck { .. }
        | ControllerToServer::Stepped { .. } => {}
    }
}
