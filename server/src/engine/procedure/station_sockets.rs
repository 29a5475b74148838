//! The stations' live sockets: one at a time per station (the newest replaces the older),
//! what each sent, and the limits that bound what one station costs the server: how often
//! it may open a socket, how much all its sockets together are read, and how much input
//! of that is used.
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

use crate::store::tokens::token_hash;

/// Sustained messages a second a station may send: twice the most its page sends (one per
/// frame, at most 250 a second), so a page never loses input to the limit.
pub const INPUT_RATE: f64 = 500.0;
/// Messages a station may send at once above the rate: 0.2 s of input, so a bunch the
/// network delivers together after a hiccup passes whole.
pub const INPUT_BURST: f64 = 100.0;
/// Messages a second a station's sockets are read at all, all of them together: 4 times
/// [`INPUT_RATE`], so a page a little over its rate is seen dropping input (counted for the
/// experimenter). Beyond it they are not read: the rest waits in the network, TCP flow
/// control slows the sender, and a flood costs the server this much reading and no more,
/// whatever the number of sockets.
pub const READ_RATE: f64 = 2_000.0;
/// Messages read at once above [`READ_RATE`].
const READ_BURST: f64 = 200.0;
/// A held-back station is read again once the budget of this many messages is back: a
/// wake-up per batch (25 ms at the read rate), not one per message.
const READ_BATCH: f64 = 50.0;
/// Seconds in a row in which a station was held back at [`READ_RATE`] after which its
/// sockets are disconnected: a flood that long is no burst but a broken or hostile page.
pub const FLOOD_SECONDS: u32 = 3;

/// What to do with a message a station sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admit {
    /// Within the limit: read it.
    Accept,
    /// Over the limit: drop it unparsed.
    Drop,
    /// The station has flooded for [`FLOOD_SECONDS`]: close its socket.
    Disconnect,
}

/// A token bucket: `rate` tokens a second up to `burst`. Time is passed in.
#[derive(Debug)]
struct Bucket {
    rate: f64,
    burst: f64,
    tokens: f64,
    refilled_at: Instant,
}

impl Bucket {
    fn full(rate: f64, burst: f64, now: Instant) -> Self {
        Self {
            rate,
            burst,
            tokens: burst,
            refilled_at: now,
        }
    }

    fn refill(&mut self, now: Instant) {
        let elapsed = now.saturating_duration_since(self.refilled_at);
        self.tokens = (self.tokens + elapsed.as_secs_f64() * self.rate).min(self.burst);
        self.refilled_at = now;
    }

    /// Takes a token if there is one.
    fn take(&mut self, now: Instant) -> bool {
        self.refill(now);
        let there = self.tokens >= 1.0;
        if there {
            self.tokens -= 1.0;
        }
        there
    }

    /// When the bucket holds `n` tokens (now if it does).
    fn holds_at(&self, n: f64) -> Instant {
        let missing = (n - self.tokens).max(0.0);
        self.refilled_at + Duration::from_secs_f64(missing / self.rate)
    }
}

/// What all the sockets of one station may be read ([`READ_RATE`]), and the flood rule
/// counted over whole seconds.
#[derive(Debug)]
pub struct ReadBudget(Mutex<Reads>);

#[derive(Debug)]
struct Reads {
    bucket: Bucket,
    second_started: Instant,
    /// Whether the station was held back in the current second.
    held_this_second: bool,
    flood_seconds: u32,
}

impl ReadBudget {
    pub fn new(now: Instant) -> Self {
        Self(Mutex::new(Reads {
            bucket: Bucket::full(READ_RATE, READ_BURST, now),
            second_started: now,
            held_this_second: false,
            flood_seconds: 0,
        }))
    }

    fn reads(&self) -> std::sync::MutexGuard<'_, Reads> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// When a socket of the station may be read next: `None` now; otherwise the budget is
    /// spent and the reader waits until then (the wait counts the second as held back).
    pub fn hold_until(&self, now: Instant) -> Option<Instant> {
        let mut r = self.reads();
        r.bucket.refill(now);
        if r.bucket.tokens >= 1.0 {
            return None;
        }
        r.held_this_second = true;
        Some(r.bucket.holds_at(READ_BATCH))
    }

    /// A message was read at `now`; whether the station has now been held back for
    /// [`FLOOD_SECONDS`] in a row.
    pub fn read(&self, now: Instant) -> bool {
        let mut r = self.reads();
        let second = Duration::from_secs(1);
        let since = now.saturating_duration_since(r.second_started);
        if since >= second {
            // A second that ended held back continues the run; a quiet one (or a gap of
            // more than a second) ends it.
            let flooded = r.held_this_second && since < 2 * second;
            r.flood_seconds = if flooded { r.flood_seconds + 1 } else { 0 };
            r.second_started = now;
            r.held_this_second = false;
        }
        // What a reader read beyond the budget (it does not, when it waits as told) is
        // taken from it all the same.
        if !r.bucket.take(now) {
            r.held_this_second = true;
        }
        r.flood_seconds >= FLOOD_SECONDS
    }
}

/// The input limit of one socket: of what is read, [`INPUT_RATE`] messages a second
/// ([`INPUT_BURST`] at once) are used; and the station's flood rule.
#[derive(Debug)]
pub struct InputLimit {
    budget: Arc<ReadBudget>,
    accept: Bucket,
}

impl InputLimit {
    pub fn new(budget: Arc<ReadBudget>, now: Instant) -> Self {
        Self {
            budget,
            accept: Bucket::full(INPUT_RATE, INPUT_BURST, now),
        }
    }

    /// A message was read at `now`.
    pub fn admit(&mut self, now: Instant) -> Admit {
        if self.budget.read(now) {
            Admit::Disconnect
        } else if self.accept.take(now) {
            Admit::Accept
        } else {
            Admit::Drop
        }
    }
}

/// Sockets a station may open at once, and then [`OPENINGS_PER_SECOND`]: a page opens one
/// when it loads and again a second after a lost connection (5 s after a flood); more is
/// no page, and each costs the server an upgrade and its queries.
pub const OPENING_BURST: f64 = 4.0;
pub const OPENINGS_PER_SECOND: f64 = 1.0;

/// The counters of one socket, shared between its task and the experimenter's view.
#[derive(Debug, Default)]
pub struct SocketCounts {
    pub accepted: AtomicU64,
    pub dropped: AtomicU64,
    connected: AtomicBool,
    /// Set (before its successor is handed out) when a newer socket replaced this one.
    replaced: AtomicBool,
    closed_by_server: Mutex<Option<String>>,
}

#[derive(Debug)]
struct Slot {
    /// Fired to close this socket when a newer one of the station opens.
    replace: Option<oneshot::Sender<()>>,
    counts: Arc<SocketCounts>,
}

/// What the server holds of one station's sockets.
#[derive(Debug)]
struct Station {
    /// The newest socket (kept after it closed, for the experimenter's view).
    newest: Option<Slot>,
    openings: Bucket,
    budget: Arc<ReadBudget>,
}

impl Station {
    /// `station_id`'s entry, made when it first connects.
    fn of(stations: &mut HashMap<i64, Station>, station_id: i64, now: Instant) -> &mut Station {
        stations.entry(station_id).or_insert_with(|| Station {
            newest: None,
            openings: Bucket::full(OPENINGS_PER_SECOND, OPENING_BURST, now),
            budget: Arc::new(ReadBudget::new(now)),
        })
    }
}

/// Each station's newest socket (one entry per station that connected since the server
/// started: bounded by the stations the experimenters paired).
#[derive(Debug, Default)]
pub struct StationSockets {
    stations: Mutex<HashMap<i64, Station>>,
    /// The station of each token that opened a socket (by the token's hash, as the database
    /// keeps it; one entry per token that ever opened one): an opening over the limit is
    /// refused without a query. Used to refuse only, never to let in, so a token revoked
    /// since is no way in.
    known: Mutex<HashMap<String, i64>>,
}

/// A socket that is the station's one live socket until `replaced` fires.
#[derive(Debug)]
pub struct Opened {
    pub replaced: oneshot::Receiver<()>,
    pub counts: Arc<SocketCounts>,
    /// The station's read budget, shared by all its sockets.
    pub budget: Arc<ReadBudget>,
}

impl Opened {
    /// Whether a newer socket of the station has opened: from then on nothing this one
    /// reads is used (the newer one is read instead, never both).
    pub fn is_replaced(&self) -> bool {
        self.counts.replaced.load(Ordering::SeqCst)
    }
}

impl StationSockets {
    fn stations(&self) -> std::sync::MutexGuard<'_, HashMap<i64, Station>> {
        self.stations.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether an opening with `token` at `now` is refused before its token is looked up: it
    /// opened a socket before and its station has no opening left ([`OPENING_BURST`],
    /// [`OPENINGS_PER_SECOND`]). A station trying again and again costs no query a try.
    pub fn known_over_limit(&self, token: &str, now: Instant) -> bool {
        let known = self.known.lock().unwrap_or_else(|p| p.into_inner());
        let Some(&station_id) = known.get(&token_hash(token)) else {
            return false;
        };
        drop(known);
        let mut stations = self.stations();
        let openings = &mut Station::of(&mut stations, station_id, now).openings;
        openings.refill(now);
        openings.tokens < 1.0
    }

    /// Whether `station_id`, whose `token` was just looked up, may open a socket at `now`
    /// ([`OPENING_BURST`], [`OPENINGS_PER_SECOND`]); asked before the upgrade.
    pub fn may_open(&self, station_id: i64, token: &str, now: Instant) -> bool {
        self.known
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(token_hash(token), station_id);
        Station::of(&mut self.stations(), station_id, now)
            .openings
            .take(now)
    }

    /// A new socket of `station_id`; the one it had before is marked replaced and told to
    /// close.
    pub fn open(&self, station_id: i64) -> Opened {
        let (replace, replaced) = oneshot::channel();
        let counts = Arc::new(SocketCounts::default());
        counts.connected.store(true, Ordering::SeqCst);
        let mut stations = self.stations();
        let station = Station::of(&mut stations, station_id, Instant::now());
        let old = station.newest.replace(Slot {
            replace: Some(replace),
            counts: Arc::clone(&counts),
        });
        if let Some(mut old) = old {
            old.counts.replaced.store(true, Ordering::SeqCst);
            if let Some(tell) = old.replace.take() {
                let _ = tell.send(());
            }
        }
        Opened {
            replaced,
            counts,
            budget: Arc::clone(&station.budget),
        }
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
        let stations = self.stations();
        let c = &stations.get(&station_id)?.newest.as_ref()?.counts;
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

    fn limit(t0: Instant) -> (Arc<ReadBudget>, InputLimit) {
        let budget = Arc::new(ReadBudget::new(t0));
        (Arc::clone(&budget), InputLimit::new(budget, t0))
    }

    #[test]
    fn a_page_at_its_fastest_loses_nothing() {
        let t0 = Instant::now();
        let (budget, mut limit) = limit(t0);
        // 250 messages a second for ten seconds: never held back, all accepted.
        for i in 0..2500 {
            assert_eq!(budget.hold_until(at(t0, i * 4)), None, "message {i}");
            assert_eq!(limit.admit(at(t0, i * 4)), Admit::Accept, "message {i}");
        }
    }

    /// Peers that always have a message waiting on each of `sockets` sockets of one
    /// station, read in turn as fast as the reader may (it waits when held back, and a read
    /// takes 10 µs): (messages read, accepted, when they were disconnected).
    fn flood_read_as_allowed(t0: Instant, sockets: usize) -> (u64, u64, Duration) {
        let budget = Arc::new(ReadBudget::new(t0));
        let mut limits: Vec<_> = (0..sockets)
            .map(|_| InputLimit::new(Arc::clone(&budget), t0))
            .collect();
        let (mut read, mut accepted, mut now) = (0u64, 0u64, t0);
        loop {
            for limit in &mut limits {
                if let Some(until) = budget.hold_until(now) {
                    assert!(until > now, "a hold ends later");
                    now = until;
                }
                read += 1;
                match limit.admit(now) {
                    Admit::Accept => accepted += 1,
                    Admit::Drop => {}
                    Admit::Disconnect => return (read, accepted, now - t0),
                }
                now += Duration::from_micros(10);
            }
        }
    }

    /// Checks that a flood was disconnected once three whole seconds were held back (at the
    /// first message of the fourth), having read no more than the read budget; returns the
    /// most it may have read.
    fn assert_read_budget_then_disconnected(read: u64, after: Duration) -> f64 {
        assert!(
            after >= Duration::from_secs(3) && after < Duration::from_millis(3100),
            "{after:?}"
        );
        let most_read = READ_BURST + READ_RATE * after.as_secs_f64() + 1.0;
        assert!(read as f64 <= most_read, "{read} read in {after:?}");
        most_read
    }

    #[test]
    fn a_flood_is_read_at_the_read_rate_and_then_disconnected() {
        let t0 = Instant::now();
        let (read, accepted, after) = flood_read_as_allowed(t0, 1);
        // Having read the read budget and accepted the input budget, no more.
        let most_read = assert_read_budget_then_disconnected(read, after);
        let secs = after.as_secs_f64();
        assert!(read as f64 >= most_read - READ_BATCH - 2.0, "{read} read");
        let most_accepted = INPUT_BURST + INPUT_RATE * secs;
        assert!(accepted as f64 <= most_accepted, "{accepted} accepted");
        // (The input budget of the last hold is not used: its first message disconnects.)
        let last_hold = INPUT_RATE * READ_BATCH / READ_RATE;
        assert!(
            accepted as f64 >= most_accepted - last_hold - 2.0,
            "{accepted} accepted, {read} read in {after:?}"
        );
    }

    #[test]
    fn a_station_is_read_at_the_read_rate_whatever_its_sockets() {
        let t0 = Instant::now();
        let (read, accepted, after) = flood_read_as_allowed(t0, 16);
        assert_read_budget_then_disconnected(read, after);
        // Each socket has its own input limit; together they use no more than was read.
        assert!(accepted <= read, "{accepted} accepted");
    }

    #[test]
    fn a_flood_read_regardless_is_disconnected_too() {
        let t0 = Instant::now();
        let (_, mut limit) = limit(t0);
        // 10 000 messages a second (one every 100 µs), the holds not kept.
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
        assert_eq!(verdict, Duration::from_secs(3));
        let most = INPUT_BURST + INPUT_RATE * 3.0;
        assert!(accepted as f64 <= most, "{accepted} accepted");
        assert!(accepted as f64 >= most - 2.0, "{accepted} accepted");
    }

    #[test]
    fn a_burst_passes_and_a_quiet_second_ends_a_flood_run() {
        let t0 = Instant::now();
        let (_, mut limit) = limit(t0);
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
        assert!(!first.is_replaced());
        let second = sockets.open(7);
        // Marked before the newer one is handed out: never both read.
        assert!(first.is_replaced() && !second.is_replaced());
        assert!(first.replaced.try_recv().is_ok(), "the first was told");
        // Both spend the station's one read budget.
        assert!(Arc::ptr_eq(&first.budget, &second.budget));
        assert!(!Arc::ptr_eq(&first.budget, &sockets.open(8).budget));
        sockets.closed(&first, Some("replaced".into()));
        // The view is the newest socket's, still open.
        assert_eq!(sockets.view(7).map(|v| v.connected), Some(true));
        sockets.closed(&second, None);
        assert_eq!(sockets.view(7).map(|v| v.connected), Some(false));
        assert!(sockets.view(9).is_none());
    }

    #[test]
    fn a_station_opens_a_few_sockets_at_once_then_one_a_second() {
        let sockets = StationSockets::default();
        let t0 = Instant::now();
        // A token not seen yet is looked up.
        assert!(!sockets.known_over_limit("seven", t0));
        for i in 0..OPENING_BURST as u64 {
            assert!(!sockets.known_over_limit("seven", at(t0, i)), "opening {i}");
            assert!(sockets.may_open(7, "seven", at(t0, i)), "opening {i}");
        }
        // Over the limit: refused before the lookup, and after it.
        assert!(sockets.known_over_limit("seven", at(t0, 10)));
        assert!(!sockets.may_open(7, "seven", at(t0, 10)));
        // Another station is not held back by this one.
        assert!(!sockets.known_over_limit("eight", at(t0, 10)));
        assert!(sockets.may_open(8, "eight", at(t0, 10)));
        assert!(!sockets.may_open(7, "seven", at(t0, 900)));
        assert!(!sockets.known_over_limit("seven", at(t0, 1010)));
        assert!(sockets.may_open(7, "seven", at(t0, 1010)));
        assert!(!sockets.may_open(7, "seven", at(t0, 1020)));
        // Asking is no opening: no view before a socket opened.
        assert!(sockets.view(7).is_none());
    }
}
