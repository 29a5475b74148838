//! The power planner: for candidate numbers of subjects, the probability that each planned
//! comparison (every pair of compensators at one seat, exact Wilcoxon, Holm across the
//! pairs; or, in a study with cancellation, each compensator on the machine against itself
//! cancelled with one arm, Holm across the compensators, as the statistics test them)
//! reaches significance, by simulating whole studies. The studies come from one of
//! two models: the study's synthetic population, whose subjects run full trials
//! (`power_sim`; slow, so it runs as a background job with progress), or a pilot's data: on
//! the log scale, each compensator's mean and the residual spread of the subject ×
//! compensator table (the subjects' own level cancels in paired differences).
//! Comparisons the exact test's floor rules out at an n are reported as impossible, not
//! simulated.

use bdft_controller::rng::Rng;
use serde::{Deserialize, Serialize};
use sqlx::AnyPool;

use std::sync::Arc;

use bdft_protocol::params::Seat;
use bdft_protocol::study::{CancellationArm, StudyParams};

use super::job::{Job, JobStatus, Progress};
use crate::engine::results::inference::nonparametric::{
    EXACT_MAX_N, holm, wilcoxon, wilcoxon_floor,
};
use crate::engine::results::study_data::{SUMMARY_VARIABLES, StudyData, cancelled_key};
use crate::error::{AppError, Result};
use crate::store;

/// Where the simulated studies come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum PlanSource {
    /// The log-normal model estimated from the study's (a pilot's) data.
    #[default]
    Pilot,
    /// The study's synthetic population, running full 1 kHz trials.
    Population,
}

/// What to plan: candidate numbers of subjects for one metric at one seat.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PlanRequest {
    /// `pilot` (default) or `population`.
    #[serde(default)]
    pub source: PlanSource,
    /// Candidate numbers of subjects, 2 to 200 each, at most 20.
    pub subjects: Vec<usize>,
    /// `mse_tracking_mm2` or `ms_cab_accel` (the continuous metrics).
    pub metric: String,
    /// The seat: `on` or `off` (the API's key is `station`).
    #[serde(rename = "station")]
    pub seat: String,
    /// Simulated studies per candidate: 100 to 100000 with a pilot's model (default 1000),
    /// 10 to 10000 with the population.
    #[serde(default = "default_draws")]
    pub draws: usize,
    #[serde(default = "default_alpha")]
    pub alpha: f64,
    #[serde(default)]
    pub seed: u64,
    /// The comparisons to plan: absent, every pair of compensators at `station`; an arm of
    /// the study's cancellation factor (`personal`, `generic`, `wrong`), each compensator on
    /// the machine against itself cancelled with it (`wilcoxon_cancellation`, Holm across
    /// the compensators). Planned from a pilot's data only: the population's simulated
    /// subjects run no identification test to take a model from.
    #[serde(default)]
    pub cancellation: Option<CancellationArm>,
}

fn default_draws() -> usize {
    1000
}

fn default_alpha() -> f64 {
    0.05
}

/// The model and the plan of every candidate.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct PlanReport {
    pub source: PlanSource,
    /// With a pilot, the pilot's model; with the population, the same model estimated from
    /// every simulated subject (the population's effects on the log scale).
    pub model: Model,
    pub seed: u64,
    pub plans: Vec<Plan>,
}

/// Simulated subjects a request may ask for in all (Σ candidates × draws): a few seconds of
/// CPU, so that one request cannot hold the planner for minutes.
const MAX_WORK: usize = 2_000_000;

impl PlanRequest {
    /// Refuses a request `params` cannot answer (422 naming the field); the metric's index.
    fn check(&self, params: &StudyParams) -> Result<usize> {
        let bad = |m: String| Err(AppError::BadRequest(m));
        if let Some(arm) = self.cancellation {
            let arms = params
                .cancellation
                .as_ref()
                .map_or(&[][..], |c| &c.arms[..]);
            if !arms.contains(&arm) {
                let listed: Vec<&str> = arms.iter().map(|a| a.as_str()).collect();
                return bad(format!(
                    "cancellation: \"{arm}\" is not one of the study's cancelling arms ({})",
                    if listed.is_empty() {
                        "it has none".to_string()
                    } else {
                        listed.join(", ")
                    }
                ));
            }
            if self.source == PlanSource::Population {
                return bad(
                    "cancellation: planned from a pilot's data only (source pilot): the \
                     population's simulated subjects run no identification test to cancel with; \
                     run `bdft-server pilot --cancellation` and plan on its copy"
                        .into(),
                );
            }
            if self.seat != Seat::On.as_str() {
                return bad(format!(
                    "station: {:?}; cancellation runs on the machine only: on",
                    self.seat
                ));
            }
        }
        if self.subjects.is_empty() || self.subjects.len() > 20 {
            return bad("subjects: 1 to 20 candidate numbers of subjects".into());
        }
        if let Some(n) = self.subjects.iter().find(|n| !(2..=200).contains(*n)) {
            return bad(format!("subjects: {n} is outside 2 to 200"));
        }
        let draws = match self.source {
            PlanSource::Pilot => 100..=100_000,
            PlanSource::Population => 10..=10_000,
        };
        if !draws.contains(&self.draws) {
            return bad(format!(
                "draws: {} to {} simulated studies with the {} model",
                draws.start(),
                draws.end(),
                if self.source == PlanSource::Pilot {
                    "pilot"
                } else {
                    "population"
                }
            ));
        }
        let work: usize = self.subjects.iter().map(|n| n * self.draws).sum();
        if self.source == PlanSource::Pilot && work > MAX_WORK {
            return bad(format!(
                "draws × subjects: {work} simulated subjects in all, at most {MAX_WORK} a \
                 request (fewer draws or fewer candidates)"
            ));
        }
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            return bad("alpha: a level between 0 and 1".into());
        }
        if !["on", "off"].contains(&self.seat.as_str()) {
            return bad(format!("station: {:?}; valid: on, off", self.seat));
        }
        match SUMMARY_VARIABLES[..2]
            .iter()
            .position(|m| *m == self.metric)
        {
            Some(i) => Ok(i),
            None => bad(format!(
                "metric: {:?}; valid: mse_tracking_mm2, ms_cab_accel (ratings are ordinal: \
                 the planner's log-normal model does not fit them)",
                self.metric
            )),
        }
    }
}

/// Most loop ticks a population plan may simulate: the benchmark's size, 1,000 studies of 8
/// subjects × 10 trials of 140 s (docs/benchmarks.md: under a minute of both cores with
/// AVX-512, about a minute and a half with AVX2).
const MAX_POPULATION_TICKS: f64 = 1.12e10;

/// Refuses a population plan larger than `MAX_POPULATION_TICKS`; the largest candidate n.
fn check_population_work(params: &StudyParams, req: &PlanRequest) -> Result<usize> {
    let max_n = req.subjects.iter().copied().max().unwrap_or(2);
    let ticks = super::power_sim::ticks(params, req.draws, max_n);
    if ticks > MAX_POPULATION_TICKS {
        return Err(AppError::BadRequest(format!(
            "draws × subjects: {ticks:.3e} loop ticks of simulated trials, at most \
             {MAX_POPULATION_TICKS:.3e} a request (fewer draws or fewer subjects)"
        )));
    }
    Ok(max_n)
}

/// Plans `study_id`: with a pilot's model, estimated from the study's data (run a pilot and
/// plan on its dry-run copy, or on the study's own first subjects); with the population, by
/// running its simulated subjects' trials (`progress` counts them).
pub async fn plan_study(
    pool: &AnyPool,
    study_id: i64,
    req: PlanRequest,
    progress: Arc<Progress>,
) -> Result<PlanReport> {
    let study = store::studies::get(pool, study_id).await?;
    let metric = req.check(&study.params)?;
    if req.source == PlanSource::Population {
        let seat: Seat = req
            .seat
            .parse()
            .map_err(|e: bdft_protocol::params::ParamError| AppError::BadRequest(e.to_string()))?;
        let max_n = check_population_work(&study.params, &req)?;
        let _turn = crate::engine::COMPUTE
            .acquire()
            .await
            .expect("never closed");
        return tokio::task::spawn_blocking(move || {
            let rows = super::power_sim::simulate(
                &study.params,
                seat,
                metric,
                req.draws,
                max_n,
                req.seed,
                &progress,
            )?;
            let names: Vec<String> = study
                .params
                .compensators
                .iter()
                .map(|c| c.kind().name().to_string())
                .collect();
            let pairs = every_pair(names.len());
            let all: Vec<Vec<f64>> = rows.iter().flatten().cloned().collect();
            let model = estimate(&names, &all).ok_or_else(|| {
                AppError::Conflict("fewer than 2 simulated subjects completed every test".into())
            })?;
            let mut rng = Rng::new(req.seed);
            let plans = req
                .subjects
                .iter()
                .map(|&n| {
                    // Study d of every candidate is the first n subjects of simulated study
                    // d: common random numbers, so candidates differ only by n.
                    let mut study = 0;
                    plan_with(&names, &pairs, n, req.alpha, req.draws, &mut rng, |_, n| {
                        let first = study * max_n;
                        study += 1;
                        rows[first..first + n].iter().flatten().cloned().collect()
                    })
                })
                .collect();
            Ok(PlanReport {
                source: req.source,
                model,
                seed: req.seed,
                plans,
            })
        })
        .await
        .map_err(|e| AppError::Internal(anyhow::anyhow!("planner task: {e}")))?;
    }
    let data = StudyData::load(pool, study_id).await?;
    let (columns, pairs) = comparisons(&data.compensators, req.cancellation);
    let model =
        estimate(&columns, &data.complete_rows(&columns, metric, &req.seat)).ok_or_else(|| {
            AppError::Conflict(match req.cancellation {
                None => format!(
                    "the study has fewer than 2 subjects with every compensator complete at \
                     the {} seat: run a pilot (its dry-run copy) first, or plan with the \
                     population",
                    req.seat
                ),
                Some(arm) => format!(
                    "the study has fewer than 2 subjects with every compensator complete on \
                     the machine both uncancelled and cancelled with the {arm} model: run a \
                     pilot with --cancellation (its dry-run copy) first"
                ),
            })
        })?;
    let _turn = crate::engine::COMPUTE
        .acquire()
        .await
        .expect("never closed");
    tokio::task::spawn_blocking(move || PlanReport {
        source: req.source,
        plans: req
            .subjects
            .iter()
            .map(|&n| plan(&model, &pairs, n, req.alpha, req.draws, req.seed))
            .collect(),
        seed: req.seed,
        model,
    })
    .await
    .map_err(|e| anyhow::anyhow!("planner task: {e}").into())
}

/// The one power plan the dashboard may have going in the background, with its progress.
#[derive(Debug, Default)]
pub struct PlanJob {
    job: Arc<Job<PlanReport>>,
}

/// Where the dashboard's power plan stands (steps: simulated trials; a pilot's model has
/// none).
pub type PlanStatus = JobStatus<PlanReport>;

impl PlanJob {
    /// Checks `req` and starts planning `study_id` in the background; refused while another
    /// plan runs.
    pub async fn start(&self, pool: &AnyPool, study_id: i64, req: PlanRequest) -> Result<()> {
        let study = store::studies::get(pool, study_id).await?;
        req.check(&study.params)?;
        if req.source == PlanSource::Population {
            check_population_work(&study.params, &req)?;
        }
        let pool = pool.clone();
        self.job
            .spawn(study_id, "a power plan", move |progress| async move {
                plan_study(&pool, study_id, req, progress)
                    .await
                    .map_err(|e| e.to_string())
            })
    }

    pub fn status(&self) -> PlanStatus {
        self.job.status()
    }
}

/// Every pair of `k` columns, in the statistics' order.
fn every_pair(k: usize) -> Vec<(usize, usize)> {
    (0..k)
        .flat_map(|i| (i + 1..k).map(move |j| (i, j)))
        .collect()
}

/// The planned comparisons over the study's `compensators`: the model's columns (the cells'
/// keys, `study_data::cancelled_key`) and the pairs of them compared. Without an arm, the
/// compensators and every pair; with one, the compensators then each cancelled with it, and
/// each against its own cancelled column.
fn comparisons(
    compensators: &[String],
    arm: Option<CancellationArm>,
) -> (Vec<String>, Vec<(usize, usize)>) {
    let k = compensators.len();
    match arm {
        None => (compensators.to_vec(), every_pair(k)),
        Some(arm) => (
            compensators
                .iter()
                .cloned()
                .chain(compensators.iter().map(|c| cancelled_key(c, arm)))
                .collect(),
            (0..k).map(|c| (c, k + c)).collect(),
        ),
    }
}

/// A study model on the log scale: each cell's mean and the residual standard deviation.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Model {
    /// The cells' keys: the compensators, and with a cancellation arm each also cancelled
    /// ("pid+personal").
    pub compensators: Vec<String>,
    pub log_means: Vec<f64>,
    pub residual_sd: f64,
    /// Subjects the model was estimated from.
    pub pilot_n: usize,
}

/// The model estimated from a pilot's table `y[s][c]` of positive values (every subject
/// every compensator, at least 2 × 2). `None` if it is too small.
pub fn estimate(compensators: &[String], y: &[Vec<f64>]) -> Option<Model> {
    let n = y.len();
    let k = compensators.len();
    if n < 2
        || k < 2
        || y.iter()
            .any(|r| r.len() != k || r.iter().any(|v| *v <= 0.0))
    {
        return None;
    }
    let logs: Vec<Vec<f64>> = y
        .iter()
        .map(|r| r.iter().map(|v| v.ln()).collect())
        .collect();
    let grand = logs.iter().flatten().sum::<f64>() / (n * k) as f64;
    let col: Vec<f64> = (0..k)
        .map(|c| logs.iter().map(|r| r[c]).sum::<f64>() / n as f64)
        .collect();
    let row: Vec<f64> = logs
        .iter()
        .map(|r| r.iter().sum::<f64>() / k as f64)
        .collect();
    let ss: f64 = logs
        .iter()
        .enumerate()
        .flat_map(|(s, r)| {
            let (row, col) = (&row, &col);
            r.iter()
                .enumerate()
                .map(move |(c, v)| (v - row[s] - col[c] + grand).powi(2))
        })
        .sum();
    Some(Model {
        compensators: compensators.to_vec(),
        log_means: col,
        residual_sd: (ss / ((n - 1) * (k - 1)) as f64).sqrt(),
        pilot_n: n,
    })
}

/// One pair's chance at one n.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct PairPower {
    pub a: String,
    pub b: String,
    /// Probability that the Holm-adjusted p is below alpha.
    pub power: f64,
    /// False when the exact floor makes significance impossible at this n.
    pub possible: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Plan {
    pub subjects: usize,
    pub alpha: f64,
    pub draws: usize,
    pub pairs: Vec<PairPower>,
    /// Probability that at least one pair is significant.
    pub any: f64,
    pub note: String,
}

/// The planner at `n` subjects: `draws` simulated studies, each drawn by `draw` (one
/// row of a value per column per subject, n rows), analysed as the study would be: each of
/// `pairs` of columns by exact Wilcoxon, Holm across them.
pub fn plan_with(
    columns: &[String],
    pairs: &[(usize, usize)],
    n: usize,
    alpha: f64,
    draws: usize,
    rng: &mut Rng,
    mut draw: impl FnMut(&mut Rng, usize) -> Vec<Vec<f64>>,
) -> Plan {
    let m = pairs.len();
    let best = (wilcoxon_floor(n) * m as f64).min(1.0);
    let possible = !(n <= EXACT_MAX_N && best >= alpha);
    let mut hits = vec![0usize; m];
    let mut any = 0usize;
    if possible {
        for _ in 0..draws {
            let y = draw(rng, n);
            let p: Vec<f64> = pairs
                .iter()
                .map(|&(i, j)| {
                    let a: Vec<f64> = y.iter().map(|r| r[i]).collect();
                    let b: Vec<f64> = y.iter().map(|r| r[j]).collect();
                    wilcoxon(&a, &b).map_or(1.0, |w| w.p_value)
                })
                .collect();
            let adjusted = holm(&p);
            let mut some = false;
            for (h, q) in hits.iter_mut().zip(&adjusted) {
                if *q < alpha {
                    *h += 1;
                    some = true;
                }
            }
            any += usize::from(some);
        }
    }
    let frac = |x: usize| {
        if possible {
            x as f64 / draws as f64
        } else {
            0.0
        }
    };
    Plan {
        subjects: n,
        alpha,
        draws: if possible { draws } else { 0 },
        pairs: pairs
            .iter()
            .zip(&hits)
            .map(|(&(i, j), &h)| PairPower {
                a: columns[i].clone(),
                b: columns[j].clone(),
                power: frac(h),
                possible,
            })
            .collect(),
        any: frac(any),
        note: if possible {
            String::new()
        } else {
            format!(
                "no pair can reach p < {alpha} with {n} subjects: the exact Wilcoxon test's \
                 smallest p is 2/2^{n} = {:.4}, × {m} comparisons (Holm) = {best:.3}",
                wilcoxon_floor(n)
            )
        },
    }
}

/// The planner at `n` subjects with a pilot's model, for `pairs` of its columns.
pub fn plan(
    model: &Model,
    pairs: &[(usize, usize)],
    n: usize,
    alpha: f64,
    draws: usize,
    seed: u64,
) -> Plan {
    let mut rng = Rng::new(seed);
    plan_with(
        &model.compensators,
        pairs,
        n,
        alpha,
        draws,
        &mut rng,
        |rng, n| {
            (0..n)
                .map(|_| {
                    model
                        .log_means
                        .iter()
                        .map(|mu| (mu + model.residual_sd * rng.normal()).exp())
                        .collect()
                })
                .collect()
        },
    )
}

#[cfg(test)]
#[path = "power_tests.rs"]
mod tests;
