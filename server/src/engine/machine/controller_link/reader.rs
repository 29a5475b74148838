//! The control connection's reader and its watchdog, on a thread of their own. The watchdog
//! must tell a hung controller from a busy server: on the server's async runtime a reader
//! that is not polled in time (the runtime busy with a filing, an export, a pilot; the store
//! holding a handler; the machine loaded) would count its own stall as the controller's
//! silence, declare the link lost and file every running test incomplete. Here the silence
//! is counted only while this thread waits on the socket: any byte that arrives counts as
//! heard (a long record chunk arriving is not silence), and the time spent handing a message
//! over to a busy server does not count at all. A controller that sends nothing for the
//! whole silence while the thread waits is hung, and is caught within that limit as before.

use std::io::Read;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::framing::{BlockingFramed, FrameError};
use tokio::sync::mpsc;

use super::HEARTBEAT;

/// What the reader hands the session: a message, or why the link ended.
pub(super) type Heard = Result<ControllerToServer, String>;

/// Messages read but not yet handled: past this the reader waits for the session (the time
/// it waits is not silence).
pub(super) const QUEUE: usize = 256;

/// Reads `stream` (after `buffered`, the bytes read with the handshake) on a new thread until
/// the link ends, each message into `out`; the last item is why it ended. The thread ends
/// when `out`'s receiver is gone, at the next message or silence, or when the socket is shut
/// down.
pub(super) fn spawn(
    stream: TcpStream,
    buffered: Vec<u8>,
    silence: Duration,
    out: mpsc::Sender<Heard>,
) -> std::io::Result<()> {
    std::thread::Builder::new()
        .name("controller-link-reader".into())
        .spawn(move || {
            let watched = match Watched::new(stream, silence) {
                Ok(w) => w,
                Err(e) => {
                    let _ = out.blocking_send(Err(format!("the link's reader: {e}")));
                    return;
                }
            };
            let mut framed: BlockingFramed<_, ControllerToServer, ()> =
                BlockingFramed::new(std::io::Cursor::new(buffered).chain(watched));
            loop {
                let (heard, last) = match framed.recv() {
                    Ok(Some(Ok(msg))) => (Ok(msg), false),
                    Ok(Some(Err(malformed))) => {
                        (Err(format!("the controller sent {malformed}")), true)
                    }
                    Ok(None) => (Err("link closed".to_string()), true),
                    Err(FrameError::Io(e)) if e.kind() == std::io::ErrorKind::TimedOut => (
                        Err(format!(
                            "the controller sent nothing for {} ms (it heartbeats every {} ms)",
                            silence.as_millis(),
                            HEARTBEAT.as_millis()
                        )),
                        true,
                    ),
                    Err(e) => (Err(format!("link closed ({e})")), true),
                };
                if out.blocking_send(heard).is_err() || last {
                    return;
                }
                // Handing the message over may have waited for a busy server: that wait is
                // not the controller's silence.
                framed.get_mut().get_mut().1.heard = Instant::now();
            }
        })
        .map(drop)
}

/// The socket, read only after it has something: a read fails `TimedOut` once it has been
/// silent for `silence` since `heard`.
struct Watched {
    stream: mio::net::TcpStream,
    poll: mio::Poll,
    events: mio::Events,
    heard: Instant,
    silence: Duration,
}

impl Watched {
    fn new(stream: std::net::TcpStream, silence: Duration) -> std::io::Result<Self> {
        let mut stream = mio::net::TcpStream::from_std(stream);
        let poll = mio::Poll::new()?;
        poll.registry()
            .register(&mut stream, mio::Token(0), mio::Interest::READABLE)?;
        Ok(Self {
            stream,
            poll,
            events: mio::Events::with_capacity(1),
            heard: Instant::now(),
            silence,
        })
    }
}

impl Read for Watched {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            // Tried first, whatever the time: what is already there counts, however late
            // this thread ran (and an edge-triggered poll reports only what arrives later).
            match self.stream.read(buf) {
                Ok(n) => {
                    self.heard = Instant::now();
                    return Ok(n);
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
            let left = (self.heard + self.silence).saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(std::io::ErrorKind::TimedOut.into());
            }
            match self.poll.poll(&mut self.events, Some(left)) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
    }
}
