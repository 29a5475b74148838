//! A serving process's heartbeat in its database, and the question a restore asks before it
//! replaces a database: is a server (or a pilot process) working on it right now?

use std::path::Path;
use std::time::Duration;

use sqlx::{AnyPool, Connection};

use crate::error::{AppError, Result};
use crate::store;

/// How often a server tells its database it is alive.
pub const BEAT: Duration = Duration::from_secs(1);

/// A process that has not beaten for this long is taken as stopped (killed, or its machine
/// lost power): five missed beats, so a busy moment never counts as a stop.
pub const SILENT_AFTER: Duration = Duration::from_secs(5);

/// Registers this serving process (`listen`: its address) and beats until the returned
/// handle is ended.
pub async fn announce(pool: &AnyPool, listen: &str) -> Result<Presence> {
    let run_id = store::server_runs::start(pool, std::process::id(), listen).await?;
    let beating = {
        let pool = pool.clone();
        crate::engine::beat_every(BEAT, "server", move || {
            let pool = pool.clone();
            async move { store::server_runs::beat(&pool, run_id).await }
        })
    };
    Ok(Presence {
        pool: pool.clone(),
        run_id,
        beating,
    })
}

/// A serving process's registration; `end` it when the server stops.
#[derive(Debug)]
pub struct Presence {
    pool: AnyPool,
    run_id: i64,
    beating: tokio::task::JoinHandle<()>,
}

impl Presence {
    pub async fn end(self) -> Result<()> {
        self.beating.abort();
        store::server_runs::end(&self.pool, self.run_id).await
    }
}

/// Refuses when a server or a pilot process has beaten on the database at `db` within
/// [`SILENT_AFTER`], naming it; a missing file has nobody on it.
pub async fn refuse_if_held(db: &Path) -> Result<()> {
    if !db.exists() {
        return Ok(());
    }
    let mut conn = store::db::open_read_only(db).await.map_err(|e| {
        AppError::BadRequest(format!(
            "{}: cannot be opened to see whether a server is running on it: {e:#}",
            db.display()
        ))
    })?;
    let now = store::db::now_ms();
    let since = now - SILENT_AFTER.as_millis() as i64;
    let holders = store::server_runs::holders(&mut conn, since).await?;
    // Closed now: a restore folds this database's log next, which needs it alone.
    conn.close().await?;
    let Some(h) = holders.first() else {
        return Ok(());
    };
    let listen = h
        .listen
        .as_deref()
        .map(|l| format!(", serving http://{l}"))
        .unwrap_or_default();
    Err(AppError::Conflict(format!(
        "{} is in use: {} (pid {}{listen}, started {}) beat on it {:.1} s ago. Stop it first: a restore replaces the database under a running server. A process killed without stopping counts as stopped {} s after its last beat",
        db.display(),
        h.what,
        h.pid,
        store::db::rfc3339(h.started_at),
        (now - h.beat_at).max(0) as f64 / 1000.0,
        SILENT_AFTER.as_secs()
    )))
}
