//! Serving the app on a TCP listener, with the bounds a server open to a lab network needs:
//! a connection that has not sent its request head within the header timeout is closed
//! (slow clients trickling headers, and idle keep-alive connections, cannot hold it), at
//! most `max_connections` are served at once (a WebSocket counts until it closes), and every
//! accepted socket has TCP_NODELAY (a live sample is sent when written, not held back by
//! Nagle's algorithm until the browser's next message acknowledges the previous one).
//!
//! `axum::serve` sets none of these (its hyper builder has no timer, so hyper's header
//! timeout never runs), hence this accept loop on hyper's HTTP/1 builder.

use std::net::SocketAddr;
use std::pin::{Pin, pin};
use std::sync::Arc;
use std::task::{Context, Poll};

use axum::Router;
use axum::extract::ConnectInfo;
use hyper::body::Incoming;
use hyper::server::conn::http1::Builder;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpListener;
use tokio::sync::{OwnedSemaphorePermit, Semaphore, watch};
use tokio_rustls::TlsAcceptor;
use tower::ServiceExt;

use crate::config::ConnectionConfig;

/// Serves `app` on `listener` until `shutdown` resolves, then lets open requests finish;
/// over TLS when `tls` is given (every connection, no plain HTTP on the same port).
pub async fn serve(
    app: Router,
    listener: TcpListener,
    limits: &ConnectionConfig,
    tls: Option<TlsAcceptor>,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let slots = Arc::new(Semaphore::new(limits.max_connections as usize));
    let mut http = Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout());
    // Connection tasks hold a receiver; `stop` tells them to finish, and its `closed()`
    // says they all have.
    let (stop, stopped) = watch::channel(());
    let mut shutdown = pin!(shutdown);
    let mut was_full = false;
    loop {
        let full = slots.available_permits() == 0;
        if full && !was_full {
            tracing::warn!(
                max = limits.max_connections,
                "every connection slot is taken; new clients wait"
            );
        }
        was_full = full;
        let slot = tokio::select! {
            slot = slots.clone().acquire_owned() => slot.expect("the semaphore is never closed"),
            () = &mut shutdown => break,
        };
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors and the like: give the system a moment.
                    tracing::warn!("accepting a connection: {e}");
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        if let Err(e) = stream.set_nodelay(true) {
            tracing::debug!("TCP_NODELAY on {peer}: {e}");
        }
        let (http, app, stopped) = (http.clone(), app.clone(), stopped.clone());
        match tls.clone() {
            None => {
                let io = Counted {
                    stream,
                    _slot: slot,
                };
                tokio::spawn(connection(http, app, peer, io, stopped));
            }
            // The handshake runs in the connection's task, bounded like a request head, so
            // a client that never finishes it holds one slot for that long and nothing else.
            Some(acceptor) => {
                let handshake = limits.header_timeout();
                tokio::spawn(async move {
                    match tokio::time::timeout(handshake, acceptor.accept(stream)).await {
                        Ok(Ok(stream)) => {
                            let io = Counted {
                                stream,
                                _slot: slot,
                            };
                            connection(http, app, peer, io, stopped).await;
                        }
                        Ok(Err(e)) => tracing::debug!("TLS handshake with {peer}: {e}"),
                        Err(_) => tracing::debug!("TLS handshake with {peer}: timed out"),
                    }
                });
            }
        }
    }
    drop(listener);
    drop(stopped);
    let _ = stop.send(());
    stop.closed().await;
    Ok(())
}

/// Serves one connection until it closes, or until `stopped` says the server is stopping
/// (then open requests finish).
async fn connection<S>(
    http: Builder,
    app: Router,
    peer: SocketAddr,
    io: Counted<S>,
    mut stopped: watch::Receiver<()>,
) where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let service = TowerToHyperService::new(app.map_request(
        move |mut req: axum::http::Request<Incoming>| {
            req.extensions_mut().insert(ConnectInfo::<SocketAddr>(peer));
            req
        },
    ));
    let conn = http
        .serve_connection(TokioIo::new(io), service)
        .with_upgrades();
    let mut conn = pin!(conn);
    tokio::select! {
        _ = conn.as_mut() => {}
        _ = stopped.changed() => {
            conn.as_mut().graceful_shutdown();
            let _ = conn.await;
        }
    }
}

/// An accepted socket holding its connection slot: the slot is free again when the socket
/// is dropped, also after an upgrade to a WebSocket (hyper hands this same object over).
#[derive(Debug)]
struct Counted<S> {
    stream: S,
    _slot: OwnedSemaphorePermit,
}

impl<S: AsyncRead + Unpin> AsyncRead for Counted<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_read(cx, buf)
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Counted<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.get_mut().stream).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.get_mut().stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_shutdown(cx)
    }
}
