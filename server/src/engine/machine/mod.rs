//! Room **machine**: everything about the real-time controller and the rig it drives — the link to
//! the controller process (`controller_link`: spawn, authenticate, supervise, the E-stop's own
//! path), the E-stop latch the server keeps outside its store (`estop_latch`), the sites one server
//! serves, each with its controller (`sites`), bench runs of designs with no operator (`bench`),
//! and the workbench's frequency and robustness analysis of a study's designs
//! (`workbench_analysis`).
//!
//! *May use:* `study`. The machine knows nothing of the protocol's rules: what the link
//! receives that only the protocol can file (a trial's result, the trials a lost controller
//! will not finish) goes to the [`controller_link::Filing`] the server hands it at start.
//!
//! Files: `controller_link/` (`mod.rs`: the link's handle and supervisor — 75 ms of silence or any
//! loss marks running trials incomplete and restarts the controller; `process.rs`: the child
//! controller, handed its key by environment; `connection.rs`: one authenticated connection,
//! whatever its role — connect, challenge–response, the frame codec; `reader.rs`: the control
//! connection's reader and watchdog on a thread of their own (silence counted only while it waits
//! on the socket, any byte counts as heard, the time a busy server takes to take a message not at
//! all); `session.rs`: the control connection — the E-stop latch re-sent to every connection, the
//! E-stop written ahead of everything, operator input as the newest value per trial, heartbeat,
//! record chunks, results (filed in order on a task of their own, so a busy store never holds the
//! link's reading); `estop_path.rs`: the E-stop's own connection, kept beside it; every E-stop goes
//! on both and the first confirmation answers). The `Filing` is `procedure::filing::LinkFiling`,
//! scoped to the link's site.
//!
//! `estop_latch`: the E-stop latch the server holds — in memory and in its own fsynced file beside
//! the audit key, never behind the store's lock; a press waits in the file until its audit row is
//! committed (`record_pending` retries a busy store), a reset commits first and clears it after.
//! *Invariant:* the latch in memory is never clear while the file or the store says latched.
//!
//! `sites`: the sites one server serves (`serve --site`), each a `ControllerLink` named by its
//! site, all telling one event channel; a station belongs to a site, a trial runs on its subject's
//! stations' site and records it (`procedure::trials` picks the link), an E-stop stops one site or
//! all.
//!
//! `bench/` (bench runs: designs or versions against a reference with no operator, one run at a
//! time; simulated in-process with `runtime::local::run`, or on a real-rig study through the link —
//! `ControllerLink::run_bench_trial`, ids from 2^50 so a result is never filed as a study's trial
//! —; `request.rs` what a run asks for and its checks, `view.rs` the results read back with the
//! reductions against each design's uncompensated `twin`). `workbench_analysis` (a study's designs
//! on its plant and body: the frequency report, cached per parameters, and robustness maps with
//! bounded grid and draws; served read-only by `http/workbench.rs`).

pub mod bench;
pub mod controller_link;
pub mod estop_latch;
pub mod sites;
pub mod workbench_analysis;
