//! The control connection: trials, operator input, record chunks and results, the latch,
//! heartbeats; the E-stop's own path is kept beside it for as long as it runs.

use std::collections::HashMap;
use std::time::Duration;

use bdft_protocol::controller_to_server::{ControllerToServer, TrialResult};
use bdft_protocol::link_auth::{LinkKey, LinkRole};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::RECORD_CHANNELS;
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

use super::connection::{Reader, frame, open};
use super::{ControllerEvent, ControllerLink, Partial, estop_path, reader};
use crate::store::records::Record;

/// Runs the control connection until it fails; returns why.
pub(super) async fn control(
    link: &ControllerLink,
    addr: std::net::SocketAddr,
    key: &LinkKey,
    silence: Duration,
) -> String {
    let (rd, wr, controller) = match open(addr, key, LinkRole::Control).await {
        Ok(c) => c,
        Err(why) => return why,
    };
    let (mut wr, closer, mut heard) = match split_off_reader(rd, wr, silence) {
        Ok(parts) => parts,
        Err(e) => return format!("handing the link to its reader: {e}"),
    };
    tracing::info!(
        controller = controller.name,
        rig = controller.rig,
        lockstep = controller.lockstep,
        "controller connected"
    );
    *link.inner.rig.lock().unwrap_or_else(|p| p.into_inner()) = Some(controller.rig);
    // The controller starts latched; the server's latch (never the store, which may be busy)
    // decides.
    let latch = if link.inner.latch.latched(link.site()) {
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
    let (results, filed) = filer(link);
    let reader = async {
        let mut partial: Partial = HashMap::new();
        while let Some(msg) = heard.recv().await {
            match msg {
                Ok(msg) => handle(link, &mut partial, &results, msg).await,
                Err(why) => return why,
            }
        }
        "the link's reader stopped".to_string()
    };
    drop(tx);
    let why = tokio::select! {
        why = writer => why,
        why = reader => why,
        () = estop_path::keep(link, addr, key) => unreachable!("the e-stop path is kept until the link ends"),
    };
    // The reader's thread wakes and ends; the results already received are filed before the
    // supervisor files what the lost link leaves running.
    let _ = closer.shutdown(std::net::Shutdown::Both);
    drop(results);
    let _ = filed.await;
    why
}

/// Moves the connection's reading to a thread of its own ([`reader`]): the async writer, a
/// handle to shut the socket down when the session ends, and what the reader hears.
fn split_off_reader(
    rd: Reader,
    wr: tokio::net::tcp::OwnedWriteHalf,
    silence: Duration,
) -> std::io::Result<(
    tokio::net::TcpStream,
    std::net::TcpStream,
    mpsc::Receiver<reader::Heard>,
)> {
    let parts = rd.into_parts();
    let buffered = parts.read_buf.to_vec();
    let stream = parts
        .io
        .reunite(wr)
        .map_err(std::io::Error::other)?
        .into_std()?;
    let (tx, heard) = mpsc::channel(reader::QUEUE);
    reader::spawn(stream.try_clone()?, buffered, silence, tx)?;
    let closer = stream.try_clone()?;
    Ok((tokio::net::TcpStream::from_std(stream)?, closer, heard))
}

/// A result and its record, to be filed.
type Finished = (Box<TrialResult>, Record);

/// Files the link's trial results in the order they came, on a task of its own: a store that
/// is busy delays the filing, never the reading of the link (the E-stop's confirmation, the
/// live samples, the heartbeats behind it). Bounded: past [`FILING_QUEUE`] results waiting
/// the link's handler waits too. The task ends once the sender is dropped and every result
/// received is filed.
fn filer(link: &ControllerLink) -> (mpsc::Sender<Finished>, tokio::task::JoinHandle<()>) {
    let (tx, mut rx) = mpsc::channel::<Finished>(FILING_QUEUE);
    let link = link.clone();
    let task = tokio::spawn(async move {
        while let Some((r, record)) = rx.recv().await {
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
    });
    (tx, task)
}

/// Results waiting to be filed at most (a controller runs a few trials at once).
const FILING_QUEUE: usize = 16;

async fn handle(
    link: &ControllerLink,
    partial: &mut Partial,
    results: &mpsc::Sender<Finished>,
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
            if let Some(done) = link.bench_waiters().remove(&r.trial_id) {
                let _ = done.send((*r, record));
                return;
            }
            if results.send((r, record)).await.is_err() {
                tracing::error!("the link's filing has stopped; a result is lost");
            }
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
