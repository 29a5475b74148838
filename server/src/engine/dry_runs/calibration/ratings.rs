//! The ratings a calibrated population predicts, beside what the study's people answered.
//! The fit sees tracking error and cab acceleration only; the ratings come from what the
//! simulated subjects perceive of their tests (`surveys`), so they are the model's honest
//! test: nothing of them was fitted.

use std::sync::atomic::AtomicBool;

use bdft_protocol::params::PopulationParams;
use bdft_protocol::study::StudyParams;

use super::fit::CellFit;
use super::sim::{Cell, enrolled};
use super::surveys::surveys;
use crate::engine::dry_runs::job::Progress;
use crate::error::Result;

/// The four survey items, as the report's `metric` names them (the exports' column names).
pub const ITEMS: [&str; 4] = [
    "rating_accuracy",
    "rating_speed",
    "rating_smoothness",
    "rating_controllability",
];

/// Simulated subjects answering the surveys after a fit, at most. Each of their tests runs
/// with its record to be perceived, a pilot's cost per test (480 tests of 140 s: 6.5 s in
/// release on 2 cores, docs/benchmarks.md): 64 subjects keep a 10-cell study's prediction
/// to seconds, and the mean rating's Monte-Carlo error near an eighth of a point.
pub const MAX_SUBJECTS: usize = 64;

/// What the study's people answered in one cell: per item the mean and how many answered.
#[derive(Debug, Clone, PartialEq)]
pub struct PeopleRated {
    pub cell: Cell,
    pub items: [Option<(f64, usize)>; 4],
}

/// Every item's mean rating in every cell of `params`' study with `population`, from `n`
/// simulated subjects (at most `MAX_SUBJECTS`, enrolled as a study seeded `seed` would
/// enrol them), each beside what `people` answered in the cell where they did.
pub fn predicted(
    params: &StudyParams,
    population: &PopulationParams,
    n: usize,
    seed: u64,
    people: &[PeopleRated],
    progress: &Progress,
    cancel: &AtomicBool,
) -> Result<Vec<CellFit>> {
    let fitted = StudyParams {
        population: *population,
        ..params.clone()
    };
    let cells = super::sim::all_cells(&fitted);
    let n = n.min(MAX_SUBJECTS) as u32;
    let answers = surveys(&fitted, &enrolled(seed, n), &cells, progress, cancel)?;
    let mut out = Vec::with_capacity(cells.len() * ITEMS.len());
    for (cell, a) in cells.iter().zip(&answers) {
        let theirs = people.iter().find(|p| p.cell == *cell);
        for (i, item) in ITEMS.iter().enumerate() {
            let observed = theirs.and_then(|p| p.items[i]);
            out.push(CellFit {
                compensator: a.compensator.clone(),
                seat: a.seat.clone(),
                metric: item.to_string(),
                target: None,
                target_sd: None,
                target_n: None,
                observed: observed.map(|o| o.0),
                observed_n: observed.map(|o| o.1),
                prediction: a.mean_ratings[i],
                monte_carlo_error: a.sd_ratings[i] / (a.n.max(1) as f64).sqrt(),
                low: None,
                high: None,
                inside: None,
                note: None,
            });
        }
    }
    Ok(out)
}
