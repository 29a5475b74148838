//! A bench run read back: its results with their reductions against each compensated
//! design's uncompensated twin, and the stored traces.

use bdft_protocol::params::CompensatorKind;
use serde::Serialize;
use sqlx::SqlitePool;
use utoipa::ToSchema;

use crate::error::{AppError, Result};
use crate::store;
use crate::store::bench::{BenchResult, BenchRun};

/// The uncompensated design a compensated one is measured against: PID for the notch and the
/// shaper, LQR for the cab-velocity and cab-acceleration feedback; none for PID and LQR.
pub fn twin(kind: CompensatorKind) -> Option<CompensatorKind> {
    match kind {
        CompensatorKind::Pid | CompensatorKind::Lqr => None,
        CompensatorKind::PidNotch | CompensatorKind::PidShaper => Some(CompensatorKind::Pid),
        CompensatorKind::LqrCabvel | CompensatorKind::LqrCabacc => Some(CompensatorKind::Lqr),
    }
}

/// One compensator of a run: a design name (`pid`, `pid-shaper:zvd`, … as `robustness`
/// design has no twin or the run has none).
/// A run's result with its reductions against its twin in the same run (none when the
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ResultView {
    #[serde(flatten)]
    pub result: BenchResult,
    /// The label of the twin it is compared with.
    pub twin: Option<String>,
    /// 100 · (1 − mine / twin's), in %: positive is better than the twin.
    pub tracking_reduction_pct: Option<f64>,
    pub cab_accel_reduction_pct: Option<f64>,
}

/// A run with its results, their reductions and their traces.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RunView {
    pub run: BenchRun,
    pub results: Vec<ResultView>,
    /// Per result (same order): {"dt_s", "target_mm", "cyl_pos_mm", "cab_accel_mm_s2"}.
    #[schema(value_type = Vec<Object>)]
    pub traces: Vec<serde_json::Value>,
}

/// Each result with its reductions against the first result of its twin's kind.
pub fn with_reductions(results: Vec<BenchResult>) -> Vec<ResultView> {
    let pct = |mine: f64, theirs: f64| (theirs > 0.0).then(|| 100.0 * (1.0 - mine / theirs));
    results
        .iter()
        .map(|r| {
            let twin = twin(r.kind).and_then(|k| results.iter().find(|t| t.kind == k));
            ResultView {
                result: r.clone(),
                twin: twin.map(|t| t.label.clone()),
                tracking_reduction_pct: twin
                    .and_then(|t| pct(r.mse_tracking_mm2, t.mse_tracking_mm2)),
                cab_accel_reduction_pct: twin.and_then(|t| pct(r.ms_cab_accel, t.ms_cab_accel)),
            }
        })
        .collect()
}

pub async fn view(pool: &SqlitePool, run_id: i64) -> Result<RunView> {
    let run = store::bench::run(pool, run_id).await?;
    let results = store::bench::results(pool, run_id).await?;
    let traces = results
        .iter()
        .map(|r| {
            serde_json::from_str(&r.trace_json).map_err(|e| {
                AppError::Internal(anyhow::anyhow!(
                    "stored trace of bench result {}: {e}",
                    r.id
                ))
            })
        })
        .collect::<Result<_>>()?;
    Ok(RunView {
        run,
        results: with_reductions(results),
        traces,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_compensated_design_has_its_uncompensated_twin() {
        use CompensatorKind::*;
        assert_eq!(twin(PidNotch), Some(Pid));
        assert_eq!(twin(PidShaper), Some(Pid));
        assert_eq!(twin(LqrCabvel), Some(Lqr));
        assert_eq!(twin(LqrCabacc), Some(Lqr));
        assert_eq!(twin(Pid), None);
        assert_eq!(twin(Lqr), None);
    }
}
