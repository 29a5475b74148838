//! The protocol engine: the study's rules with no HTTP in them — schedules and targets,
//! enrolment, when a test may start, be redone or filed, what a station shows, accounts,
//! the controller link, pilots, statistics, exports and figures. Every change goes through
//! `store::Change`, so it is committed with its audit row.
//!
//! *Invariant:* nothing here imports axum; `http` calls in, never the reverse.

pub mod accounts;
pub mod bench;
pub mod calibration;
pub mod configs;
pub mod controller_link;
pub mod dry_run;
pub mod enrolment;
pub mod export;
pub mod filing;
pub mod inference;
pub mod inference_table;
pub mod job;
pub mod learning;
pub mod login_limiter;
pub mod orchestrator;
pub mod passwords;
pub mod pilot;
pub mod plots;
pub mod power;
pub mod power_sim;
pub mod queue;
pub mod results;
pub mod runnable;
pub mod schedule;
pub mod stability;
pub mod station_sockets;
pub mod stations;
pub mod stats;
pub mod studies;
pub mod subjects;
pub mod synthetic;
pub mod trials;
pub mod validity;
pub mod williams;
pub mod workbench_analysis;

use crate::error::{AppError, Result};

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
