//! The E-stop's own connection to the controller. On the control connection an E-stop
//! would wait behind whatever was written before it; here nothing else travels, so the
//! controller reads it the moment it arrives, sets its loop's E-stop flag and confirms on
//! the same connection. The server sends every E-stop on both paths: whichever confirms
//! first answers the experimenter, and either path alone still stops the machine.

use std::time::Duration;

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::link_auth::{LinkKey, LinkRole};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::FaultKind;
use tokio::io::AsyncWriteExt;
use tokio::net::tcp::OwnedWriteHalf;
use tokio::sync::mpsc;

use super::ControllerLink;
use super::connection::{Reader, frame, open, read_frame};

/// How often the path says it is alive (the controller drops a silent one).
const BEAT: Duration = Duration::from_millis(200);
/// Wait before reconnecting a lost path.
const RETRY: Duration = Duration::from_millis(100);

/// Keeps the E-stop path to `addr` open for as long as the control link runs (the caller
/// drops this future when the link ends), reconnecting whenever it drops.
pub(super) async fn keep(link: &ControllerLink, addr: std::net::SocketAddr, key: &LinkKey) {
    loop {
        match open(addr, key, LinkRole::EStop).await {
            Ok((mut rd, mut wr, _)) => {
                let (tx, mut presses) = mpsc::channel::<()>(8);
                link.set_estop_path(Some(tx));
                let why = serve(link, &mut rd, &mut wr, &mut presses).await;
                link.set_estop_path(None);
                tracing::warn!("the e-stop path is down: {why}");
            }
            Err(why) => tracing::warn!("the e-stop path could not open: {why}"),
        }
        tokio::time::sleep(RETRY).await;
    }
}

async fn serve(
    link: &ControllerLink,
    rd: &mut Reader,
    wr: &mut OwnedWriteHalf,
    presses: &mut mpsc::Receiver<()>,
) -> String {
    let mut beat = tokio::time::interval(BEAT);
    let mut seq = 0;
    loop {
        tokio::select! {
            biased;
            Some(()) = presses.recv() => {
                if let Err(e) = wr.write_all(&frame(&ServerToController::EStop {})).await {
                    return format!("write failed: {e}");
                }
            }
            msg = read_frame(rd) => match msg {
                Ok(ControllerToServer::Fault { trial_id: None, kind: FaultKind::EStop, .. }) => {
                    link.set_estop(true);
                    link.confirm_estop();
                }
                Ok(ControllerToServer::Rejected { reason, .. }) => {
                    tracing::warn!(reason, "the controller rejected a message on the e-stop path");
                }
                Ok(_) => {}
                Err(e) => return e,
            },
            _ = beat.tick() => {
                seq += 1;
                if let Err(e) = wr.write_all(&frame(&ServerToController::Heartbeat { seq })).await {
                    return format!("write failed: {e}");
                }
            }
        }
    }
}
