//! Room **study**: what a study *is*, before and apart from anyone taking part — its
//! parameters and their edits (`studies`), the checks that it can run (`runnable`) and is
//! stable on the machine (`stability`, the gate), the schedule, protocol hash and targets
//! (`schedule`, with the Williams design in `williams`), the draw of its synthetic subjects
//! (`synthetic`), its configuration versions (`configs`) and whether it holds people or is a
//! dry run (`dry_run`), and its daily vibration exposure budget with how a subject's tests
//! count against it (`exposure`). Everything else derived here is a function of the parameters, the seed and
//! an enrolment index.
//!
//! *May use:* the store and the controller's maths only — no other room. Every other room
//! builds on this one.

pub mod configs;
pub mod dry_run;
pub mod exposure;
pub mod runnable;
pub mod schedule;
pub mod stability;
pub mod studies;
pub mod synthetic;
pub mod williams;
