//! Bench runs (`bench_runs`) and each compensator's result in them (`bench_results`: the
//! metrics of the full-rate record and the record decimated).

use bdft_protocol::params::CompensatorKind;
use serde::Serialize;
use sqlx::{AnyConnection, AnyExecutor};
use utoipa::ToSchema;

use super::db::now_ms;
use crate::error::{AppError, Result};

/// A bench run as listed.
#[derive(Debug, Clone, Serialize, ToSchema, sqlx::FromRow)]
pub struct BenchRun {
    pub id: i64,
    pub study_id: Option<i64>,
    /// `sim` or `real`.
    pub rig: String,
    /// The reference signal (a `TargetSpec`), as JSON text.
    pub signal_json: String,
    pub duration_s: f64,
    pub seed: i64,
    /// `running`, `done` or `failed`.
    pub status: String,
    pub error: Option<String>,
    pub created_by: String,
    pub created_at: i64,
    pub finished_at: Option<i64>,
    /// The site whose machine ran it (a run on the real rig; none when simulated here).
    pub site: Option<String>,
    /// The machine's condition it ran under (`MachineCondition`, migration 0032).
    pub condition: String,
}

/// What a new run is.
#[derive(Debug)]
pub struct NewRun<'a> {
    pub study_id: Option<i64>,
    pub rig: &'a str,
    pub signal_json: &'a str,
    pub duration_s: f64,
    pub seed: u64,
    pub created_by: &'a str,
    pub site: Option<&'a str>,
    pub condition: &'a str,
}

/// One compensator's result of a run.
#[derive(Debug, Clone, Serialize, ToSchema, sqlx::FromRow)]
pub struct BenchResult {
    pub id: i64,
    pub run_id: i64,
    pub position: i64,
    pub label: String,
    #[sqlx(try_from = "String")]
    pub kind: CompensatorKind,
    pub config_id: Option<i64>,
    /// The design that ran (a `CompensatorSpec`), as JSON text.
    pub spec_json: String,
    /// `complete`, or the fault that stopped it.
    pub outcome: String,
    pub ticks: i64,
    pub mse_tracking_mm2: f64,
    pub ms_cab_accel: f64,
    /// Every how many ticks the stored trace keeps one.
    pub decimation: i64,
    #[serde(skip)]
    pub trace_json: String,
}

/// What a new result is (`trace_json`: the decimated record).
#[derive(Debug)]
pub struct NewResult<'a> {
    pub position: i64,
    pub label: &'a str,
    pub kind: CompensatorKind,
    pub config_id: Option<i64>,
    pub spec_json: &'a str,
    pub outcome: &'a str,
    pub ticks: u64,
    pub mse_tracking_mm2: f64,
    pub ms_cab_accel: f64,
    pub decimation: u32,
    pub trace_json: &'a str,
}

pub async fn insert_run(db: &mut AnyConnection, run: &NewRun<'_>) -> Result<i64> {
    let (id,): (i64,) = sqlx::query_as(
        "INSERT INTO bench_runs (study_id, rig, signal_json, duration_s, seed, created_by, created_at, site, condition) \
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9) RETURNING id",
    )
    .bind(run.study_id)
    .bind(run.rig)
    .bind(run.signal_json)
    .bind(run.duration_s)
    .bind(run.seed as i64)
    .bind(run.created_by)
    .bind(now_ms())
    .bind(run.site)
    .bind(run.condition)
    .fetch_one(db)
    .await?;
    Ok(id)
}

pub async fn insert_result(db: &mut AnyConnection, run_id: i64, r: &NewResult<'_>) -> Result<i64> {
    let (id,): (i64,) = sqlx::query_as(
        "INSERT INTO bench_results (run_id, position, label, kind, config_id, spec_json, outcome, ticks, \
         mse_tracking_mm2, ms_cab_accel, decimation, trace_json) \
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12) RETURNING id",
    )
    .bind(run_id)
    .bind(r.position)
    .bind(r.label)
    .bind(r.kind.name())
    .bind(r.config_id)
    .bind(r.spec_json)
    .bind(r.outcome)
    .bind(r.ticks as i64)
    .bind(r.mse_tracking_mm2)
    .bind(r.ms_cab_accel)
    .bind(i64::from(r.decimation))
    .bind(r.trace_json)
    .fetch_one(db)
    .await?;
    Ok(id)
}

/// Ends a running run: `done`, or `failed` with `error`.
pub async fn finish(db: &mut AnyConnection, run_id: i64, error: Option<&str>) -> Result<()> {
    sqlx::query(
        "UPDATE bench_runs SET status = $1, error = $2, finished_at = $3 WHERE id = $4 AND status = 'running'",
    )
    .bind(if error.is_some() { "failed" } else { "done" })
    .bind(error)
    .bind(now_ms())
    .bind(run_id)
    .execute(db)
    .await?;
    Ok(())
}

/// Runs the server left running when it stopped: failed, with why.
pub async fn fail_unfinished(db: &mut AnyConnection, why: &str) -> Result<u64> {
    let done = sqlx::query(
        "UPDATE bench_runs SET status = 'failed', error = $1, finished_at = $2 WHERE status = 'running'",
    )
    .bind(why)
    .bind(now_ms())
    .execute(db)
    .await?;
    Ok(done.rows_affected())
}

/// The newest runs first, at most `limit`.
pub async fn runs<'c>(db: impl AnyExecutor<'c>, limit: i64) -> Result<Vec<BenchRun>> {
    Ok(
        sqlx::query_as("SELECT * FROM bench_runs ORDER BY id DESC LIMIT $1")
            .bind(limit)
            .fetch_all(db)
            .await?,
    )
}

pub async fn run<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<BenchRun> {
    sqlx::query_as("SELECT * FROM bench_runs WHERE id = $1")
        .bind(id)
        .fetch_optional(db)
        .await?
        .ok_or(AppError::NotFound("bench run"))
}

/// A run's results in the order the compensators were picked.
pub async fn results<'c>(db: impl AnyExecutor<'c>, run_id: i64) -> Result<Vec<BenchResult>> {
    Ok(
        sqlx::query_as("SELECT * FROM bench_results WHERE run_id = $1 ORDER BY position")
            .bind(run_id)
            .fetch_all(db)
            .await?,
    )
}
