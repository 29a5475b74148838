//! Serving the app on a TCP listener, with the bounds a server open to a lab network needs:
//!
//! - a connection that has not sent its request head within the header timeout is closed
//!   (slow clients trickling headers, and idle keep-alive connections, cannot hold it);
//! - a request body that has not arrived within the body timeout after its head is answered
//!   408 and its connection closed, unless it keeps arriving at the minimum rate (a large
//!   upload on a slow link goes on; one byte a second does not);
//! - at most `max_connections` are served at once (a WebSocket counts until it closes), and
//!   at most `max_connections_per_address` of them from one client address: one more from
//!   that address is answered 429 with Retry-After (plain HTTP; over TLS it is closed) and
//!   takes no slot, so one address cannot make every new client wait;
//! - every accepted socket has TCP_NODELAY (a live sample is sent when written, not held back
//!   by Nagle's algorithm until the browser's next message acknowledges the previous one);
//! - over TLS, a connection whose first byte is not a TLS handshake is plain HTTP (someone
//!   typed `http://`): its one request is answered with a redirect to the same path over
//!   HTTPS, in the slots, header timeout and a small head-size cap of any connection.
//!
//! `axum::serve` sets none of these (its hyper builder has no timer, so hyper's header
//! timeout never runs), hence this accept loop on hyper's HTTP/1 builder.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::pin::{Pin, pin};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::extract::ConnectInfo;
use axum::http::{HeaderValue, Request, Response, StatusCode, header};
use axum::response::IntoResponse;
use hyper::body::{Body, Bytes, Frame, Incoming, SizeHint};
use hyper::server::conn::http1::Builder;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore, watch};
use tokio::time::{Instant, Sleep};
use tokio_rustls::TlsAcceptor;
use tower::ServiceExt;

use crate::config::ConnectionConfig;
use crate::http::error::ErrorBody;

/// Refused connections answered at once, at most; past it a refused connection is closed
/// without an answer (the client is over its limit either way).
const REFUSALS_AT_ONCE: usize = 64;
/// How long a refused connection may take to read its 429 before it is closed.
const REFUSAL_TIME: Duration = Duration::from_secs(1);
/// At most one warning about an address at its connection limit this often (a flood would
/// otherwise write one per refused connection).
const WARN_EVERY: Duration = Duration::from_secs(10);
/// The first byte of a TLS connection: a handshake record (RFC 8446, 5.1).
const TLS_HANDSHAKE: u8 = 0x16;
/// The most a plain-HTTP request head on the HTTPS port may take (hyper's smallest buffer):
/// the redirect needs only its request line and Host.
const PLAIN_HTTP_HEAD: usize = 8192;

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
    let per_address = PerAddress::new(limits.max_connections_per_address);
    let refusals = Arc::new(Semaphore::new(REFUSALS_AT_ONCE));
    let refusal: Arc<[u8]> = refusal_answer(limits.max_connections_per_address).into();
    let body = BodyLimits {
        timeout: limits.body_timeout(),
        min_rate: limits.min_body_rate,
    };
    let mut http = Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout());
    // Plain HTTP on the HTTPS port: one small request, answered and closed.
    let mut plain_http = http.clone();
    plain_http.keep_alive(false).max_buf_size(PLAIN_HTTP_HEAD);
    // Connection tasks hold a receiver; `stop` tells them to finish, and its `closed()`
    // says they all have.
    let (stop, stopped) = watch::channel(());
    let mut shutdown = pin!(shutdown);
    let mut was_full = false;
    let mut warned_at: Option<Instant> = None;
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
        // An IPv4 client of a dual-stack listener is one address whichever way it came.
        let peer = SocketAddr::new(peer.ip().to_canonical(), peer.port());
        let Some(address) = per_address.enter(peer.ip()) else {
            // Over its address's limit: no slot, an answer if one can be given cheaply.
            drop(slot);
            if warned_at.is_none_or(|t| t.elapsed() >= WARN_EVERY) {
                warned_at = Some(Instant::now());
                tracing::warn!(
                    address = %peer.ip(),
                    max = limits.max_connections_per_address,
                    "a client address holds its most connections; more from it are refused"
                );
            }
            if tls.is_none()
                && let Ok(permit) = refusals.clone().try_acquire_owned()
            {
                tokio::spawn(refuse(stream, Arc::clone(&refusal), permit));
            }
            continue;
        };
        if let Err(e) = stream.set_nodelay(true) {
            tracing::debug!("TCP_NODELAY on {peer}: {e}");
        }
        let held = Held {
            _slot: slot,
            _address: address,
        };
        let (http, app, stopped) = (http.clone(), app.clone(), stopped.clone());
        match tls.clone() {
            None => {
                let io = Counted {
                    stream,
                    _held: held,
                };
                tokio::spawn(connection(http, app, peer, body, io, stopped));
            }
            // The handshake runs in the connection's task, bounded like a request head (the
            // wait for its first byte included), so a client that never finishes it holds
            // one slot for that long and nothing else.
            Some(acceptor) => {
                let due = Instant::now() + limits.header_timeout();
                let plain_http = plain_http.clone();
                tokio::spawn(async move {
                    match tokio::time::timeout_at(due, first_byte(&stream)).await {
                        Ok(Ok(Some(TLS_HANDSHAKE))) => {}
                        Ok(Ok(Some(_))) => {
                            // The address the client reached, for the page that names it.
                            let local = match stream.local_addr() {
                                Ok(a) => SocketAddr::new(a.ip().to_canonical(), a.port()),
                                Err(e) => {
                                    tracing::debug!("plain HTTP from {peer}: {e}");
                                    return;
                                }
                            };
                            let io = Counted {
                                stream,
                                _held: held,
                            };
                            let app = to_https(local);
                            connection(plain_http, app, peer, body, io, stopped).await;
                            return;
                        }
                        Ok(Ok(None)) => return,
                        Ok(Err(e)) => {
                            tracing::debug!("reading from {peer}: {e}");
                            return;
                        }
                        Err(_) => {
                            tracing::debug!("TLS handshake with {peer}: nothing sent in time");
                            return;
                        }
                    }
                    match tokio::time::timeout_at(due, acceptor.accept(stream)).await {
                        Ok(Ok(stream)) => {
                            let io = Counted {
                                stream,
                                _held: held,
                            };
                            connection(http, app, peer, body, io, stopped).await;
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

/// The connection's first byte, left in the socket to be read again (`None`: it closed
/// before sending one).
async fn first_byte(stream: &TcpStream) -> std::io::Result<Option<u8>> {
    let mut first = [0u8; 1];
    Ok(match stream.peek(&mut first).await? {
        0 => None,
        _ => Some(first[0]),
    })
}

/// The app of a plain-HTTP connection to the HTTPS port, `local` the address it reached.
fn to_https(local: SocketAddr) -> Router {
    Router::new().fallback(move |req: Request<axum::body::Body>| async move {
        redirect_to_https(local, req.headers().get(header::HOST), req.uri())
    })
}

/// The answer to a plain-HTTP request on the HTTPS port: a permanent redirect (308: the
/// method and body are kept) to the same path and query over HTTPS at the host the browser
/// asked for; when the request names no such host, a page saying where to go instead (the
/// Host header becomes the redirect's target, so it must be a host and nothing else).
fn redirect_to_https(
    local: SocketAddr,
    host: Option<&HeaderValue>,
    uri: &axum::http::Uri,
) -> Response<axum::body::Body> {
    let target = uri
        .path_and_query()
        .map(|p| p.as_str())
        .filter(|p| p.starts_with('/'))
        .unwrap_or("/");
    let location = host
        .and_then(|h| h.to_str().ok())
        .filter(|h| plausible_host(h))
        .and_then(|h| HeaderValue::try_from(format!("https://{h}{target}")).ok());
    let mut response = match location {
        Some(location) => (
            StatusCode::PERMANENT_REDIRECT,
            [(header::LOCATION, location)],
        )
            .into_response(),
        None => {
            let page = format!(
                "<!doctype html>\n<title>This port speaks HTTPS</title>\n<p>This port speaks \
                 HTTPS: open <a href=\"https://{local}/\">https://{local}/</a> (or this \
                 server's name instead of its address).</p>\n"
            );
            (StatusCode::BAD_REQUEST, axum::response::Html(page)).into_response()
        }
    };
    response
        .headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    response
}

/// Whether a Host header is a host name or IP address with an optional port, and nothing
/// else (no user, path, spaces or control characters).
fn plausible_host(value: &str) -> bool {
    let (host, port) = match value.rsplit_once(':') {
        // An IPv6 address's colons are inside its brackets.
        Some((host, port)) if !port.contains(']') => (host, Some(port)),
        _ => (value, None),
    };
    let port_ok = port.is_none_or(|p| {
        p.bytes().all(|b| b.is_ascii_digit()) && p.parse::<u16>().is_ok_and(|p| p > 0)
    });
    let host_ok = match host.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
        Some(ip) => ip.parse::<std::net::Ipv6Addr>().is_ok(),
        None => {
            (1..=253).contains(&host.len())
                && host.split('.').all(|label| {
                    (1..=63).contains(&label.len())
                        && label
                            .bytes()
                            .all(|b| b.is_ascii_alphanumeric() || b == b'-')
                })
        }
    };
    host_ok && port_ok
}

/// The 429 a connection over its address's limit gets, whole (status line to body).
fn refusal_answer(per_address: u64) -> Vec<u8> {
    let body = serde_json::to_vec(&ErrorBody {
        error: format!(
            "this address holds {per_address} connections to the server, the most one address \
             may (--max-connections-per-address): close some, or try again in a second"
        ),
        fields: None,
    })
    .expect("an error body serializes");
    let mut answer = format!(
        "HTTP/1.1 429 Too Many Requests\r\ncontent-type: application/json\r\nretry-after: 1\r\n\
         connection: close\r\ncontent-length: {}\r\n\r\n",
        body.len()
    )
    .into_bytes();
    answer.extend_from_slice(&body);
    answer
}

/// Answers a refused connection its 429 and closes it, reading what the client sends
/// meanwhile (closing a socket with unread data resets it, and the client could lose the
/// answer); at most [`REFUSAL_TIME`].
async fn refuse(mut stream: TcpStream, answer: Arc<[u8]>, _permit: OwnedSemaphorePermit) {
    let _ = tokio::time::timeout(REFUSAL_TIME, async {
        stream.write_all(&answer).await?;
        stream.shutdown().await?;
        let mut sink = [0u8; 4096];
        while stream.read(&mut sink).await? > 0 {}
        Ok::<_, std::io::Error>(())
    })
    .await;
}

/// Connections open per client address.
#[derive(Debug, Clone)]
struct PerAddress {
    max: u64,
    open: Arc<Mutex<HashMap<IpAddr, u64>>>,
}

impl PerAddress {
    fn new(max: u64) -> Self {
        Self {
            max,
            open: Arc::default(),
        }
    }

    fn open(&self) -> std::sync::MutexGuard<'_, HashMap<IpAddr, u64>> {
        self.open.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// One more connection from `ip`, or `None` when it holds its most.
    fn enter(&self, ip: IpAddr) -> Option<AddressSlot> {
        let mut open = self.open();
        let n = open.entry(ip).or_default();
        if *n >= self.max {
            return None;
        }
        *n += 1;
        Some(AddressSlot {
            ip,
            of: self.clone(),
        })
    }
}

/// One of an address's connections; the address has one fewer when it is dropped. The map
/// holds only addresses with a connection open, so it is bounded by the connection cap.
#[derive(Debug)]
struct AddressSlot {
    ip: IpAddr,
    of: PerAddress,
}

impl Drop for AddressSlot {
    fn drop(&mut self) {
        let mut open = self.of.open();
        if let Some(n) = open.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

/// What an accepted connection holds until it closes: a slot of the server's, and one of
/// its address's.
#[derive(Debug)]
struct Held {
    _slot: OwnedSemaphorePermit,
    _address: AddressSlot,
}

/// How long a request body may take.
#[derive(Debug, Clone, Copy)]
struct BodyLimits {
    timeout: Duration,
    /// Bytes a second; 0: no time past `timeout`.
    min_rate: u64,
}

/// Serves one connection until it closes, or until `stopped` says the server is stopping
/// (then open requests finish).
async fn connection<S>(
    http: Builder,
    app: Router,
    peer: SocketAddr,
    body: BodyLimits,
    io: Counted<S>,
    mut stopped: watch::Receiver<()>,
) where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let service = hyper::service::service_fn(move |req: Request<Incoming>| {
        let late = Arc::new(AtomicBool::new(false));
        let ended = Arc::new(AtomicBool::new(req.body().is_end_stream()));
        let mut req =
            req.map(|incoming| axum::body::Body::new(Timed::new(incoming, body, &late, &ended)));
        req.extensions_mut().insert(ConnectInfo::<SocketAddr>(peer));
        let answer = app.clone().oneshot(req);
        async move {
            let mut response = answer.await;
            // The handler saw its body fail, whatever it answered: the client was too slow.
            if late.load(Ordering::Relaxed) {
                tracing::debug!("the request body from {peer} was too slow");
                return Ok(too_slow(body));
            }
            // An answer given before its request's body was read (a refusal from the head
            // alone, a route that takes no body): hyper closes the connection after it
            // rather than read the rest, so the answer says so. Without it a client keeps
            // the connection for its next request and sends that into a closed socket.
            if !ended.load(Ordering::Relaxed)
                && let Ok(r) = response.as_mut()
            {
                r.headers_mut()
                    .insert(header::CONNECTION, HeaderValue::from_static("close"));
            }
            response
        }
    });
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

/// The answer to a request whose body did not arrive in time; the connection is closed after
/// it (the rest of the body is never read).
fn too_slow(limits: BodyLimits) -> Response<axum::body::Body> {
    let rate = if limits.min_rate > 0 {
        format!(
            ", or at {} bytes a second (--min-body-rate)",
            limits.min_rate
        )
    } else {
        String::new()
    };
    let body = ErrorBody {
        error: format!(
            "the request body did not arrive within {} ms of its head (--body-timeout-ms){rate}",
            limits.timeout.as_millis()
        ),
        fields: None,
    };
    let mut response = (StatusCode::REQUEST_TIMEOUT, axum::Json(body)).into_response();
    response
        .headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    response
}

/// Why a request body ended early.
#[derive(Debug, thiserror::Error)]
#[error("the request body did not arrive in time")]
struct TooSlow;

/// A request body with a deadline: it fails when it has not ended within `timeout` of its
/// head, unless it has averaged at least `min_rate` bytes a second since the head, checked
/// again whenever that average would fall below it. The failure is flagged in `late` for the
/// answer, and its end, once read, in `ended`.
struct Timed {
    inner: Incoming,
    limits: BodyLimits,
    started: Instant,
    received: u64,
    /// Armed at the first wait for data.
    check: Option<Pin<Box<Sleep>>>,
    late: Arc<AtomicBool>,
    ended: Arc<AtomicBool>,
}

impl Timed {
    fn new(
        inner: Incoming,
        limits: BodyLimits,
        late: &Arc<AtomicBool>,
        ended: &Arc<AtomicBool>,
    ) -> Self {
        Self {
            inner,
            limits,
            started: Instant::now(),
            received: 0,
            check: None,
            late: Arc::clone(late),
            ended: Arc::clone(ended),
        }
    }

    fn due(&self) -> Instant {
        self.started + allowed(self.limits, self.received)
    }
}

/// How long after its head a body may still be arriving, `received` bytes of it in: the
/// timeout, or longer while those bytes average the minimum rate.
fn allowed(limits: BodyLimits, received: u64) -> Duration {
    let at_rate = match limits.min_rate {
        0 => Duration::ZERO,
        rate => Duration::from_secs_f64(received as f64 / rate as f64),
    };
    limits.timeout.max(at_rate)
}

impl Body for Timed {
    type Data = Bytes;
    type Error = axum::BoxError;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let this = self.get_mut();
        match Pin::new(&mut this.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(data) = frame.data_ref() {
                    this.received += data.len() as u64;
                }
                if this.inner.is_end_stream() {
                    this.ended.store(true, Ordering::Relaxed);
                }
                return Poll::Ready(Some(Ok(frame)));
            }
            Poll::Ready(None) => {
                this.ended.store(true, Ordering::Relaxed);
                return Poll::Ready(None);
            }
            Poll::Ready(Some(Err(e))) => return Poll::Ready(Some(Err(e.into()))),
            Poll::Pending => {}
        }
        loop {
            let due = this.due();
            let check = this
                .check
                .get_or_insert_with(|| Box::pin(tokio::time::sleep_until(due)));
            if check.deadline() != due {
                check.as_mut().reset(due);
            }
            if check.as_mut().poll(cx).is_pending() {
                return Poll::Pending;
            }
            if this.due() <= Instant::now() {
                this.late.store(true, Ordering::Relaxed);
                return Poll::Ready(Some(Err(TooSlow.into())));
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

/// An accepted socket holding its connection slots: they are free again when the socket is
/// dropped, also after an upgrade to a WebSocket (hyper hands this same object over).
#[derive(Debug)]
struct Counted<S> {
    stream: S,
    _held: Held,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_body_has_its_timeout_or_longer_at_the_minimum_rate() {
        let limits = BodyLimits {
            timeout: Duration::from_secs(10),
            min_rate: 1000,
        };
        // A byte a second: cut at the timeout.
        assert_eq!(allowed(limits, 0), Duration::from_secs(10));
        assert_eq!(allowed(limits, 9_999), Duration::from_secs(10));
        // 25,000 bytes at 1,000 a second: 25 s, and so on while they keep coming.
        assert_eq!(allowed(limits, 25_000), Duration::from_secs(25));
        // Without a minimum rate, the timeout whatever arrived.
        let strict = BodyLimits {
            min_rate: 0,
            ..limits
        };
        assert_eq!(allowed(strict, 1 << 30), Duration::from_secs(10));
    }

    #[test]
    fn an_address_holds_at_most_its_connections_and_leaves_nothing_behind() {
        let per = PerAddress::new(2);
        let (a, b) = (IpAddr::from([10, 0, 0, 1]), IpAddr::from([10, 0, 0, 2]));
        let first = per.enter(a).unwrap();
        let second = per.enter(a).unwrap();
        assert!(per.enter(a).is_none(), "a third from a");
        let other = per.enter(b).expect("another address is not limited by a's");
        drop(first);
        let third = per.enter(a).expect("a closed connection frees its place");
        drop((second, third, other));
        assert!(per.open().is_empty(), "{:?}", per.open());
    }

    #[test]
    fn plain_http_is_sent_to_the_same_path_over_https_at_a_plausible_host_only() {
        let local: SocketAddr = "192.0.2.7:8443".parse().unwrap();
        let uri: axum::http::Uri = "/dashboard?study=3".parse().unwrap();
        for host in [
            "lab-pc:8443",
            "127.0.0.1:8443",
            "[::1]:8443",
            "lab-pc",
            "[fe80::1]",
        ] {
            let r = redirect_to_https(local, Some(&HeaderValue::from_static(host)), &uri);
            assert_eq!(r.status(), StatusCode::PERMANENT_REDIRECT, "{host}");
            assert_eq!(
                r.headers()[header::LOCATION],
                format!("https://{host}/dashboard?study=3"),
            );
        }
        // A Host that could make the redirect point elsewhere than a host, or none.
        let bad = [
            "",
            "evil@lab-pc",
            "lab pc",
            "lab-pc:",
            "lab-pc:99999",
            "lab-pc:0",
            "lab-pc/x",
            "::1",
            "[::1",
            "[zz::1]:80",
            "a..b",
            "lab-pc:80:80",
        ];
        for host in bad
            .iter()
            .map(|h| Some(HeaderValue::from_static(h)))
            .chain([None])
        {
            let r = redirect_to_https(local, host.as_ref(), &uri);
            assert_eq!(r.status(), StatusCode::BAD_REQUEST, "{host:?}");
            assert!(r.headers().get(header::LOCATION).is_none());
        }
        // An asterisk-form target (OPTIONS *) goes to the root.
        let star: axum::http::Uri = "*".parse().unwrap();
        let r = redirect_to_https(local, Some(&HeaderValue::from_static("lab-pc")), &star);
        assert_eq!(r.headers()[header::LOCATION], "https://lab-pc/");
    }

    #[test]
    fn the_refusal_is_a_whole_http_answer() {
        let answer = String::from_utf8(refusal_answer(128)).unwrap();
        let (head, body) = answer.split_once("\r\n\r\n").unwrap();
        assert!(
            head.starts_with("HTTP/1.1 429 Too Many Requests\r\n"),
            "{head}"
        );
        assert!(head.contains("\r\nretry-after: 1\r\n"), "{head}");
        assert!(
            head.contains(&format!("\r\ncontent-length: {}", body.len())),
            "{head}"
        );
        let json: serde_json::Value = serde_json::from_str(body).unwrap();
        assert!(json["error"].as_str().unwrap().contains("128"), "{json}");
    }
}
