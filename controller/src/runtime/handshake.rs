//! The controller's side of a new connection before anything is trusted: a cap on pending
//! (unauthenticated) connections, then the challenge–response of
//! [`bdft_protocol::link_auth`]. Until the server's proof checks out, frames are limited to
//! [`MAX_UNAUTHENTICATED_FRAME`] bytes and the hello must arrive within [`HANDSHAKE_TIMEOUT`]:
//! a stranger on the port can hold a few hundred bytes for two seconds, nothing more.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bdft_protocol::PROTOCOL_VERSION;
use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::framing::{ControllerCodec, MAX_FRAME};
use bdft_protocol::link_auth::{Bytes32, LinkKey, LinkRole, MAX_UNAUTHENTICATED_FRAME};
use bdft_protocol::server_to_controller::ServerToController;
use futures_util::{SinkExt, StreamExt};
use tokio_util::codec::{FramedRead, FramedWrite};

/// Reads the server's messages off a connection (the one frame codec of `bdft_protocol`).
pub type Reader = FramedRead<tokio::net::tcp::OwnedReadHalf, ControllerCodec>;
/// Writes our messages onto a connection.
pub type Writer = FramedWrite<tokio::net::tcp::OwnedWriteHalf, ControllerCodec>;

/// Connections allowed to be in the handshake at once, in all and from one address: a peer
/// that opens sockets and never speaks fills its own share, not the server's.
pub const MAX_PENDING: usize = 16;
pub const MAX_PENDING_PER_PEER: usize = 4;
/// How long a new connection has to authenticate.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(2);

/// Counts connections still in the handshake, per peer address.
#[derive(Debug, Default)]
pub struct PendingGate {
    by_peer: Mutex<HashMap<IpAddr, usize>>,
}

/// A place in the gate, given back when dropped (authenticated, refused or gone).
#[derive(Debug)]
pub struct Pending {
    gate: Arc<PendingGate>,
    peer: IpAddr,
}

impl PendingGate {
    /// A place for a connection from `peer`, or `None` when the caps are reached.
    pub fn admit(self: &Arc<Self>, peer: IpAddr) -> Option<Pending> {
        let mut g = self.by_peer.lock().unwrap_or_else(|p| p.into_inner());
        let total: usize = g.values().sum();
        let mine = g.get(&peer).copied().unwrap_or(0);
        if total >= MAX_PENDING || mine >= MAX_PENDING_PER_PEER {
            return None;
        }
        *g.entry(peer).or_insert(0) += 1;
        Some(Pending {
            gate: Arc::clone(self),
            peer,
        })
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        let mut g = self.gate.by_peer.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = g.get_mut(&self.peer) {
            *n -= 1;
            if *n == 0 {
                g.remove(&self.peer);
            }
        }
    }
}

/// An authenticated server: what its hello said, and the controller's proof to send back
/// in the `hello_ack`.
#[derive(Debug)]
pub struct Authenticated {
    pub role: LinkRole,
    pub client: String,
    pub proof: Bytes32,
}

/// A new connection's framing: small frames until [`authenticate`] raises the limit.
pub fn frame(stream: tokio::net::TcpStream) -> (Reader, Writer) {
    let (rd, wr) = stream.into_split();
    (
        FramedRead::new(rd, ControllerCodec::with_limit(MAX_UNAUTHENTICATED_FRAME)),
        FramedWrite::new(wr, ControllerCodec::default()),
    )
}

/// Sends the challenge and checks the hello. On failure the peer is told why in one
/// `rejected` (nothing about the key) and the caller closes the connection.
pub async fn authenticate(
    rd: &mut Reader,
    wr: &mut Writer,
    key: &LinkKey,
) -> Result<Authenticated, String> {
    let challenge = Bytes32::random().map_err(|e| e.to_string())?;
    wr.send(ControllerToServer::Challenge {
        protocol_version: PROTOCOL_VERSION,
        nonce: challenge,
    })
    .await
    .map_err(|e| format!("sending the challenge: {e}"))?;
    let verdict = match tokio::time::timeout(HANDSHAKE_TIMEOUT, rd.next()).await {
        Ok(Some(Ok(Ok(ServerToController::Hello {
            protocol_version,
            client,
            role,
            nonce,
            proof,
        })))) => {
            if protocol_version != PROTOCOL_VERSION {
                Err(format!(
                    "protocol version {protocol_version} not supported; this controller speaks {PROTOCOL_VERSION}"
                ))
            } else if !key.verify_server(role, &challenge, &nonce, &proof) {
                Err(
                    "authentication failed: the hello does not prove this controller's link key"
                        .into(),
                )
            } else {
                Ok(Authenticated {
                    role,
                    client,
                    proof: key.controller_proof(role, &challenge, &nonce),
                })
            }
        }
        Ok(Some(Ok(_))) => Err("the first message must be an authenticated hello".into()),
        Ok(Some(Err(e))) => Err(format!("before authentication: {e}")),
        Ok(None) => Err("closed during the handshake".into()),
        Err(_) => Err(format!(
            "no hello within {} ms",
            HANDSHAKE_TIMEOUT.as_millis()
        )),
    };
    match verdict {
        Ok(auth) => {
            rd.decoder_mut().set_limit(MAX_FRAME);
            Ok(auth)
        }
        Err(reason) => {
            let _ = wr
                .send(ControllerToServer::Rejected {
                    trial_id: None,
                    reason: reason.clone(),
                })
                .await;
            Err(reason)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gate_caps_pending_connections_per_peer_and_in_all() {
        let gate = Arc::new(PendingGate::default());
        let a: IpAddr = [10, 0, 0, 1].into();
        let mine: Vec<_> = (0..MAX_PENDING_PER_PEER)
            .map(|_| gate.admit(a).expect("within the peer's share"))
            .collect();
        assert!(gate.admit(a).is_none(), "a peer's share is capped");
        let others: Vec<_> = (0..MAX_PENDING - MAX_PENDING_PER_PEER)
            .map(|i| gate.admit([10, 0, 1, i as u8].into()).expect("room in all"))
            .collect();
        assert!(
            gate.admit([10, 0, 2, 1].into()).is_none(),
            "the total is capped"
        );
        drop(mine);
        assert!(gate.admit(a).is_some(), "places come back when dropped");
        drop(others);
        assert!(
            gate.by_peer.lock().unwrap().is_empty(),
            "nothing kept for gone peers"
        );
    }
}
