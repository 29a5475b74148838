//! The sessions the E-stop is authenticated from without the database: every session the
//! store confirmed recently, in memory. A store held by a long write (an erasure, a backup,
//! a pilot filing) must not keep an experimenter's E-stop waiting for its session lookup.
//!
//! Only `POST /api/estop` reads it; every other route asks the store. A session remembered
//! here after its account was disabled can therefore press the E-stop and nothing else, for
//! at most [`FRESH`]; a logout forgets it at once.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crate::store::accounts::SessionOwner;
use crate::store::tokens::token_hash;

/// How long a session confirmed by the store is believed without asking it again.
pub const FRESH: Duration = Duration::from_secs(3600);

/// Sessions remembered at most (the oldest is forgotten first): more than a lab has
/// experimenters logged in at once.
const CAPACITY: usize = 256;

#[derive(Debug, Default)]
pub struct EStopSessions {
    known: Mutex<HashMap<String, (SessionOwner, Instant)>>,
}

impl EStopSessions {
    /// Remembers that the store confirmed `token` as `owner`'s session just now.
    pub fn confirmed(&self, token: &str, owner: &SessionOwner) {
        let mut known = self.known.lock().unwrap_or_else(|p| p.into_inner());
        let now = Instant::now();
        known.retain(|_, (_, at)| now.duration_since(*at) < FRESH);
        if known.len() >= CAPACITY
            && let Some(oldest) = known
                .iter()
                .min_by_key(|(_, (_, at))| *at)
                .map(|(k, _)| k.clone())
        {
            known.remove(&oldest);
        }
        known.insert(token_hash(token), (owner.clone(), now));
    }

    /// The owner of `token` if the store confirmed it within [`FRESH`].
    pub fn owner(&self, token: &str) -> Option<SessionOwner> {
        let known = self.known.lock().unwrap_or_else(|p| p.into_inner());
        let (owner, at) = known.get(&token_hash(token))?;
        (at.elapsed() < FRESH).then(|| owner.clone())
    }

    /// Forgets `token` (its session ended).
    pub fn ended(&self, token: &str) {
        self.known
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .remove(&token_hash(token));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::accounts::Role;

    fn owner(name: &str) -> SessionOwner {
        SessionOwner {
            id: 1,
            username: name.into(),
            role: Role::Experimenter,
            csrf: "c".into(),
        }
    }

    #[test]
    fn a_confirmed_session_is_known_until_it_ends_and_the_oldest_goes_first() {
        let s = EStopSessions::default();
        assert!(s.owner("t0").is_none());
        s.confirmed("t0", &owner("ada"));
        assert_eq!(s.owner("t0").map(|o| o.username), Some("ada".into()));
        s.ended("t0");
        assert!(s.owner("t0").is_none());
        for i in 0..=CAPACITY {
            s.confirmed(&format!("t{i}"), &owner("x"));
        }
        assert!(
            s.owner("t0").is_none(),
            "the oldest of CAPACITY + 1 is forgotten"
        );
        assert!(s.owner(&format!("t{CAPACITY}")).is_some());
    }
}
