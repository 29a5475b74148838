//! The protocol engine: the study's rules with no HTTP in them, in seven rooms. Each room is a
//! folder with a module doc saying what it holds and which rooms it may use; imports between
//! rooms run one way only (checked by the integration test `structure`, drawn in ARCHITECTURE.md):
//!
//! ```text
//! dry_runs   → results, procedure, machine, study      (the top room)
//! operations → study                                   (the lab's data duties)
//! results    → machine, study
//! procedure  → machine, study
//! machine    → study
//! study      → nothing                                 (every room builds on it)
//! accounts   → nothing                                 (stands alone)
//! ```
//!
//! Every change goes through `store::Change`, so it is committed with its audit row. The
//! root holds what every room shares: the name and reason checks, `COMPUTE`, and
//! `beat_every`, the heartbeat of a process working on the database.
//!
//! *Invariant:* nothing here imports axum; `http` calls in, never the reverse.

pub mod accounts;
pub mod dry_runs;
pub mod machine;
pub mod operations;
pub mod procedure;
pub mod results;
pub mod study;

use crate::error::{AppError, Result};

/// The statistics, the planner and the workbench's analysis run one at a time, off the async
/// threads: each is seconds of CPU at most (the work is bounded per request), so a burst of
/// requests waits its turn instead of taking every core from the live sockets.
pub static COMPUTE: tokio::sync::Semaphore = tokio::sync::Semaphore::const_new(1);

/// Runs `beat` every `period` until the returned task is aborted: how a process tells the
/// database it is alive (a pilot process, a server), so others can tell when it stopped. A
/// failed beat is logged and the next one tries again.
pub fn beat_every<F, Fut>(
    period: std::time::Duration,
    what: &'static str,
    beat: F,
) -> tokio::task::JoinHandle<()>
where
    F: Fn() -> Fut + Send + 'static,
    Fut: std::future::Future<Output = Result<()>> + Send,
{
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(period);
        loop {
            tick.tick().await;
            if let Err(e) = beat().await {
                tracing::warn!("{what} heartbeat: {e}");
            }
        }
    })
}

/// A study's or a station's name: 1 to 200 characters, not only spaces.
pub fn check_name(name: &str) -> Result<()> {
    if name.trim().is_empty() || name.len() > 200 {
        return Err(AppError::BadRequest("name: 1 to 200 characters".into()));
    }
    Ok(())
}

/// A reason given for an irreversible action: 1 to 500 characters.
pub fn check_reason(reason: &str) -> Result<()> {
    if reason.trim().is_empty() || reason.chars().count() > 500 {
        return Err(AppError::BadRequest("reason: 1 to 500 characters".into()));
    }
    Ok(())
}
