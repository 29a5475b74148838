//! One authenticated connection to the controller, whatever its role (control or E-stop):
//! connect, the challenge–response of [`bdft_protocol::link_auth`], and the frame codec both
//! roles read and write with.

use std::time::Duration;

use bdft_protocol::PROTOCOL_VERSION;
use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::framing::{self, MAX_FRAME};
use bdft_protocol::link_auth::{Bytes32, LinkKey, LinkRole, MAX_UNAUTHENTICATED_FRAME};
use bdft_protocol::server_to_controller::ServerToController;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;
use tokio::net::tcp::OwnedWriteHalf;

/// How long a controller may take to answer the handshake (it may still be starting).
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// The controller's messages, decoded by the protocol's one frame codec.
pub(super) type Reader =
    tokio_util::codec::FramedRead<tokio::net::tcp::OwnedReadHalf, framing::ServerCodec>;

pub(super) async fn read_frame(r: &mut Reader) -> Result<ControllerToServer, String> {
    use futures_util::StreamExt;
    match r.next().await {
        Some(Ok(Ok(msg))) => Ok(msg),
        Some(Ok(Err(malformed))) => Err(format!("the controller sent {malformed}")),
        Some(Err(e)) => Err(format!("link closed ({e})")),
        None => Err("link closed".to_string()),
    }
}

/// A message the server always sends, as a frame (they are a few bytes).
pub(super) fn frame(msg: &ServerToController) -> Vec<u8> {
    framing::encode(msg).expect("a control message fits a frame")
}

/// What an authenticated controller said of itself.
pub(super) struct Controller {
    pub(super) name: String,
    pub(super) rig: String,
    pub(super) lockstep: bool,
}

/// Connects and runs the challenge–response of [`bdft_protocol::link_auth`] for `role`: the
/// controller's challenge, our hello with its proof, the controller's proof in the ack. A
/// controller that cannot prove the key is never believed (it could invent results).
pub(super) async fn open(
    addr: std::net::SocketAddr,
    key: &LinkKey,
    role: LinkRole,
) -> Result<(Reader, OwnedWriteHalf, Controller), String> {
    let stream = TcpStream::connect(addr)
        .await
        .map_err(|e| format!("cannot connect to the controller at {addr}: {e}"))?;
    let _ = stream.set_nodelay(true);
    let (rd, mut wr) = stream.into_split();
    let mut rd: Reader = tokio_util::codec::FramedRead::new(
        rd,
        framing::ServerCodec::with_limit(MAX_UNAUTHENTICATED_FRAME),
    );
    let within = |r: Result<Result<ControllerToServer, String>, _>| {
        r.unwrap_or_else(|_| Err(format!("no handshake within {HANDSHAKE_TIMEOUT:?}")))
    };
    let challenge = match within(
        tokio::time::timeout(HANDSHAKE_TIMEOUT, read_frame(&mut rd)).await,
    )? {
        ControllerToServer::Challenge {
            protocol_version: PROTOCOL_VERSION,
            nonce,
        } => nonce,
        ControllerToServer::Challenge {
            protocol_version, ..
        } => {
            return Err(format!(
                "the controller speaks protocol {protocol_version}, this server {PROTOCOL_VERSION}"
            ));
        }
        other => {
            return Err(format!(
                "expected the controller's challenge, got {other:?}"
            ));
        }
    };
    let nonce = Bytes32::random().map_err(|e| e.to_string())?;
    let hello = frame(&ServerToController::Hello {
        protocol_version: PROTOCOL_VERSION,
        client: format!("bdft-server {}", env!("CARGO_PKG_VERSION")),
        role,
        nonce,
        proof: key.server_proof(role, &challenge, &nonce),
    });
    wr.write_all(&hello)
        .await
        .map_err(|e| format!("hello failed: {e}"))?;
    match within(tokio::time::timeout(HANDSHAKE_TIMEOUT, read_frame(&mut rd)).await)? {
        ControllerToServer::HelloAck {
            proof,
            controller,
            rig,
            lockstep,
            ..
        } if key.verify_controller(role, &challenge, &nonce, &proof) => {
            rd.decoder_mut().set_limit(MAX_FRAME);
            Ok((
                rd,
                wr,
                Controller {
                    name: controller,
                    rig,
                    lockstep,
                },
            ))
        }
        ControllerToServer::HelloAck { .. } => Err(
            "the controller failed authentication: its proof does not match our link key".into(),
        ),
        ControllerToServer::Rejected { reason, .. } => {
            Err(format!("the controller refused us: {reason}"))
        }
        other => Err(format!("unexpected answer to hello: {other:?}")),
    }
}
