//! The link's heartbeat and watchdog: the controller beats every [`HEARTBEAT`], and a server
//! silent for longer than the link timeout has lost the link (every running trial stops).

use std::time::Duration;

use bdft_protocol::controller_to_server::ControllerToServer;

use super::state::{Shared, lock};

/// How often the controller beats: the server counts 75 ms of silence as a hang, so that a
/// hung controller's trials are filed within 100 ms; two beats may go missing and the third
/// be 25 ms late before a live controller is taken for hung.
pub const HEARTBEAT: Duration = Duration::from_millis(25);

/// Sends a heartbeat every [`HEARTBEAT`] and declares the link lost after the configured
/// silence.
pub(super) async fn heartbeat(io: Shared) {
    let mut every = tokio::time::interval(HEARTBEAT);
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
