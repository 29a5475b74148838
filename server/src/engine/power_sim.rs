//! The power planner's simulated studies with the study's own synthetic population: every
//! simulated subject is drawn from the population, scheduled and given targets as enrolment
//! would (order, positions, target seeds), and runs full 1 kHz trials — one per compensator
//! at the planned seat — through the same `StartTrial` and trial code as a pilot, without
//! records. A subject whose trial the cab-vibration interlock stopped lacks that value and
//! is left out of its study's table, as the statistics leave out a subject with a missing
//! test.

use std::sync::atomic::{AtomicUsize, Ordering};

use bdft_controller::rng::Rng;
use bdft_protocol::params::Seat;
use bdft_protocol::study::StudyParams;

use super::job::Progress;
use super::orchestrator::{Operator, TestRun, start};
use super::schedule::{schedule, target};
use super::synthetic;
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

/// One simulated subject: the metric (`metric` 0 mean-squared tracking error, 1 mean-squared
/// cab acceleration) of each of the study's compensators, in `params.controllers` order, at
/// `seat`; None if a trial did not run to its end.
fn subject(
    params: &StudyParams,
    seed: u64,
    index: u32,
    seat: Seat,
    metric: usize,
) -> Result<Option<Vec<f64>>> {
    let draw = synthetic::draw(params, seed, index);
    let tests = schedule(params, seed, index);
    let mut row = Vec::with_capacity(params.controllers.len());
    for spec in &params.controllers {
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
        let msg = start(params, run, Operator::Synthetic(Some(draw)));
        let metrics = bdft_controller::runtime::local::metrics(&msg, DT)
            .map_err(|e| AppError::BadRequest(format!("a simulated trial: {e}")))?;
        match metrics {
            Some(m) => row.push(if metric == 0 {
                m.mse_tracking_mm2
            } else {
                m.ms_cab_accel
            }),
            None => return Ok(None),
        }
    }
    Ok(Some(row))
}

/// A worker's simulated subjects, by their index in the plan.
type Part = Result<Vec<(usize, Option<Vec<f64>>)>>;

/// `studies` simulated studies of `max_n` subjects each, subject by subject
/// (`rows[study·max_n + i]`), on every core; `progress` counts trials.
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
    let next = AtomicUsize::new(0);
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let parts: Vec<Part> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let j = next.fetch_add(1, Ordering::Relaxed);
                        if j >= total {
                            return Ok(mine);
                        }
                        let (s, i) = (j / max_n, j % max_n);
                        let row = subject(params, study_seed(seed, s), i as u32, seat, metric)?;
                        progress.add(k);
                        mine.push((j, row));
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a planner worker panicked"))
            .collect()
    });
    let mut rows = vec![None; total];
    for part in parts {
        for (j, row) in part? {
            rows[j] = row;
        }
    }
    Ok(rows)
}
