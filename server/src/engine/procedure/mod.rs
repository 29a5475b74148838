//! Room **procedure**: the approved protocol run step by step with people (and with a dry
//! run's synthetic subjects, through the same code) — enrolment (`enrolment`), consent,
//! surveys and withdrawal (`subjects`), the stations and what they show (`stations`, their
//! live sockets in `station_sockets`), when a test may start, be redone or aborted
//! (`trials`), a trial row turned into the controller's start message (`orchestrator`), how
//! a test's end is filed (`filing`) and re-queued (`queue`), what an identification test
//! measured of its subject (`identification`) and what their cancelling tests cancel with
//! (`cancellation`), the stations' LSL streams (`lsl`), and the display watch that makes a
//! test invalid (`validity`).
//!
//! *May use:* `study`, `machine`.
//!
//! Files: `enrolment` (lock, schedule, targets: one transaction), `trials` (start policy, abort,
//! redo rule, file accepted as incomplete, notes, E-stop), `orchestrator` (trial row → controller
//! `StartTrial`, shared by live trials, pilots and the planner; the start policy and the pilot add
//! the exposure allowance), `filing` (outcome → status — a trial found invalid stays invalid —;
//! result, record, re-queue and audit row in one transaction, with an `exposure.action_value` row
//! when the test took its subject's day to an action value; trials nobody will finish filed
//! incomplete: at a restart, a lost controller, and a `bdft-server pilot` process whose heartbeat
//! stopped — the server watches every second; `LinkFiling`, the link's filing, keeps a result or a
//! lost controller's trials it could not write — a full disk — and writes them again every second,
//! so no result is lost and no trial stays running while the server lives), `identification` (a
//! completed identification test's record estimated and its body fitted off the async threads
//! before the filing's transaction, stored in it with an `identification.file` audit row; in a
//! personalized study the study's LQR designs tuned to that body there too, put in place of the
//! designs of the subject's scheduled tests, `design.personalize`), `cancellation` (in the same
//! filing, each cancelling cell's model checked against the fitted body and its interval's ends,
//! stored on the cell's tests or the cell filed not run with why, `cancellation.plan`; the model a
//! test starts with, 409 without one), `queue` (nothing skipped: a
//! person's failed test — aborted, incomplete, invalid — comes back as a new attempt at the end of
//! its block, at most 3 attempts, unless the experimenter accepts it as incomplete; the station
//! holds, never "done", while a test is missing; what the subject is told about a stopped test),
//! `validity` (the display watch of a person's running test: the station's display reports against
//! the study's limits, silence as hidden; beyond a limit the trial is marked invalid and stopped on
//! the controller), `subjects` (consent, surveys, timing figures, withdrawal, progress and views),
//! `stations` (pairing codes, assignment, `site_driven_by` — the site a test's start or abort
//! drives —, the subject's `StationView` and the experimenter's `MonitorView`; the pairing codes,
//! capped and expiring, per client address limited — registrations a minute (429 with Retry-After)
//! and codes shown at once (its oldest withdrawn), so one address cannot take the server's 256 —,
//! and the station's wait for its pairing), `station_sockets` (one live socket per station — the
//! newest replaces the older, which is marked before the newer is handed out, so the two are never
//! both used —, its input counts, and what one station may cost: sockets opened (a few at once,
//! then one a second), one read budget shared by all its sockets — beyond it they are not read, so
//! TCP flow control pushes back on the sender —, the token-bucket input limit and the flood
//! cut-off; `http/live.rs` reads within them and runs each socket's display watch), `lsl` (`serve
//! --lsl`: each station's LSL marker stream — test start and end with trial, phase, seat and
//! blinded label, survey, redo, E-stop, interlock, one JSON string each — published here, because
//! only the server knows these events; and the `LslStation` message that has the controller publish
//! the station's signal stream. Both are (re)published when a subject is assigned to the station,
//! so a reader connects before the first tick, and checked before each test, whose trial the
//! controller then routes to that stream. The streams belong to the process as LSL's configuration
//! does: off unless `enable` ran at start, and then nothing here opens a socket; a stream that
//! cannot be published is logged, never a failed test).
//!
//! *Invariant:* what a station sends costs the server at most its read budget, whatever its
//! sockets, rate, sizes or frames (`tests/benches/isolation.rs`).

pub mod cancellation;
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
