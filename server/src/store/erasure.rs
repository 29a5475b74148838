//! Erasing a subject's data (`engine::operations::erasure` says when it is allowed): the
//! statements of one erasure, run after its audit row is written (`Change::audit_first`),
//! since the SQL triggers of migration 0021 let only a recorded erasure mark its subject
//! erased and redact the subject's older audit rows. Also the erasures recorded so far.
//!
//! Each redacted audit entry's salt is deleted and its redaction recorded
//! (`audit_chain::record_redaction`), so `audit verify` takes the marker there and nowhere
//! else, and the entry's stored hash can no longer be tried against guessed details.
//!
//! Deleted rows leave no copy in the file: the database runs with `secure_delete` (`db`), and
//! [`purge_old_copies`] empties the write-ahead log after the erasure.

use serde::Serialize;
use sqlx::{AnyConnection, AnyExecutor, AnyPool};

use crate::error::{AppError, Result};

/// What one erasure removed, counted.
#[derive(Debug, Clone, Copy, Default, Serialize, utoipa::ToSchema)]
pub struct Removed {
    /// Test attempts (the practice's included), with their results and timing figures.
    pub trials: u64,
    /// Full-rate records of those attempts.
    pub records: u64,
    /// What the subject's identification tests measured (feedthrough and fitted body).
    pub identifications: u64,
    /// Survey answers (ratings and comments).
    pub surveys: u64,
    /// The experimenters' notes on the subject and their tests.
    pub notes: u64,
    /// Older audit rows about the subject whose details were replaced by the redaction
    /// marker (the rows themselves stay: what was done, when and by whom).
    pub audit_details_redacted: u64,
    /// Stations the subject was assigned to, now free.
    pub stations_released: u64,
}

/// The subject's running test, if one is running.
pub async fn running_trial<'c>(db: impl AnyExecutor<'c>, subject_id: i64) -> Result<Option<i64>> {
    Ok(sqlx::query_scalar(
        "SELECT id FROM trials WHERE subject_id = $1 AND status = 'running' ORDER BY id LIMIT 1",
    )
    .bind(subject_id)
    .fetch_optional(db)
    .await?)
}

/// Erases subject `subject_id` whose erasure is the audit row `erasure_id` (written in this
/// transaction): the subject's row keeps its id, study, code, enrolment index, starting seat
/// and synthetic flag, and is marked erased at the audit row's time (its page token no longer
/// matches anything; `created_at` becomes that time too, so the enrolment time is gone);
/// the details of the older audit rows about it are redacted; its stations are released;
/// its notes, surveys, records and trials are deleted.
pub async fn erase(db: &mut AnyConnection, subject_id: i64, erasure_id: i64) -> Result<Removed> {
    let marked = sqlx::query(
        "UPDATE subjects SET erased_at = (SELECT at FROM audit_log WHERE id = $1), \
         created_at = (SELECT at FROM audit_log WHERE id = $1), token_hash = 'erased:' || id, \
         consent_version = NULL, consent_decision = NULL, consent_at = NULL, consent_sha256 = NULL, \
         withdrawn_at = NULL, withdraw_reason = NULL, drawn_json = NULL \
         WHERE id = $2 AND erased_at IS NULL",
    )
    .bind(erasure_id)
    .bind(subject_id)
    .execute(&mut *db)
    .await?;
    if marked.rows_affected() != 1 {
        return Err(AppError::Conflict(
            "the subject's data were erased already".into(),
        ));
    }
    // Before the trials go: a row is the subject's when it targets one of its trials, or
    // its detail names the subject (read in Rust from the rows that may: the stores' JSON
    // functions differ).
    let candidates: Vec<(i64, String, String)> = sqlx::query_as(
        "SELECT id, target, detail_json FROM audit_log \
         WHERE id < $1 AND action <> 'subject.erase' AND (target = 'subject:' || $2 \
           OR target IN (SELECT 'trial:' || id FROM trials WHERE subject_id = $2) \
           OR detail_json LIKE '%\"subject\\_id\"%' ESCAPE '\\')",
    )
    .bind(erasure_id)
    .bind(subject_id)
    .fetch_all(&mut *db)
    .await?;
    let trial_targets: Vec<String> =
        sqlx::query_scalar("SELECT 'trial:' || id FROM trials WHERE subject_id = $1")
            .bind(subject_id)
            .fetch_all(&mut *db)
            .await?;
    let subject_target = format!("subject:{subject_id}");
    let mut redacted = 0;
    for (id, target, detail) in candidates {
        let about = target == subject_target
            || trial_targets.contains(&target)
            || super::audit::detail_field(&detail, "subject_id").and_then(|v| v.as_i64())
                == Some(subject_id);
        if about {
            // The one detail migration 0021's trigger lets an erasure write.
            redacted += sqlx::query(
                "UPDATE audit_log SET detail_json = '{\"erasure\":' || $1 || ',\"redacted\":\"subject.erase\"}' WHERE id = $2",
            )
            .bind(erasure_id)
            .bind(id)
            .execute(&mut *db)
            .await?
            .rows_affected();
            // The redaction recorded under the audit key, and the entry's salt deleted: its
            // stored hash can no longer be tried against guessed details.
            super::audit_chain::record_redaction(db, id, erasure_id).await?;
        }
    }
    // Children before the trials they name (foreign keys), in this order.
    let mut counts = [0u64; 7];
    for (n, sql) in [
        "UPDATE stations SET subject_id = NULL WHERE subject_id = $1",
        "DELETE FROM notes WHERE subject_id = $1",
        "DELETE FROM identifications WHERE subject_id = $1",
        "DELETE FROM surveys WHERE trial_id IN (SELECT id FROM trials WHERE subject_id = $1)",
        "DELETE FROM trial_records WHERE trial_id IN (SELECT id FROM trials WHERE subject_id = $1)",
        "DELETE FROM pilot_trials WHERE trial_id IN (SELECT id FROM trials WHERE subject_id = $1)",
        "DELETE FROM trials WHERE subject_id = $1",
    ]
    .into_iter()
    .enumerate()
    {
        counts[n] = sqlx::query(sql)
            .bind(subject_id)
            .execute(&mut *db)
            .await?
            .rows_affected();
    }
    let [
        stations_released,
        notes,
        identifications,
        surveys,
        records,
        _,
        trials,
    ] = counts;
    Ok(Removed {
        trials,
        identifications,
        records,
        surveys,
        notes,
        audit_details_redacted: redacted,
        stations_released,
    })
}

/// Removes the old copies of what an erasure changed. SQLite: copies the write-ahead log
/// into the database file and truncates it, so that the changed pages no longer exist in
/// their old form anywhere in the files; waits for readers (the busy timeout) and returns
/// false when one kept it from finishing (a later checkpoint clears it). PostgreSQL: vacuums
/// the tables an erasure touches, which removes their dead row versions (PostgreSQL's own
/// write-ahead log and its archives keep them until they are recycled: README, "Running a
/// lab").
pub async fn purge_old_copies(pool: &AnyPool) -> Result<bool> {
    match super::db::Dialect::of_pool(pool) {
        super::db::Dialect::Sqlite => {
            let (busy, _, _): (i64, i64, i64) = sqlx::query_as("PRAGMA wal_checkpoint(TRUNCATE)")
                .fetch_one(pool)
                .await?;
            Ok(busy == 0)
        }
        super::db::Dialect::Postgres => {
            sqlx::query(
                "VACUUM subjects, audit_log, audit_salts, stations, notes, identifications, surveys, trial_records, pilot_trials, trials",
            )
            .execute(pool)
            .await?;
            Ok(true)
        }
    }
}

/// One recorded erasure, as its audit row keeps it.
#[derive(Debug, Clone, Serialize, sqlx::FromRow)]
pub struct ErasureRow {
    /// The `subject.erase` audit row.
    pub audit_id: i64,
    /// When, in ms since the Unix epoch.
    pub at: i64,
    pub by: String,
    pub subject_id: i64,
    pub study_id: i64,
    pub code: String,
    pub reason: String,
}

/// Every erasure, oldest first.
pub async fn erasures<'c>(db: impl AnyExecutor<'c>) -> Result<Vec<ErasureRow>> {
    let mut rows: Vec<ErasureRow> = sqlx::query_as(
        "SELECT a.id AS audit_id, a.at, a.actor AS by, s.id AS subject_id, s.study_id, s.code, \
         a.detail_json AS reason \
         FROM audit_log a JOIN subjects s ON a.target = 'subject:' || s.id \
         WHERE a.action = 'subject.erase' ORDER BY a.id",
    )
    .fetch_all(db)
    .await?;
    // The query gives the row's detail; its reason is read here.
    for row in &mut rows {
        row.reason = super::audit::reason_of(&row.reason);
    }
    Ok(rows)
}
