//! The I/O side of `bdft-controller serve`: the TCP link to the server (one at a time,
//! framed by `bdft_protocol::framing::ControllerCodec`), the optional UDP input port of a
//! haptic-device host, and the pump that forwards the loop's events. Runs on a
//! single-threaded tokio runtime beside the real-time thread.
//!
//! Its tasks share `state`; `connection` accepts and reads the server, `requests` checks
//! and acts on what it asks, `pump` sends what the loop reports, `heartbeat` watches the
//! link, `input_port` takes a haptic host's datagrams. Imports run one way: this
//! module starts the tasks, and every other module leads down to `state`, which uses none
//! of them.

mod connection;
mod heartbeat;
mod input_port;
mod pump;
mod requests;
mod state;

use std::sync::{Arc, Mutex};

use tokio::net::{TcpListener, UdpSocket};

use super::rt_loop::{Command, LoopHandle};
pub use heartbeat::HEARTBEAT;
pub use state::LinkConfig;
use state::{Io, Shared, lock};

/// Runs the I/O side until `shutdown` resolves.
pub async fn run(
    cfg: LinkConfig,
    rt: LoopHandle,
    listener: TcpListener,
    input_udp: Option<UdpSocket>,
    shutdown: impl std::future::Future<Output = ()>,
) {
    let io: Shared = Arc::new(Mutex::new(Io::new(cfg, rt)));
    let tasks = [
        tokio::spawn(connection::accept(Arc::clone(&io), listener)),
        tokio::spawn(pump::pump(Arc::clone(&io))),
        tokio::spawn(heartbeat::heartbeat(Arc::clone(&io))),
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
