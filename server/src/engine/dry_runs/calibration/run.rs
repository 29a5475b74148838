//! A calibration of a study as the command line and the dashboard start it: the target
//! (a table, or the study's own completed tests), the fit on the batch simulator, and the
//! result stored as the study's next population version with its audit row.

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

use bdft_protocol::records::{TestPhase, TrialStatus};
use bdft_protocol::trial::Metrics;
use serde::{Deserialize, Serialize};
use sqlx::AnyPool;

use super::fit::{FitReport, check_enough, fit};
use super::ratings::{PeopleRated, predicted};
use super::sim::all_cells;
use super::target::{Target, from_subjects, hold_out, parse_table};
use crate::engine::dry_runs::job::{Job, JobStatus, Progress};
use crate::error::{AppError, Result};
use crate::store::exports::Withdrawn;
use crate::store::studies::Study;
use crate::store::{self, Change};

#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CalibrateRequest {
    /// A table of cell means, CSV `controller,station,metric,mean[,sd,n[,unit[,use]]]`
    /// (unit: the metric's, e.g. mm2, 1e5mm2/s4; use: fit or hold-out); absent: the study's
    /// own completed tests.
    #[serde(default)]
    pub table: Option<String>,
    /// Rows of the target left out of the fit and predicted: comma-separated
    /// `controller:station[:metric]` (no metric: every metric of the cell), e.g.
    /// `lqr:on,pid:on:ms_cab_accel`.
    #[serde(default)]
    pub hold_out: Option<String>,
    /// Simulated subjects per evaluation (8 to 512) [default 48].
    #[serde(default = "default_subjects")]
    pub simulated_subjects: usize,
    #[serde(default)]
    pub seed: u64,
}

fn default_subjects() -> usize {
    48
}

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct CalibrationReport {
    pub study_id: i64,
    /// The population version the fit was stored as.
    pub population_version: i64,
    pub fit: FitReport,
}

/// The study's own completed tests: each subject's latest completed attempt of each scored
/// test, in the study's cells; and the people's ratings of those tests per cell (predicted
/// after the fit, never fitted).
async fn study_target(
    pool: &AnyPool,
    study_id: i64,
    cells: &[super::sim::Cell],
    params: &bdft_protocol::study::StudyParams,
) -> Result<(Target, Vec<PeopleRated>)> {
    let rows = store::exports::trial_rows(pool, study_id, Withdrawn::LeftOut).await?;
    let mut subjects: Vec<(String, Vec<Option<Metrics>>)> = Vec::new();
    let mut answers: Vec<Vec<[Option<i64>; 4]>> = vec![Vec::new(); cells.len()];
    for r in rows {
        if r.phase != TestPhase::Test || !r.latest || r.status != TrialStatus::Complete {
            continue;
        }
        let Some(j) = cells.iter().position(|c| {
            c.seat == r.station && params.compensators[c.compensator].kind() == r.controller
        }) else {
            continue;
        };
        answers[j].push([r.accuracy, r.speed, r.smoothness, r.controllability]);
        let (Some(mse), Some(acc)) = (r.mse_tracking_mm2, r.ms_cab_accel) else {
            continue;
        };
        let at = match subjects.iter().position(|(code, _)| *code == r.code) {
            Some(i) => i,
            None => {
                subjects.push((r.code.clone(), vec![None; cells.len()]));
                subjects.len() - 1
            }
        };
        subjects[at].1[j] = Some(Metrics {
            ticks: 0,
            mse_tracking_mm2: mse,
            ms_cab_accel: acc,
        });
    }
    let target = from_subjects(cells, subjects.into_iter().map(|(_, v)| v).collect());
    if target.cells.is_empty() {
        return Err(AppError::BadRequest(format!(
            "study {study_id} has no cell with completed tests of 2 or more subjects to calibrate to; run tests first or give a table"
        )));
    }
    let rated = cells
        .iter()
        .zip(answers)
        .map(|(&cell, given)| PeopleRated {
            cell,
            items: std::array::from_fn(|i| {
                let v: Vec<f64> = given
                    .iter()
                    .filter_map(|a| a[i])
                    .map(|r| r as f64)
                    .collect();
                (!v.is_empty()).then(|| (v.iter().sum::<f64>() / v.len() as f64, v.len()))
            }),
        })
        .collect();
    Ok((target, rated))
}

/// A calibration ready to run: the study, its target and the request.
#[derive(Debug)]
pub struct Prepared {
    study: Study,
    target: Target,
    /// What the study's people rated (none for a table).
    people: Vec<PeopleRated>,
    source: String,
    req: CalibrateRequest,
}

/// Checks the request and reads its target: a bad table or a study without data is refused
/// here (422), before anything runs.
pub async fn prepare(pool: &AnyPool, study_id: i64, req: CalibrateRequest) -> Result<Prepared> {
    if !(8..=super::fit::MAX_SUBJECTS).contains(&req.simulated_subjects) {
        return Err(AppError::BadRequest(format!(
            "simulated_subjects: 8 to {}",
            super::fit::MAX_SUBJECTS
        )));
    }
    let study = store::studies::get(pool, study_id).await?;
    let cells = all_cells(&study.params);
    let (target, people, source) = match &req.table {
        Some(csv) => (
            parse_table(&study.params, csv)?,
            Vec::new(),
            "table".to_string(),
        ),
        None => {
            let (target, people) = study_target(pool, study_id, &cells, &study.params).await?;
            (
                target,
                people,
                format!("study {study_id}'s completed tests"),
            )
        }
    };
    let mut target = target;
    if let Some(spec) = &req.hold_out {
        hold_out(&study.params, &mut target, spec)?;
    }
    check_enough(&target)?;
    Ok(Prepared {
        study,
        target,
        people,
        source,
        req,
    })
}

/// Calibrates `study_id` on behalf of `actor` and stores the result as its next population
/// version. `progress` counts simulated trials; `cancel` stops the fit (409, nothing stored).
pub async fn calibrate(
    pool: &AnyPool,
    actor: &str,
    study_id: i64,
    req: CalibrateRequest,
    progress: Arc<Progress>,
    cancel: Arc<AtomicBool>,
) -> Result<CalibrationReport> {
    let prepared = prepare(pool, study_id, req).await?;
    run_prepared(pool, actor, prepared, progress, cancel).await
}

async fn run_prepared(
    pool: &AnyPool,
    actor: &str,
    prepared: Prepared,
    progress: Arc<Progress>,
    cancel: Arc<AtomicBool>,
) -> Result<CalibrationReport> {
    let Prepared {
        study,
        target,
        people,
        source,
        req,
    } = prepared;
    let study_id = study.id;
    let _turn = crate::engine::COMPUTE
        .acquire()
        .await
        .expect("never closed");
    let params = study.params.clone();
    let fitted = tokio::task::spawn_blocking(move || {
        let mut fitted = fit(
            &params,
            &target,
            &source,
            req.simulated_subjects,
            req.seed,
            &progress,
            &cancel,
        )?;
        // The ratings: predicted by the fitted population, beside the people's.
        fitted.predictions.extend(predicted(
            &params,
            &fitted.population,
            req.simulated_subjects,
            req.seed,
            &people,
            &progress,
            &cancel,
        )?);
        Ok::<_, AppError>(fitted)
    })
    .await
    .map_err(|e| AppError::Internal(anyhow::anyhow!("the calibration panicked: {e}")))??;
    let report = serde_json::to_value(&fitted).expect("a report serializes");
    let mut change = Change::begin(pool, actor).await?;
    let version =
        store::populations::insert(change.db(), study_id, &fitted.population, &report, actor)
            .await?;
    change
        .commit(
            "population.calibrate",
            Some(format!("study:{study_id}")),
            Calibrated {
                version,
                source: &fitted.source,
                objective: fitted.objective,
                parameters: &fitted.parameters,
                not_identified: &fitted.not_identified,
                verdict: &fitted.goodness_of_fit.verdict,
                at_bound: &fitted.at_bound,
            },
        )
        .await?;
    Ok(CalibrationReport {
        study_id,
        population_version: version,
        fit: fitted,
    })
}

/// The one calibration the dashboard may have going, with progress and cancel.
#[derive(Debug, Default)]
pub struct CalibrationJob {
    job: Arc<Job<CalibrationReport>>,
    cancel: Mutex<Arc<AtomicBool>>,
}

pub type CalibrationStatus = JobStatus<CalibrationReport>;

impl CalibrationJob {
    /// Starts a calibration of `study_id` in the background; a bad target is refused now.
    pub async fn start(
        &self,
        pool: &AnyPool,
        actor: &str,
        study_id: i64,
        req: CalibrateRequest,
    ) -> Result<()> {
        let prepared = prepare(pool, study_id, req).await?;
        // Held across the start, so a cancel reaches this run's flag, never the last one's.
        let mut current = self.cancel.lock().unwrap_or_else(|p| p.into_inner());
        let cancel = Arc::new(AtomicBool::new(false));
        let (pool, actor, flag) = (pool.clone(), actor.to_string(), cancel.clone());
        self.job
            .spawn(study_id, "a calibration", move |progress| async move {
                run_prepared(&pool, &actor, prepared, progress, flag)
                    .await
                    .map_err(|e| e.to_string())
            })?;
        *current = cancel;
        Ok(())
    }

    /// Stops the running calibration at its next batch of trials (nothing is stored).
    pub fn cancel(&self) {
        self.cancel
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .store(true, std::sync::atomic::Ordering::Relaxed);
    }

    pub fn status(&self) -> CalibrationStatus {
        self.job.status()
    }
}

/// The audit detail of a calibration (`population.calibrate`): the version it stored and
/// what the fit found — its parameters, its goodness-of-fit verdict and the parameters that
/// ended at a bound, so the log alone says whether the stored population fits (the whole
/// report is the version's own row).
#[derive(Debug, Serialize)]
struct Calibrated<'a> {
    version: i64,
    source: &'a str,
    objective: f64,
    parameters: &'a [super::fit::FittedParameter],
    not_identified: &'a [String],
    verdict: &'a str,
    at_bound: &'a [String],
}
