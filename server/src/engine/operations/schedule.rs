//! The backup directory of a serving server (`serve --backup-dir`): scheduled backups
//! (`--backup-every`), the dashboard's "back up now", the listing of what the directory
//! holds, and keeping only the newest `--backup-keep`. One backup at a time.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use sqlx::AnyPool;

use super::backup;
use super::manifest::{self, Manifest};
use crate::error::{AppError, Result};
use crate::store::db::{now_ms, rfc3339};

/// Who the audit log names for a scheduled backup.
pub const SCHEDULE: &str = "system:backup-schedule";

/// Shortest and longest period of scheduled backups.
const EVERY_MIN: Duration = Duration::from_secs(1);
const EVERY_MAX: Duration = Duration::from_secs(30 * 86_400);

/// A period as `--backup-every` takes it: a whole number and a unit, `s`, `m`, `h` or `d`
/// (`90s`, `30m`, `6h`, `1d`), from 1 s to 30 d.
pub fn parse_every(text: &str) -> std::result::Result<Duration, String> {
    let allowed = "a whole number and a unit s, m, h or d (90s, 30m, 6h, 1d), from 1s to 30d";
    let t = text.trim();
    let split = t.find(|c: char| !c.is_ascii_digit()).unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let seconds = match unit {
        "s" => 1,
        "m" => 60,
        "h" => 3_600,
        "d" => 86_400,
        _ => return Err(format!("{text:?}: write {allowed}")),
    };
    let every = number
        .parse::<u64>()
        .ok()
        .and_then(|n| n.checked_mul(seconds))
        .map(Duration::from_secs)
        .ok_or_else(|| format!("{text:?}: write {allowed}"))?;
    if !(EVERY_MIN..=EVERY_MAX).contains(&every) {
        return Err(format!("{text:?} is out of range: write {allowed}"));
    }
    Ok(every)
}

/// Where and how often a server backs up.
#[derive(Debug, Clone)]
pub struct Policy {
    pub dir: PathBuf,
    pub every: Duration,
    /// Backups the directory keeps; the oldest beyond are deleted after a new one passed.
    pub keep: usize,
}

/// The server's backups: its policy (none: backups are off) and the one backup at a time.
#[derive(Debug, Default)]
pub struct Backups {
    policy: Option<Policy>,
    busy: tokio::sync::Mutex<()>,
    next_at_ms: std::sync::atomic::AtomicI64,
}

/// What the dashboard shows.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct BackupsView {
    /// The backup directory; absent when backups are off (`serve` without `--backup-dir`).
    pub dir: Option<String>,
    pub every_s: Option<u64>,
    pub keep: Option<usize>,
    /// When the next scheduled backup is due (RFC 3339 UTC).
    pub next_at: Option<String>,
    /// A backup is being made now.
    pub running: bool,
    /// The backups in the directory, newest first.
    pub backups: Vec<Manifest>,
}

impl Backups {
    /// Backups in `policy.dir`, which is created if missing and must be writable.
    pub fn new(policy: Policy) -> anyhow::Result<Self> {
        let dir = &policy.dir;
        crate::files::create_private_dirs(dir).map_err(|e| {
            anyhow::anyhow!("--backup-dir {}: cannot create it: {e}", dir.display())
        })?;
        let probe = dir.join(".bdft-write-probe");
        std::fs::write(&probe, b"")
            .and_then(|()| std::fs::remove_file(&probe))
            .map_err(|e| {
                anyhow::anyhow!("--backup-dir {}: cannot write there: {e}", dir.display())
            })?;
        Ok(Self {
            policy: Some(policy),
            ..Self::default()
        })
    }

    fn policy(&self) -> Result<&Policy> {
        self.policy.as_ref().ok_or_else(|| {
            AppError::Conflict(
                "backups are off: start the server with --backup-dir DIR (or BDFT_BACKUP_DIR)"
                    .into(),
            )
        })
    }

    /// Backs up into the directory now, then keeps the newest `keep`.
    pub async fn now(&self, pool: &AnyPool, made_by: &str) -> Result<Manifest> {
        // On PostgreSQL first: there, --backup-dir is refused, so "start with it" misleads.
        backup::only_of_sqlite(pool)?;
        let policy = self.policy()?;
        let _one = self.busy.try_lock().map_err(|_| {
            AppError::Conflict("a backup is being made now; try again when it has ended".into())
        })?;
        self.make(pool, policy, made_by).await
    }

    async fn make(&self, pool: &AnyPool, policy: &Policy, made_by: &str) -> Result<Manifest> {
        let name = format!("bdft-backup-{}.db", rfc3339(now_ms()).replace(':', "-"));
        let made = backup::make(pool, &policy.dir.join(name), made_by).await?;
        let older = listed(&policy.dir).unwrap_or_default();
        for old in older.iter().skip(policy.keep) {
            let file = policy.dir.join(&old.file);
            tracing::info!(file = %file.display(), "older than the newest {} backups: deleted", policy.keep);
            let _ = std::fs::remove_file(manifest::path_of(&file));
            let _ = std::fs::remove_file(&file);
        }
        Ok(made)
    }

    /// The backup directory; none when backups are off.
    pub fn dir(&self) -> Option<&Path> {
        self.policy.as_ref().map(|p| p.dir.as_path())
    }

    pub fn view(&self) -> Result<BackupsView> {
        let Some(p) = &self.policy else {
            return Ok(BackupsView {
                dir: None,
                every_s: None,
                keep: None,
                next_at: None,
                running: false,
                backups: Vec::new(),
            });
        };
        let next = self.next_at_ms.load(std::sync::atomic::Ordering::Relaxed);
        Ok(BackupsView {
            dir: Some(p.dir.display().to_string()),
            every_s: Some(p.every.as_secs()),
            keep: Some(p.keep),
            next_at: (next > 0).then(|| rfc3339(next)),
            running: self.busy.try_lock().is_err(),
            backups: listed(&p.dir)?,
        })
    }

    /// Makes a backup every period, for as long as the server runs: the first when the
    /// newest in the directory is a period old (at once if there is none).
    pub async fn run_schedule(self: Arc<Self>, pool: AnyPool) {
        let Some(policy) = self.policy.clone() else {
            return;
        };
        let every = policy.every.as_millis() as i64;
        loop {
            let newest = listed(&policy.dir)
                .ok()
                .and_then(|l| l.first().map(|m| m.created_at_ms));
            let due = newest.map_or(now_ms(), |t| t + every);
            self.next_at_ms
                .store(due, std::sync::atomic::Ordering::Relaxed);
            let wait = (due - now_ms()).max(0) as u64;
            tokio::time::sleep(Duration::from_millis(wait)).await;
            let _one = self.busy.lock().await;
            match self.make(&pool, &policy, SCHEDULE).await {
                Ok(m) => {
                    tracing::info!(file = %m.file, bytes = m.bytes, took_ms = m.took_ms, "scheduled backup made")
                }
                Err(e) => {
                    tracing::error!("scheduled backup failed: {}", e.describe());
                    // Try again after a period, not in a tight loop.
                    tokio::time::sleep(policy.every).await;
                }
            }
        }
    }
}

/// The backups in `dir` whose manifest can be read, newest first.
fn listed(dir: &Path) -> Result<Vec<Manifest>> {
    let mut found: Vec<Manifest> = manifest::in_dir(dir)?
        .into_iter()
        .filter_map(|(_, m)| m.ok())
        .collect();
    found.sort_by(|a, b| {
        b.created_at_ms
            .cmp(&a.created_at_ms)
            .then(b.file.cmp(&a.file))
    });
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn periods_take_a_whole_number_and_a_unit_within_range() {
        assert_eq!(parse_every("90s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_every("30m"), Ok(Duration::from_secs(1_800)));
        assert_eq!(parse_every("6h"), Ok(Duration::from_secs(21_600)));
        assert_eq!(parse_every("1d"), Ok(Duration::from_secs(86_400)));
        assert_eq!(parse_every("30d"), Ok(EVERY_MAX));
        for bad in [
            "",
            "d",
            "1",
            "1.5h",
            "-1h",
            "1 w",
            "31d",
            "0s",
            "99999999999999999999d",
        ] {
            let e = parse_every(bad).unwrap_err();
            assert!(e.contains("from 1s to 30d"), "{bad:?}: {e}");
        }
    }
}
