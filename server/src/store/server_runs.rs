//! The `bdft-server serve` processes working on the database (`server_runs`) and their
//! heartbeats: how a restore tells that a server holds the database it would replace.

use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use super::process_runs;
use crate::error::Result;

/// Registers a serving process; returns the run's id.
pub async fn start<'c>(db: impl AnyExecutor<'c>, pid: u32, listen: &str) -> Result<i64> {
    let now = now_ms();
    let (id,): (i64,) = sqlx::query_as(
        "INSERT INTO server_runs (pid, listen, started_at, beat_at) VALUES ($1, $2, $3, $4) RETURNING id",
    )
    .bind(i64::from(pid))
    .bind(listen)
    .bind(now)
    .bind(now)
    .fetch_one(db)
    .await?;
    Ok(id)
}

/// The server is alive. Not audited: a heartbeat changes no state of a study.
pub async fn beat<'c>(db: impl AnyExecutor<'c>, run_id: i64) -> Result<()> {
    process_runs::beat(db, "server_runs", run_id).await
}

/// The server stopped serving.
pub async fn end<'c>(db: impl AnyExecutor<'c>, run_id: i64) -> Result<()> {
    process_runs::end(db, "server_runs", run_id, now_ms()).await
}

/// Ends every run that has not ended, at its last beat: a restored copy's runs were
/// processes on the database the backup was taken from, not on this one.
pub async fn end_all<'c>(db: impl AnyExecutor<'c>) -> Result<u64> {
    Ok(
        sqlx::query("UPDATE server_runs SET ended_at = beat_at WHERE ended_at IS NULL")
            .execute(db)
            .await?
            .rows_affected(),
    )
}

/// A process that holds the database: what it is, its pid, where it serves (servers), when it
/// started and last beat (ms).
#[derive(Debug, Clone, PartialEq, Eq, sqlx::FromRow)]
pub struct Holder {
    pub what: String,
    pub pid: i64,
    pub listen: Option<String>,
    pub started_at: i64,
    pub beat_at: i64,
}

/// Servers and `bdft-server pilot` processes that have not ended and beat at `since` (ms) or
/// later, newest beat first. A database older than `server_runs` was never served by a
/// program that beats: none.
pub async fn holders(db: &mut AnyConnection, since: i64) -> Result<Vec<Holder>> {
    if super::db::tables_named(db, &["server_runs"])
        .await?
        .is_empty()
    {
        return Ok(Vec::new());
    }
    Ok(sqlx::query_as(
        "SELECT 'bdft-server serve' AS what, pid, listen, started_at, beat_at FROM server_runs WHERE ended_at IS NULL AND beat_at >= $1 \
         UNION ALL SELECT 'bdft-server pilot', pid, NULL, started_at, beat_at FROM pilot_runs WHERE ended_at IS NULL AND beat_at >= $1 \
         ORDER BY beat_at DESC",
    )
    .bind(since)
    .fetch_all(db)
    .await?)
}
