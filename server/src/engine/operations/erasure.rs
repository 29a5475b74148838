//! Erasure on request: an admin erases a subject (the consent form promises withdrawal; data
//! protection law gives erasure). In one transaction with its audit row: the subject's
//! trials, records, surveys, notes and identifying fields are removed, the details of the
//! older audit rows about them are redacted, their stations released (`store::erasure`). The
//! audit log keeps that the erasure happened, when, by whom and why, and the subject's code —
//! nothing else. Exports and statistics are computed on read, so they leave the subject out
//! from then on.
//!
//! A backup made before the erasure still holds the data: each erasure lists them, from the
//! manifests in the backup directory (`FILE.manifest.json` beside each backup `FILE`, with
//! its `created_at`), so the lab can delete or lock them away as its rules say.
//!
//! Refused: an unknown subject (404), a reason missing or over 500 characters (422), a
//! subject with a running test (409: stop it first), a subject erased already (409). Only an
//! admin may erase (`http::extract` refuses everyone else).

use std::path::Path;

use serde::Serialize;
use serde_json::json;
use sqlx::SqlitePool;

use crate::error::{AppError, Result};
use crate::store::db::rfc3339;
use crate::store::erasure::Removed;
use crate::store::{self, Change};

/// The audit action of an erasure (its target: `subject:ID`).
pub const ERASE_ACTION: &str = "subject.erase";

/// One erasure: what its audit row keeps, and the backups older than it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Erasure {
    pub subject_id: i64,
    pub study_id: i64,
    /// The subject's code, which the audit log keeps.
    pub code: String,
    /// RFC 3339 UTC.
    pub erased_at: String,
    /// The admin who erased.
    pub by: String,
    pub reason: String,
    /// Backups made before the erasure (or of unknown age): they still hold the data.
    pub backups_holding_data: Vec<BackupHolding>,
}

/// A backup that may still hold an erased subject's data.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct BackupHolding {
    /// The backup's file name in the backup directory (its manifest's name without
    /// `.manifest.json`).
    pub backup: String,
    /// The manifest's file name.
    pub manifest: String,
    /// RFC 3339 UTC; absent when the manifest does not say (then listed to be safe).
    pub created_at: Option<String>,
    /// Why its age is unknown, when it is.
    pub problem: Option<String>,
}

/// What an erasure did.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ErasureReport {
    #[serde(flatten)]
    pub erasure: Erasure,
    pub removed: Removed,
    /// The backup directory looked in (`--backup-dir`); absent when none is set, and then
    /// no backup could be checked.
    pub backup_dir: Option<String>,
    /// The write-ahead log was cleared at once (else at the next checkpoint).
    pub wal_cleared: bool,
}

/// Erases subject `subject_id` for `reason`, as the admin `actor`; lists the backups in
/// `backup_dir` that still hold the data.
pub async fn erase(
    pool: &SqlitePool,
    actor: &str,
    subject_id: i64,
    reason: &str,
    backup_dir: Option<&Path>,
) -> Result<ErasureReport> {
    crate::engine::check_reason(reason)?;
    let mut change = Change::begin(pool, actor).await?;
    let subject = store::subjects::get(change.db(), subject_id).await?;
    if let Some(at) = subject.erased_at {
        return Err(AppError::Conflict(format!(
            "{}'s data were erased already, at {}",
            subject.code,
            rfc3339(at)
        )));
    }
    // Checked inside the write transaction: no test can start between the check and the
    // erasure.
    if let Some(trial) = store::erasure::running_trial(change.db(), subject_id).await? {
        return Err(AppError::Conflict(format!(
            "{} has a running test (trial {trial}); stop it (Abort) or let it end, then erase",
            subject.code
        )));
    }
    let mut audited = change
        .audit_first(
            ERASE_ACTION,
            Some(format!("subject:{subject_id}")),
            json!({ "code": subject.code, "reason": reason }),
        )
        .await?;
    let erasure_id = audited.audit_id;
    let removed = store::erasure::erase(audited.db(), subject_id, erasure_id).await?;
    let erased = store::subjects::get(audited.db(), subject_id).await?;
    audited.commit().await?;
    let wal_cleared = store::erasure::clear_wal(pool).await?;
    if !wal_cleared {
        tracing::warn!(
            "erasure of subject {subject_id}: a reader kept the write-ahead log from being cleared; the next checkpoint clears it"
        );
    }
    let erased_at = erased.erased_at.unwrap_or_default();
    Ok(ErasureReport {
        erasure: Erasure {
            subject_id,
            study_id: erased.study_id,
            code: erased.code,
            erased_at: rfc3339(erased_at),
            by: actor.to_string(),
            reason: reason.to_string(),
            backups_holding_data: match backup_dir {
                Some(dir) => held_at(&backups(dir).await?, erased_at),
                None => Vec::new(),
            },
        },
        removed,
        backup_dir: backup_dir.map(|d| d.display().to_string()),
        wal_cleared,
    })
}

/// Every erasure so far, oldest first, each with the backups in `backup_dir` older than it.
pub async fn erasures(pool: &SqlitePool, backup_dir: Option<&Path>) -> Result<Vec<Erasure>> {
    let backups = match backup_dir {
        Some(dir) => backups(dir).await?,
        None => Vec::new(),
    };
    Ok(store::erasure::erasures(pool)
        .await?
        .into_iter()
        .map(|e| Erasure {
            subject_id: e.subject_id,
            study_id: e.study_id,
            code: e.code,
            erased_at: rfc3339(e.at),
            by: e.by,
            reason: e.reason,
            backups_holding_data: held_at(&backups, e.at),
        })
        .collect())
}

/// A backup's manifest as far as erasure needs it: its name and when the backup was made
/// (ms), or why that is unknown.
#[derive(Debug, Clone, PartialEq)]
struct Manifest {
    name: String,
    created_at: std::result::Result<i64, String>,
}

/// The suffix of a backup's manifest file.
pub const MANIFEST_SUFFIX: &str = ".manifest.json";

/// The manifests in `dir`, by name. A directory that does not exist holds none.
async fn backups(dir: &Path) -> Result<Vec<Manifest>> {
    let mut entries = match tokio::fs::read_dir(dir).await {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => {
            return Err(AppError::Unavailable(format!(
                "the backup directory {} cannot be read: {e}",
                dir.display()
            )));
        }
    };
    let mut out = Vec::new();
    while let Some(entry) = entries.next_entry().await.map_err(|e| {
        AppError::Unavailable(format!(
            "the backup directory {} cannot be read: {e}",
            dir.display()
        ))
    })? {
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.ends_with(MANIFEST_SUFFIX) {
            continue;
        }
        let created_at = match tokio::fs::read(entry.path()).await {
            Ok(bytes) => created_at(&bytes),
            Err(e) => Err(format!("unreadable: {e}")),
        };
        out.push(Manifest { name, created_at });
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(out)
}

/// When a manifest says its backup was made: `created_at` as Unix milliseconds or RFC 3339.
fn created_at(manifest: &[u8]) -> std::result::Result<i64, String> {
    let v: serde_json::Value =
        serde_json::from_slice(manifest).map_err(|e| format!("not JSON: {e}"))?;
    match &v["created_at"] {
        serde_json::Value::Number(n) => n
            .as_i64()
            .ok_or_else(|| format!("created_at {n} is not whole milliseconds")),
        serde_json::Value::String(s) => {
            time::OffsetDateTime::parse(s, &time::format_description::well_known::Rfc3339)
                .map(|t| (t.unix_timestamp_nanos() / 1_000_000) as i64)
                .map_err(|e| format!("created_at {s:?} is not RFC 3339: {e}"))
        }
        serde_json::Value::Null => Err("no created_at".into()),
        other => Err(format!(
            "created_at {other} is neither a time nor milliseconds"
        )),
    }
}

/// The backups that may hold data erased at `at` (ms): those made before it — or at the same
/// millisecond, which cannot be ordered — and those of unknown age.
fn held_at(backups: &[Manifest], at: i64) -> Vec<BackupHolding> {
    backups
        .iter()
        .filter(|b| b.created_at.as_ref().map_or(true, |&t| t <= at))
        .map(|b| BackupHolding {
            backup: b.name.trim_end_matches(MANIFEST_SUFFIX).to_string(),
            manifest: b.name.clone(),
            created_at: b.created_at.as_ref().ok().map(|&t| rfc3339(t)),
            problem: b.created_at.as_ref().err().cloned(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manifest_gives_its_time_in_either_form_or_says_what_is_wrong() {
        // 2001-09-09T01:46:40Z is Unix time 10⁹ s.
        assert_eq!(
            created_at(br#"{"created_at": "2001-09-09T01:46:40.250Z"}"#),
            Ok(1_000_000_000_250)
        );
        assert_eq!(
            created_at(br#"{"created_at": "2001-09-09T03:46:40+02:00"}"#),
            Ok(1_000_000_000_000)
        );
        assert_eq!(
            created_at(br#"{"created_at": 1000000000250, "sha256": "ab"}"#),
            Ok(1_000_000_000_250)
        );
        assert!(created_at(b"{").unwrap_err().starts_with("not JSON"));
        assert_eq!(created_at(b"{}"), Err("no created_at".into()));
        assert!(
            created_at(br#"{"created_at": "yesterday"}"#)
                .unwrap_err()
                .contains("not RFC 3339")
        );
        assert!(
            created_at(br#"{"created_at": 1.5}"#)
                .unwrap_err()
                .contains("whole milliseconds")
        );
    }

    #[test]
    fn backups_older_than_the_erasure_or_of_unknown_age_hold_the_data() {
        let m = |name: &str, at: std::result::Result<i64, String>| Manifest {
            name: name.into(),
            created_at: at,
        };
        let backups = [
            m("a.db.manifest.json", Ok(999)),
            m("b.db.manifest.json", Ok(1000)),
            m("c.db.manifest.json", Ok(1001)),
            m("d.db.manifest.json", Err("no created_at".into())),
        ];
        let held: Vec<(String, Option<String>)> = held_at(&backups, 1000)
            .into_iter()
            .map(|b| (b.backup, b.problem))
            .collect();
        assert_eq!(
            held,
            [
                ("a.db".to_string(), None),
                ("b.db".to_string(), None),
                ("d.db".to_string(), Some("no created_at".to_string())),
            ]
        );
    }
}
