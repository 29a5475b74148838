//! The workbench's table of machine conditions (`docs/machine-conditions.md`): each design,
//! made for the study's rig, run on the rig under each condition — its bench cab-acceleration
//! reduction against its uncompensated twin on the same machine, and its stability margin
//! with the body closed through the feedthrough.
//!
//! Why both: a compensator that keeps its reduction but loses its margin shakes a person
//! on a machine that is no longer stable with them; one that keeps its margin but loses its
//! reduction is a PID with a delay. The bench run has no operator (the signal drives the
//! cylinder reference, as on the rig); the margin is the largest stable K_BF with the study's
//! body, on the condition's rig linearized (`analysis::robustness::OnRig`); an adaptive
//! design's margin is its design frozen at the rig's true mode ratio, where its estimate
//! converges (its bench run adapts as it runs).

use serde::Serialize;

use crate::analysis::robustness::OnRig;
use crate::closed_loop::LoopSetup;
use crate::compensator::{CompensatorKind, CompensatorSpec, default_spec};
use crate::error::DesignError;
use crate::operator::OperatorParams;
use crate::params::{MAX_KBF, MachineCondition, Seat};
use crate::signals::StepParams;
use crate::simulate::{SignalKind, SimConfig, simulate};

/// The uncompensated design a compensator's reduction is measured against (here and in the
/// server's bench runs): the PID for the prefilters, fixed or adaptive; the LQR without cab
/// feedback for the cab-feedback designs, fixed or scheduled; none for those two.
pub fn twin(kind: CompensatorKind) -> Option<CompensatorKind> {
    match kind {
        CompensatorKind::Pid | CompensatorKind::Lqr => None,
        CompensatorKind::PidNotch
        | CompensatorKind::PidShaper
        | CompensatorKind::PidNotchAdaptive
        | CompensatorKind::PidShaperAdaptive => Some(CompensatorKind::Pid),
        CompensatorKind::LqrCabvel
        | CompensatorKind::LqrCabacc
        | CompensatorKind::LqrCabvelScheduled => Some(CompensatorKind::Lqr),
    }
}

/// One design on one condition.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConditionRow {
    pub condition: String,
    pub design: String,
    /// First structure mode of the condition's rig (Hz), and the rule's relative
    /// uncertainty on it.
    pub f1_hz: f64,
    pub f1_uncertainty: f64,
    /// Mean-squared cab acceleration of the structure in the bench run ((mm/s²)²): the
    /// measured less the noise floor.
    pub ms_cab_accel: f64,
    /// 100 · (1 − RMS / twin's RMS) on the same condition, in %; none without a twin.
    pub cab_accel_reduction_pct: Option<f64>,
    /// Largest stable K_BF with the body on this rig; `None` = stable up to `MAX_KBF`.
    pub max_stable_kbf: Option<f64>,
    /// Stable at the study's K_BF.
    pub stable: bool,
}

/// The table and how it was made.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConditionTable {
    pub signal: &'static str,
    pub duration_s: f64,
    pub seed: u64,
    pub k_bf: f64,
    pub rows: Vec<ConditionRow>,
}

/// Every design of `designs` (name, spec made for `base.plant`) on every condition.
/// `base` gives the design rig, the body and the study's K_BF; its compensator is ignored.
pub fn condition_table(
    designs: &[(String, CompensatorSpec)],
    conditions: &[MachineCondition],
    base: &LoopSetup,
    seed: u64,
) -> Result<ConditionTable, DesignError> {
    let duration_s = SignalKind::SweptSine.default_duration_s();
    let bench = |spec: &CompensatorSpec, condition: MachineCondition| {
        let cfg = SimConfig {
            setup: LoopSetup {
                seat: Seat::Off,
                compensator: spec.clone(),
                ..base.clone()
            },
            signal: SignalKind::SweptSine,
            duration_s,
            seed,
            operator: OperatorParams::default(),
            steps: StepParams::default(),
            max_cab_rms_mm_s2: None,
            condition,
        };
        let floor = {
            let rig = condition.apply(&base.plant)?;
            rig.accel_noise_std.powi(2) + rig.engine_vibration_rms.powi(2)
        };
        simulate(&cfg, |_| {}).map(|s| (s.ms_cab_accel - floor).max(0.0))
    };
    let k_bf = base.loop_params.k_bf;
    let mut rows = Vec::with_capacity(designs.len() * conditions.len());
    let judged = |spec: &CompensatorSpec| {
        OnRig::new(&LoopSetup {
            seat: Seat::On,
            compensator: spec.clone(),
            ..base.clone()
        })
    };
    for (name, spec) in designs {
        let fixed = judged(spec)?;
        let twin = twin(spec.kind()).map(|k| default_spec(k, &base.plant));
        for &condition in conditions {
            let rig = condition.apply(&base.plant)?;
            let ms = bench(spec, condition)?;
            let reduction = match &twin {
                Some(t) => Some(100.0 * (1.0 - (ms / bench(t, condition)?).sqrt())),
                None => None,
            };
            // An adaptive design is judged as it converges: frozen at the rig's true ratio
            // (clamped to the range it is retuned to), beside its fixed design's row.
            let max_stable_kbf = match spec.retune_bounds() {
                Some((lo, hi)) => {
                    let ratio = (rig.f1_hz / base.plant.f1_hz).clamp(lo, hi);
                    judged(&spec.frozen_at(ratio))?.max_stable_kbf(rig, MAX_KBF)?
                }
                None => fixed.max_stable_kbf(rig, MAX_KBF)?,
            };
            rows.push(ConditionRow {
                condition: condition.to_string(),
                design: name.clone(),
                f1_hz: rig.f1_hz,
                f1_uncertainty: condition.uncertainty(),
                ms_cab_accel: ms,
                cab_accel_reduction_pct: reduction,
                max_stable_kbf,
                stable: max_stable_kbf.is_none_or(|m| m > k_bf),
            });
        }
    }
    Ok(ConditionTable {
        signal: SignalKind::SweptSine.name(),
        duration_s,
        seed,
        k_bf,
        rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{BodyModel, LoopParams, PlantParams};

    fn base() -> LoopSetup {
        let plant = PlantParams::default();
        LoopSetup {
            plant,
            body: BodyModel::default(),
            loop_params: LoopParams {
                dt: 1e-3,
                k_bf: 0.78,
            },
            seat: Seat::On,
            compensator: default_spec(CompensatorKind::Pid, &plant),
        }
    }

    #[test]
    fn every_compensated_design_has_its_uncompensated_twin() {
        use CompensatorKind::*;
        assert_eq!(twin(PidNotch), Some(Pid));
        assert_eq!(twin(PidShaper), Some(Pid));
        assert_eq!(twin(LqrCabvel), Some(Lqr));
        assert_eq!(twin(LqrCabacc), Some(Lqr));
        assert_eq!(twin(PidNotchAdaptive), Some(Pid));
        assert_eq!(twin(PidShaperAdaptive), Some(Pid));
        assert_eq!(twin(LqrCabvelScheduled), Some(Lqr));
        assert_eq!(twin(Pid), None);
        assert_eq!(twin(Lqr), None);
    }

    #[test]
    fn the_thesiss_rig_row_is_the_bench_and_the_analysis_of_today() {
        let base = base();
        let designs: Vec<_> = [CompensatorKind::PidNotch, CompensatorKind::LqrCabvel]
            .into_iter()
            .map(|k| (k.name().to_string(), default_spec(k, &base.plant)))
            .collect();
        let t = condition_table(&designs, &[MachineCondition::STILTS], &base, 1).unwrap();
        for (row, (_, spec)) in t.rows.iter().zip(&designs) {
            // The margin is `analyze`'s on the design's own rig.
            let setup = LoopSetup {
                compensator: spec.clone(),
                ..base.clone()
            };
            let a = crate::analysis::analyze(&setup).unwrap();
            match (row.max_stable_kbf, a.max_stable_kbf) {
                (Some(m), Some(want)) => assert!((m - want).abs() < 1e-4, "{m} vs {want}"),
                (got, want) => assert_eq!(got, want, "{}", row.design),
            }
            assert_eq!(row.stable, a.stable, "{}", row.design);
            // Both designs cut the bench vibration of their twin on the rig they were made for.
            assert!(row.cab_accel_reduction_pct.unwrap() > 20.0, "{row:?}");
        }
    }

    #[test]
    fn on_tires_the_fixed_notch_loses_reduction_and_the_first_mode_falls() {
        let base = base();
        let notch = vec![(
            "pid-notch".to_string(),
            default_spec(CompensatorKind::PidNotch, &base.plant),
        )];
        let tires: MachineCondition = "tires".parse().unwrap();
        let t = condition_table(&notch, &[MachineCondition::STILTS, tires], &base, 1).unwrap();
        let (home, field) = (&t.rows[0], &t.rows[1]);
        assert!((field.f1_hz - 0.75 * home.f1_hz).abs() < 1e-9);
        assert!(
            field.cab_accel_reduction_pct.unwrap() < home.cab_accel_reduction_pct.unwrap(),
            "{home:?} {field:?}"
        );
    }

    /// The claim on the structure's vibration, both ways: with the modes 30 % low and
    /// 30 % high, each adaptive design keeps at least 80 % of its fixed design's reduction on
    /// the rig it was made for, and its margin there is at least the fixed design's. Low, it
    /// also reduces more than the fixed design keeps; high, the notch and the shaper run their
    /// fixed design (not retuned upward) and the scheduled LQR reduces more.
    /// Measured (reduction · max K_BF, fixed → adaptive): ×0.7 notch 50.5 % · 0.343 → 64.7 % ·
    /// 0.522, shaper 75.3 % · 0.969 → 90.9 % · 3.751, LQR 23.6 % · 1.158 → 46.1 % · 1.458; ×1.3
    /// notch 65.6 % · 2.899 → the same, shaper 85.4 % · 5.005 → the same, LQR 24.8 % · 4.958 →
    /// 50.5 % · 5.519 (nominal 61.5 %, 90.3 %, 41.3 %).
    #[test]
    fn with_the_modes_low_or_high_the_adaptive_designs_keep_their_reduction() {
        let base = base();
        let moved: [MachineCondition; 2] = ["modes:0.7", "modes:1.3"].map(|c| c.parse().unwrap());
        for (fixed, adaptive) in [
            (CompensatorKind::PidNotch, CompensatorKind::PidNotchAdaptive),
            (
                CompensatorKind::PidShaper,
                CompensatorKind::PidShaperAdaptive,
            ),
            (
                CompensatorKind::LqrCabvel,
                CompensatorKind::LqrCabvelScheduled,
            ),
        ] {
            let designs: Vec<_> = [fixed, adaptive]
                .into_iter()
                .map(|k| (k.name().to_string(), default_spec(k, &base.plant)))
                .collect();
            let conditions = [MachineCondition::STILTS, moved[0], moved[1]];
            let t = condition_table(&designs, &conditions, &base, 1).unwrap();
            // Rows: the fixed design on stilts, ×0.7, ×1.3, then the adaptive one.
            let r = |i: usize| t.rows[i].cab_accel_reduction_pct.unwrap();
            let m = |i: usize| t.rows[i].max_stable_kbf.unwrap_or(f64::INFINITY);
            let nominal = r(0);
            for (i, condition) in moved.iter().enumerate() {
                let (f, a) = (1 + i, 4 + i);
                assert!(
                    r(a) >= 0.8 * nominal,
                    "{adaptive} on {condition}: {} vs nominal {nominal}",
                    r(a)
                );
                assert!(
                    m(a) >= m(f),
                    "{adaptive} on {condition}: margin {} vs fixed {}",
                    m(a),
                    m(f)
                );
            }
            assert!(r(4) > r(1), "{adaptive} low: {} vs fixed {}", r(4), r(1));
            assert!(
                r(5) >= r(2) - 0.5,
                "{adaptive} high: {} vs fixed {}",
                r(5),
                r(2)
            );
        }
    }
}
