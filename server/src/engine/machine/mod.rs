//! Room **machine**: everything about the real-time controller and the rig it drives — the
//! link to the controller process (`controller_link`: spawn, authenticate, supervise, the
//! E-stop's own path), the E-stop latch the server keeps outside its store (`estop_latch`), the sites one server serves, each with its controller (`sites`), bench runs of designs with no operator (`bench`), and the workbench's
//! frequency and robustness analysis of a study's designs (`workbench_analysis`).
//!
//! *May use:* `study`. The machine knows nothing of the protocol's rules: what the link
//! receives that only the protocol can file (a trial's result, the trials a lost controller
//! will not finish) goes to the [`controller_link::Filing`] the server hands it at start.

pub mod bench;
pub mod controller_link;
pub mod estop_latch;
pub mod sites;
pub mod workbench_analysis;
