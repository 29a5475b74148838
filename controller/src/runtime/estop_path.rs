//! The E-stop's own connection. The control connection is one ordered byte stream: an
//! E-stop written there waits until everything before it (operator input, commands) has
//! been read. On its own connection it is read as soon as it arrives; it sets the loop's
//! E-stop flag directly (an atomic the loop checks before computing any valve command, so
//! the very next tick zeroes every valve) and is confirmed at once on the same connection.
//!
//! Only `e_stop`, `status` and `heartbeat` travel here: the path can stop the machine but
//! never move it or clear a latch.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::FaultKind;
use futures_util::{SinkExt, StreamExt};

use super::handshake::{Reader, Writer};
use super::rt_loop::Shared;

/// E-stop connections open at once (a server keeps one; a second covers its reconnect).
pub const MAX_ESTOP_CONNECTIONS: usize = 2;

/// The confirmation of an E-stop, on whichever connection it came.
pub fn confirmation() -> ControllerToServer {
    ControllerToServer::Fault {
        trial_id: None,
        kind: FaultKind::EStop,
        message: "e-stop pressed: valves at zero, latched until reset_e_stop".into(),
    }
}

/// Serves one authenticated E-stop connection until it closes or stays silent for
/// `silence`. `status` answers what the control side reports.
pub async fn serve(
    loop_state: Arc<Shared>,
    open: Arc<AtomicUsize>,
    mut rd: Reader,
    mut wr: Writer,
    silence: Duration,
    status: impl Fn() -> ControllerToServer,
) {
    if open.fetch_add(1, Ordering::SeqCst) >= MAX_ESTOP_CONNECTIONS {
        open.fetch_sub(1, Ordering::SeqCst);
        let _ = wr
            .send(ControllerToServer::Rejected {
                trial_id: None,
                reason: format!("{MAX_ESTOP_CONNECTIONS} e-stop connections are open already"),
            })
            .await;
        return;
    }
    loop {
        let reply = match tokio::time::timeout(silence, rd.next()).await {
            Ok(Some(Ok(Ok(ServerToController::EStop {})))) => {
                loop_state.estop.store(true, Ordering::SeqCst);
                tracing::warn!("E-STOP (e-stop path): every valve to zero, latched until reset");
                Some(confirmation())
            }
            Ok(Some(Ok(Ok(ServerToController::Status {})))) => Some(status()),
            Ok(Some(Ok(Ok(ServerToController::Heartbeat { .. })))) => None,
            Ok(Some(Ok(Ok(_)))) => Some(ControllerToServer::Rejected {
                trial_id: None,
                reason: "only e_stop, status and heartbeat travel on an e-stop connection".into(),
            }),
            Ok(Some(Ok(Err(malformed)))) => Some(ControllerToServer::Rejected {
                trial_id: None,
                reason: malformed.to_string(),
            }),
            Ok(Some(Err(_)) | None) | Err(_) => break,
        };
        if let Some(msg) = reply
            && wr.send(msg).await.is_err()
        {
            break;
        }
    }
    open.fetch_sub(1, Ordering::SeqCst);
}
