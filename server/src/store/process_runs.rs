//! What `server_runs` and `pilot_runs` share: a row for each process working on the
//! database, which beats on it (`beat_at`) while it runs and is ended (`ended_at`) once.

use sqlx::AnyExecutor;

use super::db::now_ms;
use crate::error::Result;

/// The run `run_id` in `table` (`server_runs` or `pilot_runs`) is alive, unless it has
/// ended. Not audited: a heartbeat changes no state of a study.
pub(super) async fn beat<'c>(db: impl AnyExecutor<'c>, table: &str, run_id: i64) -> Result<()> {
    sqlx::query(&format!(
        "UPDATE {table} SET beat_at = $1 WHERE id = $2 AND ended_at IS NULL"
    ))
    .bind(now_ms())
    .bind(run_id)
    .execute(db)
    .await?;
    Ok(())
}

/// Ends the run `run_id` in `table` (`server_runs` or `pilot_runs`) at `at` (ms), unless
/// it has ended already.
pub(super) async fn end<'c>(
    db: impl AnyExecutor<'c>,
    table: &str,
    run_id: i64,
    at: i64,
) -> Result<()> {
    sqlx::query(&format!(
        "UPDATE {table} SET ended_at = $1 WHERE id = $2 AND ended_at IS NULL"
    ))
    .bind(at)
    .bind(run_id)
    .execute(db)
    .await?;
    Ok(())
}
