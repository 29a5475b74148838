//! The `bdft-server pilot` processes working on the database (`pilot_runs`), their
//! heartbeats, and the trials each started (`pilot_trials`): how a killed pilot's trials
//! are found.

use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use super::process_runs;
use crate::error::Result;

/// Registers a pilot process; returns the run's id.
pub async fn start(db: &mut AnyConnection, pid: u32) -> Result<i64> {
    let now = now_ms();
    let (id,): (i64,) = sqlx::query_as(
        "INSERT INTO pilot_runs (pid, started_at, beat_at) VALUES ($1, $2, $3) RETURNING id",
    )
    .bind(i64::from(pid))
    .bind(now)
    .bind(now)
    .fetch_one(db)
    .await?;
    Ok(id)
}

/// The run is alive. Not audited: a heartbeat changes no state of the study.
pub async fn beat<'c>(db: impl AnyExecutor<'c>, run_id: i64) -> Result<()> {
    process_runs::beat(db, "pilot_runs", run_id).await
}

/// `trial_id` is run by the pilot `run_id` (in the transaction that marks it running).
pub async fn claim(db: &mut AnyConnection, run_id: i64, trial_id: i64) -> Result<()> {
    sqlx::query("INSERT INTO pilot_trials (trial_id, run_id) VALUES ($1, $2)")
        .bind(trial_id)
        .bind(run_id)
        .execute(db)
        .await?;
    Ok(())
}

/// Runs that have not ended and last beat before `before` (ms): (id, pid).
pub async fn silent_since<'c>(db: impl AnyExecutor<'c>, before: i64) -> Result<Vec<(i64, i64)>> {
    Ok(sqlx::query_as(
        "SELECT id, pid FROM pilot_runs WHERE ended_at IS NULL AND beat_at < $1 ORDER BY id",
    )
    .bind(before)
    .fetch_all(db)
    .await?)
}

/// Ends a run: the trials it left running are filed incomplete with `reason`; returns
/// their ids.
pub async fn end(db: &mut AnyConnection, run_id: i64, reason: &str) -> Result<Vec<i64>> {
    let now = now_ms();
    let ids: Vec<(i64,)> = sqlx::query_as(
        "UPDATE trials SET status = 'incomplete', status_reason = $1, finished_at = CASE WHEN COALESCE(started_at, 0) > $2 THEN COALESCE(started_at, 0) ELSE $2 END \
         WHERE status = 'running' AND id IN (SELECT trial_id FROM pilot_trials WHERE run_id = $3) RETURNING id",
    )
    .bind(reason)
    .bind(now)
    .bind(run_id)
    .fetch_all(&mut *db)
    .await?;
    process_runs::end(&mut *db, "pilot_runs", run_id, now).await?;
    Ok(ids.into_iter().map(|r| r.0).collect())
}
