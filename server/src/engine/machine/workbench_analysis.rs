//! The workbench's analysis of a study's designs on its plant and body: frequency responses
//! of every part and closed loop, the Nyquist view with the feedthrough opened, the pole
//! tables in both views (`bdft_controller::analysis::frequency`), and robustness maps
//! (`…::robustness`) over ranges the user sets, and the machine-conditions table
//! (`bdft_controller::conditions`: each design on the rig under each condition).
//!
//! Each is seconds of CPU: they run off the async threads and one at a time with the other
//! heavy reads (`engine::COMPUTE`); a robustness request's work is bounded (grid and
//! draws), and frequency reports are kept per distinct parameters in a small cache, as the
//! stability gate keeps its reports.

use std::collections::HashMap;
use std::sync::{Arc, LazyLock, Mutex};

use bdft_controller::analysis::frequency;
pub use bdft_controller::analysis::frequency::FrequencyReport;
pub use bdft_controller::analysis::robustness::RobustnessReport;
use bdft_controller::analysis::robustness::{Range, RobustnessSpec, robustness};
pub use bdft_controller::conditions::ConditionTable;
use bdft_controller::conditions::condition_table;
use bdft_controller::error::DesignError;
use bdft_protocol::params::{CompensatorSpec, MAX_KBF, MachineCondition, check};
use bdft_protocol::study::StudyParams;
use serde::Deserialize;
use sqlx::AnyPool;

use crate::engine::COMPUTE;
use crate::engine::study::stability::{analysis_key, study_loop};
use crate::error::{AppError, Result};
use crate::store;
use crate::store::studies::Study;

/// Largest robustness map (cells per axis) and number of draws one request may ask for:
/// about 3 s of CPU for the slowest design.
pub const MAX_GRID: usize = 50;
pub const MAX_DRAWS: usize = 2000;

/// What the dashboard asks of a robustness map; ranges in percent of nominal.
#[derive(Debug, Clone, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct RobustnessQuery {
    /// One of the study's compensators.
    pub design: String,
    /// K_H range, percent [default −50, 50].
    #[serde(default = "kh_lo")]
    pub kh_lo: f64,
    #[serde(default = "kh_hi")]
    pub kh_hi: f64,
    /// Both structure frequencies, percent [default −20, 20].
    #[serde(default = "freq_lo")]
    pub freq_lo: f64,
    #[serde(default = "freq_hi")]
    pub freq_hi: f64,
    /// Both structure dampings, percent [default −30, 30].
    #[serde(default = "damping_lo")]
    pub damping_lo: f64,
    #[serde(default = "damping_hi")]
    pub damping_hi: f64,
    /// Valve/cylinder K_VC, ω_VC, ζ_VC, percent [default −10, 10].
    #[serde(default = "valve_lo")]
    pub valve_lo: f64,
    #[serde(default = "valve_hi")]
    pub valve_hi: f64,
    /// Map cells per axis (1–50) [default 25].
    #[serde(default = "grid")]
    pub grid: usize,
    /// Monte-Carlo draws (0–2000) [default 500].
    #[serde(default = "draws")]
    pub draws: usize,
    #[serde(default = "seed")]
    pub seed: u64,
    /// K_BF a draw must be stable at [default: the study's].
    pub kbf: Option<f64>,
    /// A subject of the study whose identified body replaces the study's [default: none].
    pub subject: Option<i64>,
}

fn kh_lo() -> f64 {
    -50.0
}
fn kh_hi() -> f64 {
    50.0
}
fn freq_lo() -> f64 {
    -20.0
}
fn freq_hi() -> f64 {
    20.0
}
fn damping_lo() -> f64 {
    -30.0
}
fn damping_hi() -> f64 {
    30.0
}
fn valve_lo() -> f64 {
    -10.0
}
fn valve_hi() -> f64 {
    10.0
}
fn grid() -> usize {
    25
}
fn draws() -> usize {
    500
}
fn seed() -> u64 {
    1
}

impl RobustnessQuery {
    /// The spec, or a 422 naming the field and what is allowed.
    fn spec(&self, study_kbf: f64) -> Result<RobustnessSpec> {
        if !(1..=MAX_GRID).contains(&self.grid) {
            return Err(AppError::BadRequest(format!(
                "grid must be 1–{MAX_GRID} cells per axis, not {}",
                self.grid
            )));
        }
        if self.draws > MAX_DRAWS {
            return Err(AppError::BadRequest(format!(
                "draws must be 0–{MAX_DRAWS}, not {}",
                self.draws
            )));
        }
        let spec = RobustnessSpec {
            kh: Range::pct(self.kh_lo, self.kh_hi),
            freq: Range::pct(self.freq_lo, self.freq_hi),
            damping: Range::pct(self.damping_lo, self.damping_hi),
            valve: Range::pct(self.valve_lo, self.valve_hi),
            grid: self.grid,
            draws: self.draws,
            seed: self.seed,
            kbf: self.kbf.unwrap_or(study_kbf),
        };
        spec.validate()?;
        Ok(spec)
    }
}

fn design_error(name: &str) -> impl Fn(DesignError) -> AppError + '_ {
    move |e| match e {
        DesignError::Param(p) => p.into(),
        e => AppError::BadRequest(format!("{name}: the design cannot be analysed: {e}")),
    }
}

/// The study's designs by name (its compensators' names).
fn designs(params: &StudyParams) -> Vec<(String, CompensatorSpec)> {
    params
        .compensators
        .iter()
        .map(|c| (c.kind().name().to_string(), c.clone()))
        .collect()
}

/// Distinct frequency reports kept (each some hundreds of kB).
const CACHE_ENTRIES: usize = 8;

static REPORTS: LazyLock<Mutex<HashMap<String, Arc<FrequencyReport>>>> =
    LazyLock::new(Mutex::default);

/// The study's parameters with the body of `subject` (one of its subjects) as their latest
/// identification test fitted it, or as they are without a subject: what the workbench and
/// the per-subject stability analyse. A 409 when the subject has no fitted body yet.
pub async fn params_for(
    pool: &AnyPool,
    study: &Study,
    subject: Option<i64>,
) -> Result<StudyParams> {
    let mut params = study.params.clone();
    let Some(subject_id) = subject else {
        return Ok(params);
    };
    let subject = store::subjects::get(pool, subject_id).await?;
    if subject.study_id != study.id {
        return Err(AppError::BadRequest(format!(
            "subject: {subject_id} is not a subject of study {}",
            study.id
        )));
    }
    let fit = store::identifications::latest_fit(pool, subject_id)
        .await?
        .ok_or_else(|| {
            AppError::Conflict(format!(
                "{} has no identification test with a fitted body yet",
                subject.code
            ))
        })?;
    // A body with a parameter the data did not identify is no one's: not analysed.
    params.body = fit.identified_body().map_err(|why| {
        AppError::Conflict(format!(
            "{}'s identification test did not identify a whole body: {why}",
            subject.code
        ))
    })?;
    Ok(params)
}

/// Frequency responses, Nyquist views and pole tables of every design of the study, at
/// `kbf` (default the study's K_BF), on the machine under the study's condition (with a
/// condition factor, its first level).
pub async fn frequency_report(
    pool: &AnyPool,
    study_id: i64,
    kbf: Option<f64>,
    subject: Option<i64>,
) -> Result<Arc<FrequencyReport>> {
    let study = store::studies::get(pool, study_id).await?;
    let params = params_for(pool, &study, subject).await?;
    let k_bf = kbf.unwrap_or(params.k_bf);
    check("kbf", k_bf, 0.0, MAX_KBF)?;
    let key = analysis_key(&params, k_bf);
    let cached = || {
        REPORTS
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(&key)
            .cloned()
    };
    if let Some(r) = cached() {
        return Ok(r);
    }
    let _turn = COMPUTE.acquire().await.expect("never closed");
    // Someone may have computed it while this request waited its turn.
    if let Some(r) = cached() {
        return Ok(r);
    }
    let designs = designs(&params);
    let Some((_, first)) = designs.first() else {
        return Err(AppError::Conflict("the study has no compensators".into()));
    };
    let mut base = study_loop(&params, first);
    base.loop_params.k_bf = k_bf;
    // The machine as the study runs it: under its condition (a factor's first level).
    let condition = params.machine_conditions()[0];
    let rig = condition
        .apply(&params.plant)
        .map_err(|e| AppError::BadRequest(e.to_string()))?;
    let report = tokio::task::spawn_blocking(move || {
        frequency::report(&base, &designs, rig)
            .map(|r| FrequencyReport {
                condition: (!condition.is_default()).then(|| condition.to_string()),
                ..r
            })
            .map_err(design_error("frequency"))
    })
    .await
    .map_err(|e| anyhow::anyhow!("frequency task: {e}"))??;
    let report = Arc::new(report);
    let mut reports = REPORTS.lock().unwrap_or_else(|p| p.into_inner());
    if reports.len() >= CACHE_ENTRIES {
        reports.clear();
    }
    reports.insert(key, Arc::clone(&report));
    Ok(report)
}

/// The robustness map and pass rate of one of the study's designs.
pub async fn robustness_report(
    pool: &AnyPool,
    study_id: i64,
    q: RobustnessQuery,
) -> Result<RobustnessReport> {
    let study = store::studies::get(pool, study_id).await?;
    let params = params_for(pool, &study, q.subject).await?;
    let spec = q.spec(params.k_bf)?;
    let designs = designs(&params);
    let Some((name, design)) = designs.into_iter().find(|(n, _)| *n == q.design) else {
        let names: Vec<String> = params
            .compensators
            .iter()
            .map(|c| c.kind().name().to_string())
            .collect();
        return Err(AppError::BadRequest(format!(
            "design {:?} is not one of the study's compensators: {}",
            q.design,
            names.join(", ")
        )));
    };
    let setup = study_loop(&params, &design);
    let _turn = COMPUTE.acquire().await.expect("never closed");
    tokio::task::spawn_blocking(move || {
        robustness(&name, &setup, &spec).map_err(design_error("robustness"))
    })
    .await
    .map_err(|e| anyhow::anyhow!("robustness task: {e}"))?
}

/// The most conditions one conditions table may ask for: every named one and as many more.
pub const MAX_CONDITIONS: usize = 24;

/// What the dashboard asks of the machine-conditions table.
#[derive(Debug, Clone, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ConditionsQuery {
    /// Conditions, comma-separated (`tires,outriggers+loaded`, …) [default: every ground ×
    /// empty or rated bucket × boom or stick].
    pub conditions: Option<String>,
    /// A subject of the study whose identified body replaces the study's [default: none].
    pub subject: Option<i64>,
}

/// Every design of the study, made for its rig, on the rig under each condition: the bench
/// reduction against its twin and the margin with the body (`bdft-controller conditions`).
pub async fn conditions_report(
    pool: &AnyPool,
    study_id: i64,
    q: ConditionsQuery,
) -> Result<ConditionTable> {
    let conditions = match q.conditions.as_deref() {
        None | Some("") => MachineCondition::named(),
        Some(list) => {
            let names: Vec<&str> = list.split(',').map(str::trim).collect();
            if names.len() > MAX_CONDITIONS {
                return Err(AppError::BadRequest(format!(
                    "conditions: {} given; at most {MAX_CONDITIONS}",
                    names.len()
                )));
            }
            names
                .into_iter()
                .map(|n| n.parse::<MachineCondition>())
                .collect::<std::result::Result<Vec<_>, _>>()?
        }
    };
    let study = store::studies::get(pool, study_id).await?;
    let params = params_for(pool, &study, q.subject).await?;
    let designs = designs(&params);
    let Some((_, first)) = designs.first() else {
        return Err(AppError::Conflict("the study has no compensators".into()));
    };
    let base = study_loop(&params, first);
    let seed = 1;
    let _turn = COMPUTE.acquire().await.expect("never closed");
    tokio::task::spawn_blocking(move || {
        condition_table(&designs, &conditions, &base, seed).map_err(design_error("conditions"))
    })
    .await
    .map_err(|e| anyhow::anyhow!("conditions task: {e}"))?
}
