//! The power planner's simulated studies with the study's own synthetic population: every
//! simulated subject is drawn from the population, scheduled and given targets as enrolment
//! would (order, positions, target seeds), and runs full 1 kHz trials — one per compensator
//! at the planned seat — from the same `StartTrial` as a pilot, without records, batched
//! several subjects to a run (`bdft_controller::batch`: the pilot's trial, tick for tick,
//! with its own vectorized noise streams). A subject whose trial the cab-vibration interlock stopped lacks that value and
//! is left out of its study's table, as the statistics leave out a subject with a missing
//! test.

use std::sync::atomic::{AtomicUsize, Ordering};

use bdft_controller::batch::LANES;
use bdft_controller::rng::Rng;
use bdft_protocol::params::{CompensatorSpec, Seat};
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::study::StudyParams;

use super::job::Progress;
use crate::engine::procedure::orchestrator::{Operator, TestRun, start};
use crate::engine::study::schedule::{schedule, target};
use crate::engine::study::synthetic;
use crate::error::{AppError, Result};

/// Loop sample period of the simulated trials.
const DT: f64 = 1e-3;

/// Loop ticks a plan of `studies` simulated studies of `max_n` subjects takes at `params`'
/// trial length: what bounds a request.
pub fn ticks(params: &StudyParams, studies: usize, max_n: usize) -> f64 {
    (studies * max_n * params.controllers.len()) as f64 * (params.trial_s / DT).round()
}

/// The seed of simulated study `study` of a plan seeded `seed` (its subjects' draws,
/// schedules and targets derive from it as enrolment derives them from a study's seed).
fn study_seed(seed: u64, study: usize) -> u64 {
    Rng::derive(seed, study as u64 + 1).next_u64()
}

/// The trial of simulated subject `index` of the study seeded `seed` with compensator
/// `spec` at `seat`: its drawn parameters, its place in its schedule and its target, as
/// enrolment and a pilot would give them.
fn trial(
    params: &StudyParams,
    seed: u64,
    index: u32,
    seat: Seat,
    spec: &CompensatorSpec,
) -> Result<StartTrial> {
    let draw = synthetic::draw(params, seed, index);
    let tests = schedule(params, seed, index);
    let t = tests
        .iter()
        .find(|t| !t.practice && t.seat == seat && t.compensator == spec.kind())
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
    let run = TestRun {
        trial_id: 0,
        compensator: spec.clone(),
        seat,
        slot: t.slot,
        k_bf: params.k_bf,
        levels_mm,
        duration_s: t.duration_s,
        target_seed: t.target_seed,
    };
    Ok(start(params, run, Operator::Synthetic(Some(draw))))
}

/// A worker's results: (subject, compensator, metric or None if the trial was stopped).
type Part = Result<Vec<(usize, usize, Option<f64>)>>;

/// `studies` simulated studies of `max_n` subjects each, subject by subject
/// (`rows[study·max_n + i]`, one metric per compensator in `params.controllers` order; None
/// for a subject with a trial the interlock stopped), on every core; `progress` counts
/// trials. The work is batches of `batch::LANES` subjects with one compensator, each batch
/// one vectorized run (`bdft_controller::batch`).
pub fn simulate(
    params: &StudyParams,
    seat: Seat,
    metric: usize,
    studies: usize,
    max_n: usize,
    seed: u64,
    progress: &Progress,
) -> Result<Vec<Option<Vec<f64>>>> {
    let total = studies * max_n;
    let k = params.controllers.len();
    progress.total.store(total * k, Ordering::Relaxed);
    let chunks = total.div_ceil(LANES);
    let next = AtomicUsize::new(0);
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let batch = |item: usize| -> Part {
        let (chunk, c) = (item / k, item % k);
        let subjects = chunk * LANES..(chunk * LANES + LANES).min(total);
        let starts = subjects
            .clone()
            .map(|j| {
                let (s, i) = (j / max_n, j % max_n);
                trial(
                    params,
                    study_seed(seed, s),
                    i as u32,
                    seat,
                    &params.controllers[c],
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let metrics = bdft_controller::batch::metrics(&starts, DT)
            .map_err(|e| AppError::BadRequest(format!("a simulated trial: {e}")))?;
        progress.add(starts.len());
        Ok(subjects
            .zip(metrics)
            .map(|(j, m)| {
                let value = m.map(|m| {
                    if metric == 0 {
                        m.mse_tracking_mm2
                    } else {
                        m.ms_cab_accel
                    }
                });
                (j, c, value)
            })
            .collect())
    };
    let parts: Vec<Part> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let item = next.fetch_add(1, Ordering::Relaxed);
                        if item >= chunks * k {
                            return Ok(mine);
                        }
                        mine.extend(batch(item)?);
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a planner worker panicked"))
            .collect()
    });
    let mut values = vec![vec![None; k]; total];
    for part in parts {
        for (j, c, value) in part? {
            values[j][c] = value;
        }
    }
    Ok(values
        .into_iter()
        .map(|row| row.into_iter().collect::<Option<Vec<f64>>>())
        .collect())
}
