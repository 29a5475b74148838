//! Room **dry_runs**: whole studies run without people — the pilot (`pilot`: synthetic
//! subjects through the procedure's own code, faster than real time), the power planner
//! (`power`, with whole simulated studies of the study's population in `power_sim`), and the
//! one background job of a kind the dashboard watches (`job`).
//!
//! *May use:* `study`, `machine`, `procedure`, `results` (only `operations` is above it).

pub mod calibration;
pub mod job;
pub mod pilot;
pub mod power;
pub mod power_sim;
