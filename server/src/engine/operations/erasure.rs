//! Erasure on request: an admin erases a subject (the consent form promises withdrawal; data
//! protection law gives erasure). In one transaction with its audit row: the subject's
//! trials, records, surveys, notes and identifying fields are removed, the details of the
//! older audit rows about them are redacted, their stations released (`store::erasure`). The
//! audit log keeps that the erasure happened, when, by whom and why, and the subject's code —
//! nothing else. Exports and statistics are computed on read, so they leave the subject out
//! from then on.
//!
//! A backup made before the erasure still holds the data: each erasure lists them, from the
//! manifests of the backup directory (`serve --backup-dir`), so the lab can delete or lock
//! them away as its rules say. A backup holds the data when its copy does not hold the
//! erasure's audit row — its manifest counts fewer audit rows than the erasure row's id
//! (the log is append-only and its ids are given in commit order, so a copy taken before
//! the erasure committed has only rows with smaller ids): no clock is compared, so a backup
//! being copied while the erasure runs is judged right. A backup whose manifest cannot be
//! read is listed too (its content unknown).
//!
//! Refused: an unknown subject (404), a reason missing or over 500 characters (422), a
//! subject with a running test (409: stop it first), a subject erased already (409). Only an
//! admin may erase (`http::extract` refuses everyone else).

use std::path::Path;

use serde::Serialize;
use sqlx::AnyPool;

use super::manifest;
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
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct BackupHolding {
    /// The backup's file name in the backup directory (its manifest is
    /// `FILE.manifest.json` beside it).
    pub backup: String,
    /// When it was made (RFC 3339 UTC), as its manifest says; absent when the manifest
    /// cannot be read.
    pub created_at: Option<String>,
    /// What is wrong with its manifest, when it cannot be read (then it is listed to be
    /// safe).
    pub problem: Option<String>,
}

/// What an erasure did.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ErasureReport {
    #[serde(flatten)]
    pub erasure: Erasure,
    pub removed: Removed,
    /// The backup directory looked in (`serve --backup-dir`); absent when none is set, and then
    /// no backup could be checked.
    pub backup_dir: Option<String>,
    /// Why the backup directory could not be looked in, when it could not (the erasure is
    /// done all the same; `GET /api/erasures` lists the backups again).
    pub backups_unchecked: Option<String>,
    /// The old copies of the erased rows were removed at once: SQLite's write-ahead log
    /// cleared (else at the next checkpoint), or PostgreSQL's tables vacuumed.
    pub wal_cleared: bool,
}

/// What the erasure's audit row keeps: the subject's code and why, nothing else.
#[derive(Debug, Serialize)]
struct Erased<'a> {
    code: &'a str,
    reason: &'a str,
}

/// Erases subject `subject_id` for `reason`, as the admin `actor`; lists the backups in
/// `backup_dir` that still hold the data.
pub async fn erase(
    pool: &AnyPool,
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
            Erased {
                code: &subject.code,
                reason,
            },
        )
        .await?;
    let erasure_id = audited.audit_id;
    let removed = store::erasure::erase(audited.db(), subject_id, erasure_id).await?;
    let erased = store::subjects::get(audited.db(), subject_id).await?;
    audited.commit().await?;
    // The erasure is committed: what follows reports, and fails nothing.
    let purged = match store::erasure::purge_old_copies(pool).await {
        Ok(purged) => purged,
        Err(e) => {
            tracing::warn!(
                "erasure of subject {subject_id}: removing the old copies of the erased rows failed: {}",
                e.describe()
            );
            false
        }
    };
    if !purged {
        tracing::warn!(
            "erasure of subject {subject_id}: the write-ahead log was not cleared (a reader held it); the next checkpoint clears it"
        );
    }
    // Listed after the commit (a backup being copied now is judged by what it holds), and a
    // directory that cannot be read does not hide that the erasure is done.
    let (backups_holding_data, backups_unchecked) = match backup_dir.map(backups).transpose() {
        Ok(found) => (held_by(&found.unwrap_or_default(), erasure_id), None),
        Err(e) => {
            tracing::warn!(
                "erasure of subject {subject_id}: the backups holding its data could not be listed: {}",
                e.describe()
            );
            (Vec::new(), Some(e.describe()))
        }
    };
    Ok(ErasureReport {
        erasure: Erasure {
            subject_id,
            study_id: erased.study_id,
            code: erased.code,
            erased_at: rfc3339(erased.erased_at.unwrap_or_default()),
            by: actor.to_string(),
            reason: reason.to_string(),
            backups_holding_data,
        },
        removed,
        backup_dir: backup_dir.map(|d| d.display().to_string()),
        backups_unchecked,
        wal_cleared: purged,
    })
}

/// Every erasure so far, oldest first, each with the backups in `backup_dir` that still hold
/// its data.
pub async fn erasures(pool: &AnyPool, backup_dir: Option<&Path>) -> Result<Vec<Erasure>> {
    let backups = backup_dir.map(backups).transpose()?.unwrap_or_default();
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
            backups_holding_data: held_by(&backups, e.audit_id),
        })
        .collect())
}

/// A backup as erasure needs it: its file, and the audit rows its copy holds (with when it
/// was made), or what is wrong with its manifest.
#[derive(Debug, Clone, PartialEq)]
struct Backup {
    file: String,
    copied: std::result::Result<Copied, String>,
}

#[derive(Debug, Clone, PartialEq)]
struct Copied {
    audit_rows: i64,
    created_at: String,
}

/// The backups of `dir`, by their manifests.
fn backups(dir: &Path) -> Result<Vec<Backup>> {
    Ok(manifest::in_dir(dir)?
        .into_iter()
        .map(|(file, m)| Backup {
            file,
            copied: m.map_err(|e| e.describe()).and_then(|m| {
                let audit_rows = *m.row_counts.get("audit_log").ok_or_else(|| {
                    "the manifest counts no audit_log rows: what the copy holds is unknown"
                        .to_string()
                })?;
                Ok(Copied {
                    audit_rows,
                    created_at: m.created_at,
                })
            }),
        })
        .collect())
}

/// The backups that may hold the data of the erasure whose audit row is `erasure_id`: those
/// whose copy holds fewer audit rows than that id (taken before the erasure committed), and
/// those whose manifest cannot be read.
fn held_by(backups: &[Backup], erasure_id: i64) -> Vec<BackupHolding> {
    backups
        .iter()
        .filter(|b| {
            b.copied
                .as_ref()
                .map_or(true, |c| c.audit_rows < erasure_id)
        })
        .map(|b| BackupHolding {
            backup: b.file.clone(),
            created_at: b.copied.as_ref().ok().map(|c| c.created_at.clone()),
            problem: b.copied.as_ref().err().cloned(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backups_copied_before_the_erasure_or_unknown_hold_the_data() {
        let b = |file: &str, audit_rows: std::result::Result<i64, &str>| Backup {
            file: file.into(),
            copied: audit_rows
                .map(|audit_rows| Copied {
                    audit_rows,
                    created_at: format!("made with {audit_rows} rows"),
                })
                .map_err(str::to_string),
        };
        let backups = [
            b("a.db", Ok(99)),
            b("b.db", Ok(100)),
            b("c.db", Ok(101)),
            b("d.db", Err("not a backup manifest of this program")),
        ];
        // The erasure is audit row 100: a copy of 99 rows was taken before it committed, one
        // of 100 or more holds it (and not the data).
        assert_eq!(
            held_by(&backups, 100),
            [
                BackupHolding {
                    backup: "a.db".into(),
                    created_at: Some("made with 99 rows".into()),
                    problem: None,
                },
                BackupHolding {
                    backup: "d.db".into(),
                    created_at: None,
                    problem: Some("not a backup manifest of this program".into()),
                },
            ]
        );
    }
}
