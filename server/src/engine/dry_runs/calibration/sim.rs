//! Simulated subjects of a study's population in every cell they are asked for: each subject
//! drawn, scheduled and given targets as enrolment would (order, positions, target seeds),
//! each cell's trial a full 1 kHz trial from the same `StartTrial` as a pilot, without
//! records, batched `batch::LANES` subjects of one cell to a run
//! (`bdft_controller::batch`). The power planner and the calibration both run on this.
//!
//! Common random numbers: a subject's draw takes its standard-normal deviates in a fixed
//! order and scales them by the population's medians and spreads, and a trial's noise comes
//! from its seeds; so the same subjects under another population are the same people with
//! other parameters, and a prediction moves smoothly with the population.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use bdft_controller::batch::LANES;
use bdft_protocol::params::{CompensatorSpec, Seat};
use bdft_protocol::records::TestPhase;
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::study::StudyParams;
use bdft_protocol::trial::Metrics;
use bdft_protocol::trial::TargetSpec;

use crate::engine::dry_runs::job::Progress;
use crate::engine::procedure::orchestrator::{Operator, TestRun, start};
use crate::engine::study::schedule::{schedule, target};
use crate::engine::study::synthetic;
use crate::error::{AppError, Result};

/// Loop sample period of the simulated trials.
pub const DT: f64 = 1e-3;

/// One simulated subject: enrolled `index`-th in a study seeded `seed`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SubjectRef {
    pub seed: u64,
    pub index: u32,
}

/// A cell of the design: one of the study's compensators (its index in
/// `params.compensators`) at one seat.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cell {
    pub compensator: usize,
    pub seat: Seat,
}

/// The trial of `subject` with compensator `spec` at `seat`: its drawn parameters, its place
/// in its schedule and its target, as enrolment and a pilot would give them; and the test's
/// target seed (what its survey's answers derive from).
pub(super) fn trial(
    params: &StudyParams,
    subject: SubjectRef,
    seat: Seat,
    spec: &CompensatorSpec,
) -> Result<(StartTrial, u64)> {
    let SubjectRef { seed, index } = subject;
    let draw = synthetic::draw(params, seed, index);
    let tests = schedule(params, seed, index);
    let t = tests
        .iter()
        .find(|t| t.phase == TestPhase::Test && t.seat == seat && t.compensator == spec.kind())
        .ok_or_else(|| {
            AppError::BadRequest(format!(
                "station: the study schedules no {} test at the {} seat",
                spec.kind(),
                seat.as_str()
            ))
        })?;
    let levels_mm = target(params, t)
        .map_err(|e| AppError::BadRequest(e.to_string()))?
        .levels_mm;
    let target = TargetSpec::Steps {
        interval_s: params.step_interval_s,
        levels_mm,
    };
    let run = TestRun {
        trial_id: 0,
        compensator: spec.clone(),
        seat,
        slot: t.slot,
        k_bf: params.k_bf,
        target,
        duration_s: t.duration_s,
        target_seed: t.target_seed,
        // Calibration fits the uncancelled cells the published study ran.
        cancellation: None,
        condition: params.condition_of(index),
    };
    Ok((
        start(params, run, Operator::Synthetic(Some(draw))),
        t.target_seed,
    ))
}

/// A worker's results: (subject, cell, metrics or None if the trial was stopped).
type Part = Result<Vec<(usize, usize, Option<Metrics>)>>;

/// Every `subjects`' trial in every one of `cells`, on every core: `out[subject][cell]`, None
/// where the cab-vibration interlock stopped the trial. `progress` counts trials; when
/// `cancel` is set the workers stop at their next batch and the run ends in a 409.
pub fn simulate(
    params: &StudyParams,
    subjects: &[SubjectRef],
    cells: &[Cell],
    progress: &Progress,
    cancel: &AtomicBool,
) -> Result<Vec<Vec<Option<Metrics>>>> {
    let total = subjects.len();
    let k = cells.len();
    progress.total.fetch_add(total * k, Ordering::Relaxed);
    let chunks = total.div_ceil(LANES);
    let batch = |item: usize| -> Part {
        let (chunk, c) = (item / k, item % k);
        let cell = cells[c];
        let spec = params.compensators.get(cell.compensator).ok_or_else(|| {
            AppError::BadRequest(format!(
                "controller: the study has {} controllers",
                params.compensators.len()
            ))
        })?;
        let range = chunk * LANES..(chunk * LANES + LANES).min(total);
        let starts = range
            .clone()
            .map(|j| trial(params, subjects[j], cell.seat, spec).map(|(start, _)| start))
            .collect::<Result<Vec<_>>>()?;
        let metrics = bdft_controller::batch::metrics(&starts, DT)
            .map_err(|e| AppError::BadRequest(format!("a simulated trial: {e}")))?;
        progress.add(starts.len());
        Ok(range.zip(metrics).map(|(j, m)| (j, c, m)).collect())
    };
    let parts = on_every_core(chunks * k, cancel, batch)?;
    let mut values = vec![vec![None; k]; total];
    for (j, c, m) in parts {
        values[j][c] = m;
    }
    Ok(values)
}

/// `one(item)` for every item below `items` on every core, each worker taking the next item
/// when it is done with one; every item's results, in no particular order. When `cancel` is
/// set the workers stop before their next item and the run ends in a 409.
pub(super) fn on_every_core<T: Send>(
    items: usize,
    cancel: &AtomicBool,
    one: impl Fn(usize) -> Result<Vec<T>> + Sync,
) -> Result<Vec<T>> {
    let next = AtomicUsize::new(0);
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let parts: Vec<Result<Vec<T>>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        if cancel.load(Ordering::Relaxed) {
                            return Err(AppError::Conflict("cancelled".into()));
                        }
                        let item = next.fetch_add(1, Ordering::Relaxed);
                        if item >= items {
                            return Ok(mine);
                        }
                        mine.extend(one(item)?);
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a simulation worker panicked"))
            .collect()
    });
    let mut all = Vec::new();
    for part in parts {
        all.extend(part?);
    }
    Ok(all)
}

/// Every cell of the study: each controller at each station, in `params` order.
pub fn all_cells(params: &StudyParams) -> Vec<Cell> {
    params
        .seats
        .iter()
        .flat_map(|&seat| {
            (0..params.compensators.len()).map(move |compensator| Cell { compensator, seat })
        })
        .collect()
}

/// The first `n` subjects a study seeded `seed` would enrol: a pilot's.
pub fn enrolled(seed: u64, n: u32) -> Vec<SubjectRef> {
    (0..n).map(|index| SubjectRef { seed, index }).collect()
}
