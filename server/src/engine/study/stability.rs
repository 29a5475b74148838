//! The stability gate: every compensator of a study analysed at the study's K_BF with its
//! plant (under each of the study's machine conditions, the design made for the plant) and body, an
//! adaptive design at every frozen estimate of its retune range (`adaptive_gate`), on the machine
//! (feedthrough loop closed) and off it, before a person
//! runs it. A study on the real machine whose on-machine design is unstable cannot be
//! locked; a simulated one needs an explicit, audited acknowledgement. The off-machine
//! verdict is also the gate of an identification test's disturbance: the multisine drives
//! the boom through one of the study's designs with no feedthrough (K_BF = 0 for the loop),
//! which is that design's loop off the machine.
//!
//! The analysis reads the one-tick map off the loop that runs (`bdft_controller::analysis`)
//! and can take a second or more, so reports are computed off the async threads, once per distinct set
//! of the parameters it depends on, and kept in a small cache.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use bdft_controller::analysis::robustness::OnRig;
use bdft_controller::analysis::{GATE_POINTS, LinearizedLoop, adaptive_gate};
use bdft_controller::closed_loop::LoopSetup;
use bdft_protocol::params::{
    BodyModel, CompensatorKind, CompensatorSpec, LoopParams, MAX_KBF, MachineCondition,
    PlantParams, Seat,
};
use bdft_protocol::study::{RigKind, StudyParams};
use serde::Serialize;
use tokio::sync::OnceCell;

use crate::error::{AppError, Result};

/// The margin a study's design should keep: stable up to this many times the study's K_BF.
pub const MARGIN: f64 = 1.5;

/// One compensator's verdict.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Verdict {
    #[serde(rename = "controller")]
    pub compensator: CompensatorKind,
    /// In a study with a condition factor, the condition the verdict is on: the design's
    /// least stable (its margin there; stable only if on every condition).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub condition: Option<String>,
    /// Stable on the machine at the study's K_BF (feedthrough closed).
    pub stable_on: bool,
    /// Stable off the machine (no feedthrough).
    pub stable_off: bool,
    /// Largest K_BF with the loop stable on the machine for all smaller K (null: stable up
    /// to the analysis limit of 20).
    pub max_stable_kbf: Option<f64>,
    /// Stable on the machine up to at least `MARGIN` × the study's K_BF.
    pub has_margin: bool,
}

/// Every compensator's verdict for a study's parameters.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct StabilityReport {
    pub k_bf: f64,
    /// The margin asked of each design (× K_BF).
    pub margin: f64,
    pub verdicts: Vec<Verdict>,
}

impl StabilityReport {
    /// The compensators unstable on the machine at the study's K_BF, or off it.
    pub fn unstable(&self) -> Vec<&Verdict> {
        self.verdicts
            .iter()
            .filter(|v| !v.stable_on || !v.stable_off)
            .collect()
    }
}

/// The loop a trial of `spec` in a study of `params` runs (on the machine, at the study's
/// K_BF and the loop's sample period): what the stability gate analyses and the creation
/// checks build.
pub fn study_loop(
    params: &StudyParams,
    spec: &bdft_protocol::params::CompensatorSpec,
) -> LoopSetup {
    LoopSetup {
        plant: params.plant,
        body: params.body,
        loop_params: LoopParams {
            k_bf: params.k_bf,
            ..LoopParams::default()
        },
        seat: Seat::On,
        compensator: spec.clone(),
    }
}

/// A design's verdict on every condition of the study's machine: as stable as on the least
/// stable of them (a study with a condition factor runs it on each).
fn verdict(params: &StudyParams, spec: &CompensatorSpec) -> Result<Verdict> {
    let mut least: Option<Verdict> = None;
    for condition in params.machine_conditions() {
        let v = verdict_on(params, spec, condition)?;
        let kbf = |v: &Verdict| v.max_stable_kbf.unwrap_or(f64::INFINITY);
        least = Some(match least {
            None => v,
            Some(l) => Verdict {
                stable_on: l.stable_on && v.stable_on,
                stable_off: l.stable_off && v.stable_off,
                has_margin: l.has_margin && v.has_margin,
                ..if kbf(&v) < kbf(&l) { v } else { l }
            },
        });
    }
    Ok(least.expect("a study's machine has a condition"))
}

/// A design's verdict on the study's machine under `condition`.
fn verdict_on(
    params: &StudyParams,
    spec: &CompensatorSpec,
    condition: MachineCondition,
) -> Result<Verdict> {
    let setup = study_loop(params, spec);
    let design = |e: bdft_controller::error::DesignError| {
        AppError::BadRequest(format!("{}: the design cannot be built: {e}", spec.kind()))
    };
    let rig = condition
        .apply(&params.plant)
        .map_err(|e| AppError::BadRequest(e.to_string()))?;
    let (stable_on, stable_off, max_stable_kbf) = if spec.adapt().is_some() {
        // An adaptive design may be frozen anywhere in its range by its estimate: the gate
        // judges every ratio of it, and the design is as stable as its least stable ratio.
        let gate = adaptive_gate(&setup, GATE_POINTS, &rig).map_err(design)?;
        let least = gate
            .iter()
            .map(|v| v.max_stable_kbf.unwrap_or(f64::INFINITY))
            .fold(f64::INFINITY, f64::min);
        let nominal = study_loop(params, &spec.frozen_at(1.0));
        (
            gate.iter().all(|v| v.stable),
            OnRig::new(&nominal)
                .and_then(|on| on.is_stable(rig, 0.0))
                .map_err(design)?,
            least.is_finite().then_some(least),
        )
    } else if condition.is_default() {
        let lin = LinearizedLoop::new(&setup).map_err(design)?;
        (
            lin.is_stable(params.k_bf).map_err(design)?,
            lin.is_stable(0.0).map_err(design)?,
            lin.margin(&setup).map_err(design)?,
        )
    } else {
        // The design made for the study's rig, judged on the machine under its condition.
        let on = OnRig::new(&setup).map_err(design)?;
        (
            on.is_stable(rig, params.k_bf).map_err(design)?,
            on.is_stable(rig, 0.0).map_err(design)?,
            on.max_stable_kbf(rig, MAX_KBF).map_err(design)?,
        )
    };
    Ok(Verdict {
        compensator: spec.kind(),
        condition: (params.machine_conditions().len() > 1).then(|| condition.to_string()),
        stable_on,
        stable_off,
        has_margin: max_stable_kbf.is_none_or(|k| k >= MARGIN * params.k_bf),
        max_stable_kbf,
    })
}

/// Analyses every compensator, one thread each (they are independent, and each takes
/// eigenvalues of up to a few hundred states many times over).
fn analyse(params: &StudyParams) -> Result<StabilityReport> {
    let verdicts = std::thread::scope(|s| {
        let handles: Vec<_> = params
            .compensators
            .iter()
            .map(|spec| s.spawn(move || verdict(params, spec)))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join().unwrap_or_else(|_| {
                    Err(AppError::Internal(anyhow::anyhow!("the analysis panicked")))
                })
            })
            .collect::<Result<Vec<_>>>()
    })?;
    Ok(StabilityReport {
        k_bf: params.k_bf,
        margin: MARGIN,
        verdicts,
    })
}

/// What an analysis of a study's loops depends on: its plant, body and designs at `k_bf`.
#[derive(Serialize)]
struct AnalysisInput<'a> {
    plant: &'a PlantParams,
    #[serde(skip_serializing_if = "MachineCondition::is_default")]
    condition: MachineCondition,
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    conditions: &'a [MachineCondition],
    body: &'a BodyModel,
    k_bf: f64,
    controllers: &'a [CompensatorSpec],
}

/// What an analysis of the study's loops at `k_bf` depends on, as a cache key (the gate's
/// here, the workbench's frequency reports').
pub fn analysis_key(params: &StudyParams, k_bf: f64) -> String {
    serde_json::to_string(&AnalysisInput {
        plant: &params.plant,
        condition: params.condition,
        conditions: &params.conditions,
        body: &params.body,
        k_bf,
        controllers: &params.compensators,
    })
    .expect("study parameters serialize")
}

/// A report once computed (or the reason it could not be), shared by everyone who waits.
type Slot = Arc<OnceCell<std::result::Result<StabilityReport, String>>>;

/// Reports already computed (or being computed), by the parameters they depend on.
#[derive(Debug, Default)]
pub struct StabilityCache {
    reports: Mutex<HashMap<String, Slot>>,
}

/// Distinct parameter sets kept; a lab has a handful of studies.
const CACHE_ENTRIES: usize = 64;

impl StabilityCache {
    fn cell(&self, key: String) -> Slot {
        let mut reports = self.reports.lock().unwrap_or_else(|p| p.into_inner());
        if reports.len() >= CACHE_ENTRIES && !reports.contains_key(&key) {
            reports.clear();
        }
        reports.entry(key).or_default().clone()
    }

    /// The report for `params`, computed once.
    pub async fn report(&self, params: &StudyParams) -> Result<StabilityReport> {
        let cell = self.cell(analysis_key(params, params.k_bf));
        let params = params.clone();
        let r = cell
            .get_or_init(|| async move {
                match tokio::task::spawn_blocking(move || analyse(&params)).await {
                    Ok(r) => r.map_err(|e| e.to_string()),
                    Err(e) => Err(format!("the analysis failed: {e}")),
                }
            })
            .await;
        r.clone().map_err(AppError::BadRequest)
    }

    /// Starts computing the report for `params` in the background (a study was created or
    /// edited: its page will ask).
    pub fn prefetch(self: &Arc<Self>, params: &StudyParams) {
        let (cache, params) = (Arc::clone(self), params.clone());
        tokio::spawn(async move {
            let _ = cache.report(&params).await;
        });
    }
}

/// Whether a study may be locked (its first subject enrolled): every design stable on and
/// off the machine — or, for a simulated study, the instability acknowledged.
pub fn check_lockable(
    params: &StudyParams,
    report: &StabilityReport,
    acknowledged: bool,
) -> Result<()> {
    let unstable = report.unstable();
    if unstable.is_empty() {
        return Ok(());
    }
    let names: Vec<String> = unstable
        .iter()
        .map(|v| {
            let limit = v.max_stable_kbf.map_or("no limit".into(), |k| {
                format!("stable only up to K_BF {k:.2}")
            });
            format!("{} ({limit})", v.compensator)
        })
        .collect();
    let what = format!(
        "unstable at the study's K_BF {}: {}",
        params.k_bf,
        names.join(", ")
    );
    match params.rig {
        RigKind::Real => Err(AppError::Conflict(format!(
            "the study runs on the real machine and a design is {what}; change the design or K_BF before anyone sits on it"
        ))),
        RigKind::Simulated if acknowledged => Ok(()),
        RigKind::Simulated => Err(AppError::Conflict(format!(
            "a design is {what}; acknowledge it on the study page (POST /api/studies/{{id}}/acknowledge-instability) to run it in simulation"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::study::schedule::default_params;

    #[test]
    fn the_default_study_passes_the_gate_with_margin_and_ziegler_nichols_does_not() {
        let params = default_params();
        let report = analyse(&params).unwrap();
        assert_eq!(report.verdicts.len(), 5);
        for v in &report.verdicts {
            assert!(v.stable_on && v.stable_off && v.has_margin, "{v:?}");
        }
        check_lockable(&params, &report, false).unwrap();
        // The bench tuning on the machine at 0.78: the analysis of the original designs
        // says plain PID is stable only up to K_BF 0.35 (docs/system-model.md §6).
        let mut bench = params.clone();
        bench.compensators = CompensatorKind::STUDY
            .iter()
            .map(|&k| bdft_controller::compensator::default_spec(k, &bench.plant))
            .collect();
        let report = analyse(&bench).unwrap();
        let pid = &report.verdicts[0];
        assert_eq!(pid.compensator, CompensatorKind::Pid);
        assert!(!pid.stable_on && pid.stable_off, "{pid:?}");
        assert!((pid.max_stable_kbf.unwrap() - 0.35).abs() < 0.01, "{pid:?}");
        assert!(check_lockable(&bench, &report, false).is_err());
        assert!(
            check_lockable(&bench, &report, true).is_ok(),
            "simulated, acknowledged"
        );
        bench.rig = RigKind::Real;
        let refused = check_lockable(&bench, &report, true)
            .unwrap_err()
            .to_string();
        assert!(
            refused.contains("real machine") && refused.contains("pid"),
            "{refused}"
        );
    }
}
