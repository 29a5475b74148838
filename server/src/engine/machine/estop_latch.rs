//! The E-stop latch as this server holds it: in memory, and in a file of its own beside the
//! audit key (`<stem>.estop-latch`), never behind the store's write lock. A press sets the
//! latch in memory at once (starts are refused from that moment) and writes the file
//! (fsynced) while the controllers confirm; the press's audit row and the store's latch rows
//! follow when the store allows ([`record_pending`]): the press waits in the file until they
//! are committed, so a store that is busy for minutes, or a server killed meanwhile, delays
//! its record but never loses it. A database lock therefore neither delays an E-stop's answer
//! nor loses its latch, and a controller that restarts meanwhile is told the latch from here.
//!
//! A reset is the one way out: it commits its own audit row (and the store's rows) first —
//! after every press before it has been recorded, so the log keeps their order — and only then
//! clears the latch here.
//!
//! *Invariant:* the latch in memory is never clear while the file or the store says latched:
//! at start it is the union of both, and a reset clears the store before the file.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use anyhow::Context;
use serde::{Deserialize, Serialize};
use sqlx::AnyPool;
use tokio::sync::Notify;

use crate::error::{AppError, Result};
use crate::store::{self, Change};

/// The latch shared by the server's parts (cheap to clone).
#[derive(Clone, Debug)]
pub struct EStopLatch {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    /// The latch file; `None` keeps it in memory only (a server without a file of its own:
    /// the tests' in-process servers).
    path: Option<PathBuf>,
    state: Mutex<State>,
    /// Held while the file is written, so writes land in the order their states were taken.
    writing: Mutex<()>,
    /// A press waits to be recorded, or was.
    changed: Notify,
}

/// What the file holds.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct State {
    /// The E-stop of every site.
    all: bool,
    /// Sites stopped on their own.
    sites: BTreeSet<String>,
    /// Presses whose audit row is not yet in the store, oldest first.
    pending: Vec<Press>,
    /// The next press's number (one per press, to remove the one recorded).
    next: u64,
}

/// An E-stop as it waits for its audit row.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Press {
    number: u64,
    /// Who pressed it (the audit row's actor).
    pub actor: String,
    /// The site stopped, or `None` for every site.
    pub site: Option<String>,
    /// When it was pressed (ms since the epoch).
    pub pressed_at: i64,
    /// What the controllers answered (the audit row's detail), once they did; a press whose
    /// server stopped before this was known is recorded without it.
    pub outcome: Option<serde_json::Value>,
}

impl EStopLatch {
    /// The latch kept in `<stem>.estop-latch`, as the file left it (none yet: clear), joined
    /// with the store's latch rows (a database of a release before the file, or one restored).
    pub async fn open(stem: &Path, pool: &AnyPool) -> anyhow::Result<Self> {
        let path = latch_path(stem);
        let mut state = match std::fs::read(&path) {
            Ok(bytes) => match serde_json::from_slice::<State>(&bytes) {
                Ok(state) => state,
                // Fail-safe: a latch that cannot be read latches every site (the file is
                // kept aside for whoever looks into it).
                Err(e) => {
                    let mut aside = path.as_os_str().to_owned();
                    aside.push(".unreadable");
                    std::fs::rename(&path, &aside)
                        .with_context(|| format!("moving {} aside", path.display()))?;
                    tracing::error!(
                        "the E-stop latch {} cannot be read ({e}): every site starts latched; the file is kept as {}",
                        path.display(),
                        PathBuf::from(&aside).display()
                    );
                    State {
                        all: true,
                        ..State::default()
                    }
                }
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => State::default(),
            Err(e) => {
                return Err(e)
                    .with_context(|| format!("reading the E-stop latch {}", path.display()));
            }
        };
        let (all, sites) = store::latch::stored(pool).await?;
        state.all |= all;
        state.sites.extend(sites);
        let latch = Self::with(Some(path), state);
        latch.write().await.context("writing the E-stop latch")?;
        Ok(latch)
    }

    /// A latch in memory only, clear.
    pub fn in_memory() -> Self {
        Self::with(None, State::default())
    }

    fn with(path: Option<PathBuf>, state: State) -> Self {
        Self {
            inner: Arc::new(Inner {
                path,
                state: Mutex::new(state),
                writing: Mutex::new(()),
                changed: Notify::new(),
            }),
        }
    }

    fn state(&self) -> MutexGuard<'_, State> {
        self.inner.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether `site` is latched: by its own E-stop or by that of every site.
    pub fn latched(&self, site: &str) -> bool {
        let s = self.state();
        s.all || s.sites.contains(site)
    }

    /// Whether the E-stop of every site is latched.
    pub fn all_latched(&self) -> bool {
        self.state().all
    }

    /// Presses not yet in the audit log.
    pub fn pending(&self) -> usize {
        self.state().pending.len()
    }

    /// Latches `site` (every site for `None`) in memory at once, then in the file; the
    /// press's number, for [`EStopLatch::answered`]. An error only says the file could not
    /// be written: the latch holds in memory and the press still waits to be recorded.
    pub async fn press(&self, actor: &str, site: Option<&str>) -> (u64, std::io::Result<()>) {
        let number = {
            let mut s = self.state();
            match site {
                Some(name) => {
                    s.sites.insert(name.to_string());
                }
                None => s.all = true,
            }
            let number = s.next;
            s.next += 1;
            s.pending.push(Press {
                number,
                actor: actor.to_string(),
                site: site.map(str::to_string),
                pressed_at: store::db::now_ms(),
                outcome: None,
            });
            number
        };
        (number, self.write().await)
    }

    /// Adds what the controllers answered to press `number`'s record, and hands it to the
    /// recorder; the file takes it in the background (the answer to the press need not wait
    /// for a second write: the latch is in the file already).
    pub fn answered(&self, number: u64, outcome: serde_json::Value) {
        if let Some(p) = self.state().pending.iter_mut().find(|p| p.number == number) {
            p.outcome = Some(outcome);
        }
        self.inner.changed.notify_one();
        let latch = self.clone();
        tokio::spawn(async move {
            if let Err(e) = latch.write().await {
                tracing::error!("the E-stop latch file could not be written: {e}");
            }
        });
    }

    /// Clears the latch of `site` (of every site, and each site's own, for `None`) once the
    /// store has recorded the reset: memory, then the file.
    pub async fn clear(&self, site: Option<&str>) -> std::io::Result<()> {
        {
            let mut s = self.state();
            match site {
                Some(name) => {
                    s.sites.remove(name);
                }
                None => {
                    s.all = false;
                    s.sites.clear();
                }
            }
        }
        self.write().await
    }

    /// Waits until every press so far is in the audit log, at most `limit`.
    pub async fn recorded(&self, limit: Duration) -> Result<()> {
        let deadline = tokio::time::Instant::now() + limit;
        loop {
            let changed = self.inner.changed.notified();
            let waiting = self.pending();
            if waiting == 0 {
                return Ok(());
            }
            if tokio::time::timeout_at(deadline, changed).await.is_err() {
                return Err(AppError::Unavailable(format!(
                    "{waiting} E-stop press(es) still wait for the store to record them (it is busy); the latch stays set: reset again in a moment"
                )));
            }
        }
    }

    /// Writes the state as it is now to the file (a new file, fsynced, renamed over the old
    /// one, the directory fsynced): a crash leaves the old file or the new, never half.
    async fn write(&self) -> std::io::Result<()> {
        let Some(path) = self.inner.path.clone() else {
            return Ok(());
        };
        let latch = self.clone();
        tokio::task::spawn_blocking(move || {
            let _turn = latch
                .inner
                .writing
                .lock()
                .unwrap_or_else(|p| p.into_inner());
            let text = serde_json::to_vec_pretty(&*latch.state()).map_err(std::io::Error::other)?;
            write_durably(&path, &text)
        })
        .await
        .map_err(std::io::Error::other)?
    }

    /// The oldest press not yet recorded.
    fn oldest(&self) -> Option<Press> {
        self.state().pending.first().cloned()
    }

    /// Drops press `number` from the file once the store has it.
    async fn forget(&self, number: u64) -> std::io::Result<()> {
        self.state().pending.retain(|p| p.number != number);
        self.inner.changed.notify_waiters();
        self.write().await
    }
}

/// The latch file of the server whose key files are named after `stem`.
pub fn latch_path(stem: &Path) -> PathBuf {
    crate::files::with_suffix(stem, ".estop-latch")
}

fn write_durably(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let tmp = crate::files::with_suffix(path, ".new");
    {
        let mut f = crate::files::replace_private(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::File::open(dir)?.sync_all()
}

/// How long a press waits for the controllers' answer before it is recorded without it (the
/// answer comes within `ESTOP_CONFIRMATION`; this only guards against a press whose answer
/// never came).
const ANSWER_WAIT_MS: i64 = 5_000;

/// Records every press in the audit log (and the store's latch rows) as the store allows,
/// oldest first, retrying a busy or failing store until it takes them; runs for the server's
/// life.
pub async fn record_pending(latch: EStopLatch, pool: AnyPool) {
    let mut backoff = Duration::from_millis(50);
    loop {
        let changed = latch.inner.changed.notified();
        let Some(press) = latch.oldest() else {
            changed.await;
            continue;
        };
        let waited = store::db::now_ms() - press.pressed_at;
        if press.outcome.is_none() && waited < ANSWER_WAIT_MS {
            // The controllers' answer is on its way.
            let rest = Duration::from_millis((ANSWER_WAIT_MS - waited).max(1) as u64);
            let _ = tokio::time::timeout(rest, changed).await;
            continue;
        }
        match record(&pool, &press).await {
            Ok(()) => {
                backoff = Duration::from_millis(50);
                if let Err(e) = latch.forget(press.number).await {
                    tracing::error!("the E-stop latch file could not be written: {e}");
                }
            }
            Err(e) => {
                tracing::warn!(
                    actor = press.actor,
                    "an E-stop is not yet in the audit log (the store: {}); trying again",
                    e.describe()
                );
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(Duration::from_secs(2));
            }
        }
    }
}

/// What the audit log names as an E-stop's target: one site, or every site's controller.
pub fn target(site: Option<&str>) -> String {
    match site {
        Some(name) => format!("site:{name}"),
        None => "controller".into(),
    }
}

/// One press's audit row and the store's latch rows, in one change.
async fn record(pool: &AnyPool, press: &Press) -> Result<()> {
    let mut change = Change::begin(pool, press.actor.clone()).await?;
    match &press.site {
        Some(name) => store::latch::set_site(change.db(), name, true).await?,
        None => store::latch::set_all(change.db(), true).await?,
    }
    let mut detail = press.outcome.clone().unwrap_or_else(|| {
        serde_json::json!({
            "delivered": null,
            "unknown": "the server stopped before the controllers' answer was recorded",
        })
    });
    if let Some(d) = detail.as_object_mut() {
        d.insert("pressed_at".into(), press.pressed_at.into());
    }
    change
        .commit("estop", Some(target(press.site.as_deref())), detail)
        .await
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A press is kept by the file across a restart (memory lost) until the store records
    /// it; the store's rows join the file's at start; a file that cannot be read latches
    /// every site.
    #[tokio::test]
    async fn the_file_keeps_a_press_until_recorded_and_an_unreadable_one_latches_all() {
        let dir = std::env::temp_dir().join(format!("bdft-latch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let stem = dir.join("lab.db");
        let pool = store::db::open(&stem).await.unwrap();
        let latch = EStopLatch::open(&stem, &pool).await.unwrap();
        assert!(!latch.latched("main"));
        let (number, kept) = latch.press("system:test", Some("lab-a")).await;
        kept.unwrap();
        assert!(latch.latched("lab-a") && !latch.latched("main"));
        latch.answered(number, serde_json::json!({ "delivered": true }));
        // (The answer reaches the file in the background; another latch on the same file is
        // for this test only.)
        while !std::fs::read_to_string(latch_path(&stem))
            .unwrap_or_default()
            .contains("delivered")
        {
            tokio::task::yield_now().await;
        }
        // A restart before the store recorded it: the file still has the latch and the press.
        let again = EStopLatch::open(&stem, &pool).await.unwrap();
        assert!(again.latched("lab-a") && !again.all_latched());
        assert_eq!(again.pending(), 1);
        record(&pool, &again.oldest().unwrap()).await.unwrap();
        again.forget(number).await.unwrap();
        assert_eq!(EStopLatch::open(&stem, &pool).await.unwrap().pending(), 0);
        // The store's rows count too: the file cleared, the store still latched.
        again.clear(Some("lab-a")).await.unwrap();
        assert!(
            EStopLatch::open(&stem, &pool)
                .await
                .unwrap()
                .latched("lab-a")
        );
        std::fs::write(latch_path(&stem), b"{ not json").unwrap();
        let unreadable = EStopLatch::open(&stem, &pool).await.unwrap();
        assert!(unreadable.all_latched() && unreadable.latched("main"));
        pool.close().await;
        let _ = std::fs::remove_dir_all(&dir);
    }
}
