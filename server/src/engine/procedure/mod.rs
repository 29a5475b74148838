//! Room **procedure**: the approved protocol run step by step with people (and with a dry
//! run's synthetic subjects, through the same code) — enrolment (`enrolment`), consent,
//! surveys and withdrawal (`subjects`), the stations and what they show (`stations`, their
//! live sockets in `station_sockets`), when a test may start, be redone or aborted
//! (`trials`), a trial row turned into the controller's start message (`orchestrator`), how
//! a test's end is filed (`filing`) and re-queued (`queue`), what an identification test
//! measured of its subject (`identification`), the stations' LSL streams (`lsl`), and the
//! display watch that makes a test invalid (`validity`).
//!
//! *May use:* `study`, `machine`.

pub mod enrolment;
pub mod filing;
pub mod identification;
pub mod lsl;
pub mod orchestrator;
pub mod queue;
pub mod station_sockets;
pub mod stations;
pub mod subjects;
pub mod trials;
pub mod validity;
