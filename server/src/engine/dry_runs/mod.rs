//! Room **dry_runs**: whole studies run without people — the pilot (`pilot`: synthetic
//! subjects through the procedure's own code, faster than real time), the power planner
//! (`power`, with whole simulated studies of the study's population in `power_sim`), and the
//! one background job of a kind the dashboard watches (`job`), and a stored test run again
//! (`replay`: bit for bit, with the offline bound of cancellation).
//!
//! *May use:* `study`, `machine`, `procedure`, `results` (only `operations` is above it).
//!
//! Files: `replay` (a stored test run again through the controller's slot code and compared
//! bit for bit, with cancellation's offline bound), `pilot` (synthetic subjects through the same code, and the dashboard's one pilot job; a
//! pilot process registers in `pilot_runs`, beats every second and claims each trial it starts),
//! `power` (the power planner: whole studies simulated from a pilot's spread, or — `power_sim` —
//! from the study's synthetic population, whose subjects are drawn, scheduled and given targets as
//! enrolment does and run full trials without records on every core, eight subjects of one
//! compensator to a batch (`bdft_controller::batch`); candidates share their simulated studies
//! (common random numbers); a population plan runs as a background job), `job` (one background job
//! of a kind at a time with its progress and outcome: the dashboard's pilot, power plan and
//! calibration), `calibration/` (the population against data: `sim` — the study's simulated
//! subjects in any cells on every core, batched, what `power_sim` and the fit run on —, `findings`
//! — what a population predicts in the thesis's terms, `bdft-server findings` —, `surveys` — what
//! its subjects answer: full trials with records, perceived and answered as a pilot's —, `ratings`
//! — the fitted population's mean ratings per cell beside what the study's subjects gave, never
//! fitted —, `target` — a table or a study's own completed tests as target moments, bad rows
//! refused naming the row —, `fit` — simulated moments, Levenberg–Marquardt on log medians with
//! common random numbers, linearized bootstrap intervals, the delay's and k_h's carried onto their
//! profiles (the delay–gain ridge is curved), unidentified parameters named —, `table_error` — a
//! table's error on its moments for the bootstrap: its cells erring together, with the simulated
//! subjects' correlation between cells, as the same people give every cell —, `run` — `bdft-server
//! calibrate`'s and the dashboard's job, with cancel).
//!
//! *Invariants:* a comparison the exact test's floor rules out is reported impossible, never
//! simulated; a calibration's fit is stored only as a new `population_versions` row with its audit
//! row, which `store::studies` overlays on the study (and on its dry-run copy) so pilots and the
//! planner draw from it.

pub mod calibration;
pub mod job;
pub mod pilot;
pub mod power;
pub mod power_sim;
pub mod replay;
