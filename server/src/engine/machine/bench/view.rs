//! A bench run read back: its results with their reductions against each compensated
//! design's uncompensated twin, and the stored traces.

use bdft_protocol::trial::record_channel;
use serde::{Deserialize, Serialize};
use sqlx::AnyPool;
use utoipa::ToSchema;

use super::DECIMATION;
use crate::error::{AppError, Result};
use crate::store;
use crate::store::bench::{BenchResult, BenchRun};

pub use bdft_controller::conditions::twin;

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
    /// Per result, in the same order.
    pub traces: Vec<Trace>,
}

/// A result's stored trace: the reference, cylinder position and cab acceleration of its
/// record at every `DECIMATION`-th tick, `dt_s` apart (null where a value was not finite).
// The fields are in alphabetical order, the order the stored text and the API's answer have
// had since the trace was an untyped JSON object.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Trace {
    /// Cab acceleration (mm/s²).
    pub cab_accel_mm_s2: Vec<Option<f64>>,
    /// Cylinder position (mm).
    pub cyl_pos_mm: Vec<Option<f64>>,
    /// Time between two kept samples (s).
    pub dt_s: f64,
    /// The reference signal (mm).
    pub target_mm: Vec<Option<f64>>,
}

impl Trace {
    /// The trace of a record's `channels` (in `RECORD_CHANNELS` order) ticking every `dt`.
    /// Each value is the f32 the record holds, widened to f64 as JSON numbers are.
    pub fn decimated(channels: &[Vec<f32>], dt: f64) -> Self {
        let kept = |name: &str| -> Vec<Option<f64>> {
            let k = record_channel(name).expect("trace channels are record channels");
            channels.get(k).map_or_else(Vec::new, |c| {
                c.iter()
                    .step_by(DECIMATION)
                    .map(|&x| x.is_finite().then_some(f64::from(x)))
                    .collect()
            })
        };
        Self {
            cab_accel_mm_s2: kept("cab_accel_mm_s2"),
            cyl_pos_mm: kept("cyl_pos_mm"),
            dt_s: dt * DECIMATION as f64,
            target_mm: kept("target_mm"),
        }
    }

    /// The channels in `TRACE_CHANNELS` order.
    pub fn columns(&self) -> [&[Option<f64>]; 3] {
        [&self.target_mm, &self.cyl_pos_mm, &self.cab_accel_mm_s2]
    }
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

pub async fn view(pool: &AnyPool, run_id: i64) -> Result<RunView> {
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
    fn a_trace_holds_the_trace_channels_in_their_order() {
        let channels: Vec<Vec<f32>> = (0..bdft_protocol::trial::RECORD_CHANNELS.len())
            .map(|k| vec![k as f32; 2 * DECIMATION])
            .collect();
        let trace = Trace::decimated(&channels, 1e-3);
        for (name, column) in super::super::TRACE_CHANNELS.iter().zip(trace.columns()) {
            let k = record_channel(name).unwrap() as f64;
            assert_eq!(column, [Some(k), Some(k)], "{name}");
        }
        let text = serde_json::to_value(&trace).unwrap();
        let mut keys: Vec<&str> = text
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        let mut expected = super::super::TRACE_CHANNELS.to_vec();
        expected.push("dt_s");
        keys.sort_unstable();
        expected.sort_unstable();
        assert_eq!(keys, expected);
    }

    #[test]
    fn a_trace_is_stored_as_the_untyped_object_was() {
        // Keys in sorted order, each f32 widened to f64 as `serde_json::Value` widens it, null
        // for a value that is not finite.
        let mut channels =
            vec![vec![0.0f32; DECIMATION]; bdft_protocol::trial::RECORD_CHANNELS.len()];
        channels[record_channel("target_mm").unwrap()][0] = 0.1;
        channels[record_channel("cab_accel_mm_s2").unwrap()][0] = f32::NAN;
        let trace = Trace::decimated(&channels, 1e-3);
        assert_eq!(
            serde_json::to_string(&trace).unwrap(),
            r#"{"cab_accel_mm_s2":[null],"cyl_pos_mm":[0.0],"dt_s":0.01,"target_mm":[0.10000000149011612]}"#
        );
    }
}
