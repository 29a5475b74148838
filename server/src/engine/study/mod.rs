//! Room **study**: what a study *is*, before and apart from anyone taking part — its parameters and
//! their edits (`studies`), the checks that it can run (`runnable`) and is stable on the machine
//! (`stability`, the gate), the schedule, protocol hash and targets (`schedule`, with the Williams
//! design in `williams`), the draw of its synthetic subjects (`synthetic`), its configuration
//! versions (`configs`) and whether it holds people or is a dry run (`dry_run`), and its daily
//! vibration exposure budget with how a subject's tests count against it (`exposure`). Everything
//! else derived here is a function of the parameters, the seed and an enrolment index.
//!
//! *May use:* the store and the controller's maths only — no other room. Every other room
//! builds on this one.
//!
//! Files: `studies` (create, edit with the version rule), `runnable` (at creation and edit: every
//! test's target can be drawn and every design — the practice's included — builds as the controller
//! builds it; the field and the reason otherwise), `stability` (the gate: every compensator
//! analysed at the study's K_BF on and off the machine, cached off the async threads; a
//! real-machine study with an unstable design cannot be locked, a simulated one only when
//! acknowledged), `schedule` (default parameters — the published study with the designs for people
//! —, the protocol hash, each subject's schedule — random orders or the Williams design's rows
//! (`williams`: the design, and which row each seat of a subject runs) — and each test's target
//! from the study seed), `synthetic` (a synthetic subject's draw at enrolment, its operator and
//! body per test, its survey answers through the person's path), `configs` (configuration versions:
//! validated and built as the controller builds them; a study's pick puts each version's design in
//! its parameters, so its hash and messages are those of a study naming the designs itself),
//! `dry_run` (a study holds people or is a dry run of synthetic subjects; a pilot runs in the
//! study's dry-run copy), `exposure` (the study's vibration budget against a subject's tests on the
//! machine: measured tests at their figures, unmeasured ones at the interlock's worst case; the
//! days as UTC dates; the budget over the 24 hours before a test — the allowance a test starts
//! with, or the 409 naming the figures —, and which action values a filed test reached; read by
//! `procedure` at start and filing, by `results` for the subject view and the subjects export).
//!
//! *Invariant:* a schedule is a function of (params, seed, enrol index) only; a design aid at its
//! default is left out of the hashed JSON, so an older study's hash, orders and targets stay as
//! they were.

pub mod configs;
pub mod dry_run;
pub mod exposure;
pub mod runnable;
pub mod schedule;
pub mod stability;
pub mod studies;
pub mod synthetic;
pub mod williams;
