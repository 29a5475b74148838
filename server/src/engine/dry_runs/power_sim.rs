//! The power planner's simulated studies with the study's own synthetic population: every
//! simulated subject is drawn from the population, scheduled and given targets as enrolment
//! would (order, positions, target seeds), and runs full 1 kHz trials — one per compensator
//! at the planned seat — from the same `StartTrial` as a pilot, without records, batched
//! several subjects to a run (`bdft_controller::batch`: the pilot's trial, tick for tick,
//! with its own vectorized noise streams; `calibration::sim`). A subject whose trial the
//! cab-vibration interlock stopped lacks that value and
//! is left out of its study's table, as the statistics leave out a subject with a missing
//! test.

use bdft_controller::rng::Rng;
use bdft_protocol::params::Seat;
use bdft_protocol::study::StudyParams;
use std::sync::atomic::AtomicBool;

use super::calibration::sim::{self, Cell, DT, SubjectRef};
use super::job::Progress;
use crate::error::Result;

/// Loop ticks a plan of `studies` simulated studies of `max_n` subjects takes at `params`'
/// trial length: what bounds a request.
pub fn ticks(params: &StudyParams, studies: usize, max_n: usize) -> f64 {
    (studies * max_n * params.compensators.len()) as f64 * (params.trial_s / DT).round()
}

/// The seed of simulated study `study` of a plan seeded `seed` (its subjects' draws,
/// schedules and targets derive from it as enrolment derives them from a study's seed).
fn study_seed(seed: u64, study: usize) -> u64 {
    Rng::derive(seed, study as u64 + 1).next_u64()
}

/// `studies` simulated studies of `max_n` subjects each, subject by subject
/// (`rows[study·max_n + i]`, one metric per compensator in `params.compensators` order; None
/// for a subject with a trial the interlock stopped), on every core
/// (`calibration::sim::simulate`); `progress` counts trials.
pub fn simulate(
    params: &StudyParams,
    seat: Seat,
    metric: usize,
    studies: usize,
    max_n: usize,
    seed: u64,
    progress: &Progress,
) -> Result<Vec<Option<Vec<f64>>>> {
    let subjects: Vec<SubjectRef> = (0..studies * max_n)
        .map(|j| SubjectRef {
            seed: study_seed(seed, j / max_n),
            index: (j % max_n) as u32,
        })
        .collect();
    let cells: Vec<Cell> = (0..params.compensators.len())
        .map(|compensator| Cell { compensator, seat })
        .collect();
    let rows = sim::simulate(params, &subjects, &cells, progress, &AtomicBool::new(false))?;
    Ok(rows
        .into_iter()
        .map(|row| {
            row.into_iter()
                .map(|m| {
                    m.map(|m| {
                        if metric == 0 {
                            m.mse_tracking_mm2
                        } else {
                            m.ms_cab_accel
                        }
                    })
                })
                .collect::<Option<Vec<f64>>>()
        })
        .collect())
}
