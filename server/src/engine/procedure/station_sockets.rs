//! The stations' live sockets: one at a time per station (the newest replaces the older),
//! what each sent, and the operator-input rate limit every station socket applies.
//!
//! The newest socket wins rather than the first because the common case is a page that was
//! reloaded or reopened while its old socket still looks open to the server (a laptop
//! woke up, a tab was duplicated): refusing the newcomer would leave the subject with a
//! dead page and the experimenter with no way but a restart. The replaced page is told
//! (its socket closes with `station_close::REPLACED`) and does not reconnect, so two pages
//! of one station never take turns feeding a test.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bdft_protocol::server_to_browser::StationSocket;
use tokio::sync::oneshot;

/// Sustained messages a second a station may send: twice the most its page sends (one per
/// frame, at most 250 a second), so a page never loses input to the limit.
pub const INPUT_RATE: f64 = 500.0;
/// Messages a station may send at once above the rate: 0.2 s of input, so a bunch the
/// network delivers together after a hiccup passes whole.
pub const INPUT_BURST: f64 = 100.0;
/// A second with more messages than this is a flood second: 8 times what a page sends.
pub const FLOOD_PER_SECOND: u32 = 2_000;
/// Flood seconds in a row after which the station is disconnected: a flood that long is no
/// burst but a broken or hostile page, and reading it costs the server for nothing.
pub const FLOOD_SECONDS: u32 = 3;

/// What to do with a message a station sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admit {
    /// Within the limit: read it.
    Accept,
    /// Over the limit: drop it unread.
    Drop,
    /// The station has flooded for [`FLOOD_SECONDS`]: close its socket.
    Disconnect,
}

/// The rate limit of one socket: a token bucket ([`INPUT_RATE`], [`INPUT_BURST`]) and a
/// count of messages per whole second for the flood rule. Time is passed in.
#[derive(Debug)]
pub struct InputLimit {
    tokens: f64,
    refilled_at: Instant,
    second_started: Instant,
    this_second: u32,
    flood_seconds: u32,
}

impl InputLimit {
    pub fn new(now: Instant) -> Self {
        Self {
            tokens: INPUT_BURST,
            refilled_at: now,
            second_started: now,
            this_second: 0,
            flood_seconds: 0,
        }
    }

    /// A message arrived at `now`.
    pub fn admit(&mut self, now: Instant) -> Admit {
        let second = Duration::from_secs(1);
        let since = now.saturating_duration_since(self.second_started);
        if since >= second {
            // A second that ended flooding continues the run; a quiet one (or a gap of
            // more than a second) ends it.
            let flooded = self.this_second > FLOOD_PER_SECOND && since < 2 * second;
            self.flood_seconds = if flooded { self.flood_seconds + 1 } else { 0 };
            self.second_started = now;
            self.this_second = 0;
        }
        self.this_second = self.this_second.saturating_add(1);
        if self.flood_seconds >= FLOOD_SECONDS {
            return Admit::Disconnect;
        }
        let elapsed = now
            .saturating_duration_since(self.refilled_at)
            .as_secs_f64();
        self.tokens = (self.tokens + elapsed * INPUT_RATE).min(INPUT_BURST);
        self.refilled_at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            Admit::Accept
        } else {
            Admit::Drop
        }
    }
}

/// The counters of one socket, shared between its task and the experimenter's view.
#[derive(Debug, Default)]
pub struct SocketCounts {
    pub accepted: AtomicU64,
    pub dropped: AtomicU64,
    connected: AtomicBool,
    closed_by_server: Mutex<Option<String>>,
}

#[derive(Debug)]
struct Slot {
    /// Fired to close this socket when a newer one of the station opens.
    replace: Option<oneshot::Sender<()>>,
    counts: Arc<SocketCounts>,
}

/// Each station's newest socket (one entry per station that connected since the server
/// started: bounded by the stations the experimenters paired).
#[derive(Debug, Default)]
pub struct StationSockets {
    slots: Mutex<HashMap<i64, Slot>>,
}

/// A socket that is the station's one live socket until `replaced` fires.
#[derive(Debug)]
pub struct Opened {
    pub replaced: oneshot::Receiver<()>,
    pub counts: Arc<SocketCounts>,
}

impl StationSockets {
    fn slots(&self) -> std::sync::MutexGuard<'_, HashMap<i64, Slot>> {
        self.slots.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A new socket of `station_id`; the one it had before is told to close.
    pub fn open(&self, station_id: i64) -> Opened {
        let (replace, replaced) = oneshot::channel();
        let counts = Arc::new(SocketCounts::default());
        counts.connected.store(true, Ordering::SeqCst);
        let old = self.slots().insert(
            station_id,
            Slot {
                replace: Some(replace),
                counts: Arc::clone(&counts),
            },
        );
        if let Some(tell) = old.and_then(|mut o| o.replace.take()) {
            let _ = tell.send(());
        }
        Opened { replaced, counts }
    }

    /// The socket has ended; `why` when the server closed it. (A replaced socket's slot
    /// already holds its successor; the newest one's counts stay for the experimenter.)
    pub fn closed(&self, opened: &Opened, why: Option<String>) {
        opened.counts.connected.store(false, Ordering::SeqCst);
        *opened
            .counts
            .closed_by_server
            .lock()
            .unwrap_or_else(|p| p.into_inner()) = why;
    }

    /// The station's newest socket, for the experimenter.
    pub fn view(&self, station_id: i64) -> Option<StationSocket> {
        let slots = self.slots();
        let c = &slots.get(&station_id)?.counts;
        Some(StationSocket {
            connected: c.connected.load(Ordering::SeqCst),
            accepted: c.accepted.load(Ordering::Relaxed),
            dropped: c.dropped.load(Ordering::Relaxed),
            closed_by_server: c
                .closed_by_server
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(t0: Instant, ms: u64) -> Instant {
        t0 + Duration::from_millis(ms)
    }

    #[test]
    fn a_page_at_its_fastest_loses_nothing() {
        let t0 = Instant::now();
        let mut limit = InputLimit::new(t0);
        // 250 messages a second for ten seconds.
        for i in 0..2500 {
            assert_eq!(limit.admit(at(t0, i * 4)), Admit::Accept, "message {i}");
        }
    }

    #[test]
    fn a_flood_is_cut_to_the_rate_and_then_disconnected() {
        let t0 = Instant::now();
        let mut limit = InputLimit::new(t0);
        // 10 000 messages a second (one every 100 µs).
        let mut accepted = 0;
        let mut i = 0u64;
        let verdict = loop {
            let now = t0 + Duration::from_micros(i * 100);
            match limit.admit(now) {
                Admit::Accept => accepted += 1,
                Admit::Drop => {}
                Admit::Disconnect => break now - t0,
            }
            i += 1;
        };
        // Disconnected once three whole seconds flooded (at the first message of the
        // fourth), having let through the burst and the rate, no more.
        assert_eq!(verdict, Duration::from_secs(3));
        let most = INPUT_BURST + INPUT_RATE * 3.0;
        assert!(accepted as f64 <= most, "{accepted} accepted");
        assert!(accepted as f64 >= most - 2.0, "{accepted} accepted");
    }

    #[test]
    fn a_burst_passes_and_a_quiet_second_ends_a_flood_run() {
        let t0 = Instant::now();
        let mut limit = InputLimit::new(t0);
        // A bunch of 100 at once passes; the next one at the same instant does not.
        for _ in 0..100 {
            assert_eq!(limit.admit(t0), Admit::Accept);
        }
        assert_eq!(limit.admit(t0), Admit::Drop);
        // Two flood seconds, a quiet one, two more: never three in a row.
        let mut t = t0;
        for second in 0..5u64 {
            let n = if second == 2 { 10 } else { 5000 };
            for k in 0..n {
                t = t0 + Duration::from_secs(second) + Duration::from_micros(k * 1_000_000 / n);
                assert_ne!(limit.admit(t), Admit::Disconnect, "second {second}");
            }
        }
        assert!(t > t0);
    }

    #[test]
    fn a_newer_socket_replaces_the_older() {
        let sockets = StationSockets::default();
        let mut first = sockets.open(7);
        let second = sockets.open(7);
        assert!(first.replaced.try_recv().is_ok(), "the first was told");
        sockets.closed(&first, Some("replaced".into()));
        // The view is the newest socket's, still open.
        assert_eq!(sockets.view(7).map(|v| v.connected), Some(true));
        sockets.closed(&second, None);
        assert_eq!(sockets.view(7).map(|v| v.connected), Some(false));
        assert!(sockets.view(8).is_none());
    }
}
