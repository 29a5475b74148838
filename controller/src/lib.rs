//! bdft-lab's control core: models of the backhoe rig and the operator's body, the five
//! compensators of the biodynamic-feedthrough study (plus cab-acceleration feedback for
//! comparison), their design routines, a stability analysis of each with the feedthrough
//! loop closed, and a deterministic offline simulation.
//!
//! Everything is pure: time is passed in (one `step` per tick at `dt`), randomness comes
//! from seeds. The real-time runtime runs exactly these `step` functions.
//!
//! Map: [`params`] (named parameters with the identified defaults) → [`model`] (plant, body)
//! and [`compensator`] (designs in [`linalg`], filters in [`filters`], [`shaper`]) →
//! [`closed_loop`] (one tick) → [`simulate`] and [`analysis`]; [`special`]: the special
//! functions (log-gamma, incomplete gamma and beta) the identification's intervals and the
//! server's statistics share.
//!
//! Files and folders (each folder's module doc lists its own):
//!
//! - `params` — named physical parameters (`PlantParams`, `BodyModel`, `LoopParams`, `Seat`) with
//!   the identified defaults, and `check`, the range validation every boundary uses. *Invariant:*
//!   no model matrix is typed in; all are built from these.
//! - `param_set` — all parameters in one JSON document (`defaults` / `--params`).
//! - `model/` — the plant, the simulated rig and the seat-to-hand body.
//! - `linalg/` — design routines written here (ZOH, eigenvalues, Riccati, Lyapunov, observer
//!   placement).
//! - `filters` — Tustin first-order and biquad sections (pre-warping optional).
//! - `shaper` — input shapers on the sample grid: ZV solved exactly (three impulses per mode when
//!   the half period is not a whole number of samples), the robust ZVD, EI (tolerance V) and
//!   two-hump EI (textbook sequences made exact for the damping, each impulse split between its
//!   neighbouring samples), at one frequency or per mode by convolution; the running ring-buffer
//!   shaper and its added delay (`duration`).
//! - `compensator/` — the compensators behind one interface (`CompensatorKind`, `CompensatorSpec`,
//!   `Compensator`).
//! - `compensator/adaptive/` — the adaptive designs (issue 41; a submodule of `compensator`,
//!   whose fixed designs it prepares, so the two do not import each other): the mode estimator
//!   (accelerometer and cylinder position → the first mode's frequency ratio and its
//!   confidence), the retune schedule with its crossfade over [1 − range, 1 + range_up], the
//!   designs prepared at build on a grid of ratios.
//!   *Invariant:* a design at ratio r is exactly `Compensator::build` of the spec `frozen_at(r)`.
//! - `state` — `LinearState`: every per-tick block exposes its state as a flat vector.
//! - `closed_loop` — `ClosedLoop::tick`: measure → body → feedthrough → (cancellation) →
//!   compensator → plant, the order the real-time loop uses.
//! - `conditions` — the machine conditions' workbench table: each design, made for the study's
//!   rig, on the rig under each condition (`params::MachineCondition`, the rules in the protocol
//!   crate): bench cab-acceleration reduction against its twin, and stability margin with the
//!   body; `twin`, the uncompensated design a reduction is measured against.
//! - `cancellation` — model-based cancellation of the feedthrough (issue 38): the fitted
//!   body's device-over-cab-acceleration as two biquads, a deliberately wrong model's gain
//!   and phase lag, and the guard that turns it off.
//! - `analysis/` — stability, design view, robustness, frequency, Nyquist and personal designs, all
//!   read off the code that runs; an adaptive design is analysed frozen at r = 1, and
//!   `adaptive_gate` judges it frozen at every r it can be retuned to.
//! - `signals` — swept sine, smoothed trapezoid, and the protocol's random-step target (seeded;
//!   mean exactly 0 and standard deviation exactly as asked, within range; matched targets also
//!   have the mean-squared step change `ms_step` = 2·std², by mixing two seeded draws on either
//!   side of it). *Invariant:* an unmatched target is bit-identical to what it was before matching
//!   existed (pinned fingerprints). An uploaded bench reference is a `SampledReference` (linear
//!   between samples, the last held).
//! - `identification/` — the identification test (`docs/identification.md`): `multisine` (the
//!   excitation: log-spaced distinct grid lines, amplitudes ∝ 1/f, seeded phases, one period
//!   precomputed; refused unless a period is a whole number of ticks), `estimate` (the feedthrough
//!   device/ẍ_c at the lines: Ȳ/Ū over the recorded periods, variance from their spread, 95 % F(2,
//!   2P − 2) disc), `fit` (the seated body k_h(1 − T·A)/ω² by Levenberg–Marquardt in
//!   log-parameters, Student-t intervals, unidentified parameters named); `identify` does both.
//!   *Invariant:* in an identification trial the hand never reaches r_c (`Drive::Excited`; proved
//!   on the real process by `tests/integration/controller_identification.rs`).
//! - `operator` — the synthetic operator (reaction delay, second-order neuromuscular lag, error
//!   correction that lowers its gain on a shaking cylinder, remnant that grows and a neuromuscular
//!   corner that falls with felt vibration, a grip that stiffens a seated body's arm), for pilots,
//!   the planner and end-to-end tests; in an identification test it holds still (`hold`: its
//!   remnant through its lag, the grip stiffening unless relaxed).
//! - `population` — the synthetic subject pool: a subject's draw from the study's
//!   `PopulationParams` (log-normal spreads, each from its own deviate in a fixed order, so one
//!   spread never moves another parameter), its operator at a test position after some time on task
//!   (learning, fatigue), its body (`docs/synthetic-subjects.md`). *Invariant:* a draw is a
//!   function of its seed only.
//! - `perception` — a synthetic subject's survey answers from what it perceived of a test's record.
//! - `simulate` — the offline run: signal → operator → `ClosedLoop` → metrics and record.
//! - `batch/` — the power planner's engine: `LANES` (8) trials ticked together.
//! - `exposure` — ISO 2631-1's W_d weighting as three prewarped Tustin biquads (within 0.03 dB of
//!   the analog weighting over 0.5–80 Hz at 1 kHz: the low-pass prewarped at 130 Hz makes up what
//!   the transition section loses to the transform) and `ExposureMeter`: a test's ∫a_w² dt and
//!   ∫a_w⁴ dt tick by tick (its a_w and VDV), and the exposure guard — the runner stops the trial
//!   (`exposure-budget`) once they exceed the allowance the server handed over
//!   (`docs/exposure.md`). *Invariant:* `add` never allocates, locks or logs.
//! - `interlock` — the cab-vibration interlock: RMS cab acceleration over a 1 s sliding window (a
//!   ring allocated when the trial is built) against the trial's limit; the runner updates it every
//!   tick and the trial ends as a `cab-vibration` fault when it trips.
//! - `runner` — `TrialRunner`: one trial tick by tick (target → operator or external input → loop →
//!   metrics); `Sample::record_row` is a tick's row of the record (`RECORD_CHANNELS` order) for the
//!   real-time slot and `simulate --out` alike. `simulate` and the real-time process both use it,
//!   so a trial in the process reproduces `simulate` bit for bit (an end-to-end test checks this).
//! - `runtime/` — the real-time process; `lsl/` — its Lab Streaming Layer streams.
//! - `rng` — xoshiro256++ written here so seeds reproduce forever; checked against the C reference.
//!   *Invariant:* each use of a seed draws from its own derived stream (`Rng::derive`), so adding
//!   draws in one place never changes another's values.
//! - `special` — the special functions; `logging` — `init`, the one log set-up of both programs;
//!   `error`; `fixtures` — the reference values of the tests; `alloc_check` — a counting allocator
//!   in the test binary.
//!
//! `unsafe` is denied in the workspace (`unsafe_code = "deny"`) and allowed in three places only:
//! `batch::trial::run_with` (calling the AVX-512 or AVX2 build after the CPU check), `runtime::os`
//! (the libc calls: the monotonic clock, SCHED_FIFO, mlockall, affinity) and `alloc_check` (the
//! test binary's counting allocator).

pub mod analysis;
pub mod batch;
pub mod cancellation;
pub mod closed_loop;
pub mod compensator;
pub mod conditions;
pub mod error;
pub mod exposure;
pub mod filters;
pub mod identification;
pub mod interlock;
pub mod linalg;
pub mod logging;
pub mod lsl;
pub mod model;
pub mod operator;
pub mod param_set;
pub mod params;
pub mod perception;
pub mod population;
pub mod rng;
pub mod runner;
pub mod runtime;
pub mod shaper;
pub mod signals;
pub mod simulate;
pub mod special;
pub mod state;

#[cfg(test)]
mod alloc_check;
#[cfg(test)]
mod fixtures;
#[cfg(test)]
mod tests;
