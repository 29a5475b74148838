//! The login rate limit: attempts per (username, client address) and per client address in a
//! sliding window. An attempt is *reserved* before its password is checked, so a burst of
//! concurrent attempts counts in full instead of all passing the check before the first
//! failure is recorded. Memory is bounded: every key holds at most its limit of instants,
//! expired keys are swept, and past [`MAX_KEYS`] distinct keys new ones are refused (a
//! spray of usernames or addresses is then held off until the window frees room) rather
//! than evicting the records of an attack in progress.

use std::collections::{HashMap, VecDeque};
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Distinct keys (username at address, or address) held at most.
pub const MAX_KEYS: usize = 10_000;

/// How many attempts the limiter allows in its window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoginLimits {
    /// Failed attempts per username from one client address.
    pub per_user_address: usize,
    /// Failed attempts from one client address, whatever the usernames.
    pub per_address: usize,
    pub window: Duration,
}

impl Default for LoginLimits {
    fn default() -> Self {
        Self {
            per_user_address: 5,
            per_address: 20,
            window: Duration::from_secs(60),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Key {
    UserAt(String, IpAddr),
    Address(IpAddr),
}

/// An attempt counted by [`LoginLimiter::reserve`]; it stays counted (as a failure) unless
/// given back to [`LoginLimiter::succeeded`].
#[derive(Debug)]
#[must_use]
pub struct Reservation {
    user_at: Key,
    address: Key,
    at: Instant,
}

#[derive(Debug)]
pub struct LoginLimiter {
    limits: LoginLimits,
    state: Mutex<State>,
}

#[derive(Debug)]
struct State {
    attempts: HashMap<Key, VecDeque<Instant>>,
    last_sweep: Instant,
}

impl Default for LoginLimiter {
    fn default() -> Self {
        Self::new(LoginLimits::default())
    }
}

impl LoginLimiter {
    pub fn new(limits: LoginLimits) -> Self {
        Self {
            limits,
            state: Mutex::new(State {
                attempts: HashMap::new(),
                last_sweep: Instant::now(),
            }),
        }
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Counts an attempt of `username` from `addr` at `now`; when a limit is reached (or the
    /// limiter is full), how long until an attempt can be counted again.
    pub fn reserve(
        &self,
        username: &str,
        addr: IpAddr,
        now: Instant,
    ) -> Result<Reservation, Duration> {
        let window = self.limits.window;
        let live = |t: &Instant| now.saturating_duration_since(*t) < window;
        let mut state = self.state();
        if now.saturating_duration_since(state.last_sweep) >= window
            || state.attempts.len() + 2 > MAX_KEYS
        {
            state.attempts.retain(|_, times| {
                times.retain(live);
                !times.is_empty()
            });
            state.last_sweep = now;
        }
        let user_at = Key::UserAt(username.to_string(), addr);
        let address = Key::Address(addr);
        let new_keys = [&user_at, &address]
            .iter()
            .filter(|k| !state.attempts.contains_key(**k))
            .count();
        if state.attempts.len() + new_keys > MAX_KEYS {
            // The next sweep, a window after the last, frees the expired keys.
            return Err((state.last_sweep + window).saturating_duration_since(now));
        }
        for (key, limit) in [
            (&user_at, self.limits.per_user_address),
            (&address, self.limits.per_address),
        ] {
            if let Some(times) = state.attempts.get_mut(key) {
                times.retain(live);
                if times.len() >= limit {
                    // Free again when the oldest attempt leaves the window.
                    let oldest = times.front().copied().unwrap_or(now);
                    return Err((oldest + window).saturating_duration_since(now));
                }
            }
        }
        for key in [&user_at, &address] {
            state
                .attempts
                .entry(key.clone())
                .or_default()
                .push_back(now);
        }
        Ok(Reservation {
            user_at,
            address,
            at: now,
        })
    }

    /// The attempt was a successful login: it does not count, and neither do the earlier
    /// failures of this username from this address.
    pub fn succeeded(&self, r: Reservation) {
        let mut state = self.state();
        state.attempts.remove(&r.user_at);
        if let Some(times) = state.attempts.get_mut(&r.address) {
            if let Some(i) = times.iter().position(|t| *t == r.at) {
                times.remove(i);
            }
            if times.is_empty() {
                state.attempts.remove(&r.address);
            }
        }
    }

    /// Distinct keys held (for tests of the bound).
    #[cfg(test)]
    fn keys(&self) -> usize {
        self.state().attempts.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(last: u8) -> IpAddr {
        IpAddr::from([10, 0, 0, last])
    }

    #[test]
    fn attempts_are_counted_when_reserved_per_user_and_per_address() {
        let l = LoginLimiter::default();
        let t0 = Instant::now();
        let held: Vec<_> = (0..5)
            .filter_map(|_| l.reserve("ann", ip(1), t0).ok())
            .collect();
        assert_eq!(held.len(), 5);
        assert!(l.reserve("ann", ip(1), t0).is_err(), "6th for ann@1");
        // Refused until the oldest attempt leaves the window.
        assert_eq!(
            l.reserve("ann", ip(1), t0 + Duration::from_secs(10))
                .unwrap_err(),
            Duration::from_secs(50)
        );
        assert!(l.reserve("ann", ip(2), t0).is_ok(), "another address");
        // The address limit holds across usernames: 5 (ann) + 15 more names, then none.
        let names: Vec<_> = (0..20)
            .filter_map(|i| l.reserve(&format!("user{i}"), ip(1), t0).ok())
            .collect();
        assert_eq!(names.len(), 15);
        // A window later everything is free again.
        assert!(
            l.reserve("ann", ip(1), t0 + Duration::from_secs(60))
                .is_ok()
        );
    }

    #[test]
    fn a_success_gives_its_attempt_back() {
        let l = LoginLimiter::default();
        let t0 = Instant::now();
        for _ in 0..4 {
            let _ = l.reserve("ann", ip(1), t0);
        }
        let ok = l.reserve("ann", ip(1), t0).unwrap();
        l.succeeded(ok);
        assert_eq!(
            (0..10)
                .filter_map(|_| l.reserve("ann", ip(1), t0).ok())
                .count(),
            5,
            "ann's failures were forgotten at her login"
        );
    }

    #[test]
    fn expired_keys_are_swept_and_distinct_keys_are_capped() {
        let l = LoginLimiter::new(LoginLimits {
            per_user_address: 5,
            per_address: 5,
            window: Duration::from_secs(60),
        });
        let t0 = Instant::now();
        // Every address a key, every (name, address) another: MAX_KEYS / 2 attempts fill it.
        let mut taken = 0;
        for i in 0..MAX_KEYS {
            let addr = IpAddr::from(std::net::Ipv6Addr::from(i as u128));
            if l.reserve("x", addr, t0).is_ok() {
                taken += 1;
            }
        }
        assert_eq!(taken, MAX_KEYS / 2);
        assert_eq!(l.keys(), MAX_KEYS);
        assert_eq!(
            l.reserve("y", ip(1), t0).unwrap_err(),
            Duration::from_secs(60),
            "full: refused until the next sweep, not evicted"
        );
        // After the window the expired keys are swept and room is back.
        let later = t0 + Duration::from_secs(61);
        assert!(l.reserve("y", ip(1), later).is_ok());
        assert_eq!(l.keys(), 2);
    }
}
