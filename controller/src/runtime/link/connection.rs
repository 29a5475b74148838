//! The server's connections: accepted under the handshake's caps, authenticated before
//! anything is read, then either the one control connection (its reader hands each message
//! to the checks of [`super::requests`], its writer frames the replies and the pump's
//! messages) or an E-stop path ([`estop_path`]).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::AtomicUsize;
use std::time::{Duration, Instant};

use bdft_protocol::PROTOCOL_VERSION;
use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::framing::FrameError;
use bdft_protocol::link_auth::LinkRole;
use futures_util::{SinkExt, StreamExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

use super::state::{Conn, Shared, lock};
use crate::runtime::estop_path;
use crate::runtime::handshake::{self, Pending, PendingGate, Reader, Writer};

pub(super) async fn accept(io: Shared, listener: TcpListener) {
    let gate = Arc::new(PendingGate::default());
    let estop_open = Arc::new(AtomicUsize::new(0));
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        // Over the cap the socket is closed unread: nobody unauthenticated gets more.
        let Some(pending) = gate.admit(peer.ip()) else {
            tracing::debug!(%peer, "too many connections in the handshake; closed");
            continue;
        };
        let _ = stream.set_nodelay(true);
        tokio::spawn(connection(
            Arc::clone(&io),
            Arc::clone(&estop_open),
            stream,
            peer,
            pending,
        ));
    }
}

async fn connection(
    io: Shared,
    estop_open: Arc<AtomicUsize>,
    stream: TcpStream,
    peer: SocketAddr,
    pending: Pending,
) {
    let (mut rd, mut wr) = handshake::frame(stream);
    let key = lock(&io).cfg.key.clone();
    let auth = match handshake::authenticate(&mut rd, &mut wr, &key).await {
        Ok(auth) => auth,
        Err(why) => {
            tracing::warn!(%peer, why, "connection refused");
            return;
        }
    };
    drop(pending);
    let ack = {
        let g = lock(&io);
        ControllerToServer::HelloAck {
            protocol_version: PROTOCOL_VERSION,
            proof: auth.proof,
            controller: format!("bdft-controller {}", env!("CARGO_PKG_VERSION")),
            loop_rate_hz: 1.0 / g.cfg.dt,
            rig: if g.cfg.real_rig { "udp" } else { "sim" }.into(),
            lockstep: g.cfg.lockstep,
        }
    };
    match auth.role {
        LinkRole::Control => control(io, rd, wr, peer, auth.client, ack).await,
        LinkRole::EStop => {
            if wr.send(ack).await.is_err() {
                return;
            }
            tracing::info!(%peer, client = auth.client, "e-stop path connected");
            let (loop_state, silence) = {
                let g = lock(&io);
                (Arc::clone(&g.rt.shared), g.cfg.link_timeout)
            };
            estop_path::serve(loop_state, estop_open, rd, wr, silence, || {
                lock(&io).status()
            })
            .await;
        }
    }
}

/// The control connection: one at a time; trials, input, records, the latch.
async fn control(
    io: Shared,
    mut rd: Reader,
    mut wr: Writer,
    peer: SocketAddr,
    client: String,
    ack: ControllerToServer,
) {
    let (tx, mut rx) = mpsc::channel::<ControllerToServer>(16_384);
    let accepted = {
        let mut g = lock(&io);
        if g.conn.is_some() {
            None
        } else {
            let id = g.next_conn;
            g.next_conn += 1;
            g.conn = Some(Conn { id, tx: tx.clone() });
            g.last_rx = Instant::now();
            tracing::info!(%peer, client, conn = id, "server connected");
            Some(id)
        }
    };
    let Some(conn) = accepted else {
        let _ = wr
            .send(ControllerToServer::Rejected {
                trial_id: None,
                reason: "another server is connected to this controller".into(),
            })
            .await;
        return;
    };
    let writer_io = Arc::clone(&io);
    let writer = tokio::spawn(async move {
        if wr.send(ack).await.is_err() {
            return;
        }
        // Frame everything queued, then flush once: a record's chunks go out together.
        while let Some(msg) = rx.recv().await {
            let mut sent = wr.feed(msg).await;
            while sent.is_ok() {
                match rx.try_recv() {
                    Ok(msg) => sent = wr.feed(msg).await,
                    Err(_) => break,
                }
            }
            if let Err(e) = sent.and(wr.flush().await) {
                lock(&writer_io).link_lost(conn, &format!("write failed: {e}"));
                return;
            }
        }
    });
    drop(tx);
    let mut since_yield = 0u32;
    loop {
        // A flood of frames is always ready to read; hand the runtime back now and then so
        // the E-stop path (same thread) is never kept waiting behind it.
        since_yield += 1;
        if since_yield == 32 {
            since_yield = 0;
            tokio::task::yield_now().await;
        }
        let replies = match rd.next().await {
            Some(Ok(Ok(msg))) => {
                let mut g = lock(&io);
                if g.conn.as_ref().is_none_or(|c| c.id != conn) {
                    break; // replaced or timed out
                }
                let replies = g.handle(conn, msg);
                (replies, g.sender())
            }
            // A frame that is not a message: answered, and the link goes on.
            Some(Ok(Err(malformed))) => {
                let mut g = lock(&io);
                (g.reject(malformed.to_string()), g.sender())
            }
            None => {
                lock(&io).link_lost(conn, "connection closed");
                break;
            }
            Some(Err(FrameError::Io(e))) => {
                lock(&io).link_lost(conn, &format!("connection failed: {e}"));
                break;
            }
            // A frame we cannot delimit leaves the stream unusable.
            Some(Err(e)) => {
                lock(&io).link_lost(conn, &format!("bad frame: {e}"));
                break;
            }
        };
        if let (replies, Some((_, tx))) = replies {
            for msg in replies {
                let _ = tx.send(msg).await;
            }
        }
    }
    writer.abort();
}
