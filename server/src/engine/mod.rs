//! The protocol engine: the study's rules with no HTTP in them, in seven rooms. Each room is
//! a folder with a module doc saying what it holds and which rooms it may use; imports
//! between rooms run one way only (checked by the integration test `structure`, drawn in
//! ARCHITECTURE.md):
//!
//! ```text
//! operations → every other room                        (a lab's duties: erasure, the
//!                                                        ethics board's package)
//! dry_runs   → results, procedure, machine, study
//! results    → machine, study
//! procedure  → machine, study
//! machine    → study
//! study      → nothing                                 (every room builds on it)
//! accounts   → nothing                                 (stands alone)
//! ```
//!
//! Every change goes through `store::Change`, so it is committed with its audit row.
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
