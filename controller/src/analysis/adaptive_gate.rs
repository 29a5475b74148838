//! The stability gate of an adaptive design: the design frozen at every mode-frequency
//! ratio r of a grid over its range, each closed through the feedthrough on the setup's
//! plant and body, as the analysis judges a fixed design. An estimate anywhere in the range
//! — right or wrong — then leaves a loop whose stability was checked before the trial.

use serde::{Deserialize, Serialize};

use super::robustness::OnRig;
use crate::closed_loop::LoopSetup;
use crate::error::{DesignError, ParamError};
use crate::params::{MAX_KBF, PlantParams, check};

/// The gate's grid: seven ratios (the scheduled LQR's own designs), r = 1 among them.
pub const GATE_POINTS: usize = 7;

/// The design frozen at one ratio.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrozenVerdict {
    /// Mode-frequency ratio r the design is frozen at.
    pub ratio: f64,
    /// Stable for every K_BF in [0, the setup's K_BF].
    pub stable: bool,
    /// Largest K_BF with the loop stable on all of [0, K]; `null` = up to MAX_KBF (as
    /// `CompensatorAnalysis::max_stable_kbf`).
    pub max_stable_kbf: Option<f64>,
}

/// The ratios the gate judges: `points` (odd) over the retune range [lo, hi] ∋ 1, r = 1
/// among them — half evenly each side of 1 when the range spans both, all evenly over it
/// when one end is 1 (a design not retuned upward: [1 − range, 1]).
pub fn gate_ratios((lo, hi): (f64, f64), points: usize) -> Vec<f64> {
    let half = (points - 1) / 2;
    if lo < 1.0 && hi > 1.0 {
        (0..points)
            .map(|i| match i.cmp(&half) {
                std::cmp::Ordering::Less => 1.0 - (1.0 - lo) * (half - i) as f64 / half as f64,
                std::cmp::Ordering::Equal => 1.0,
                std::cmp::Ordering::Greater => 1.0 + (hi - 1.0) * (i - half) as f64 / half as f64,
            })
            .collect()
    } else {
        (0..points)
            .map(|i| lo + (hi - lo) * i as f64 / (points - 1) as f64)
            .collect()
    }
}

/// The verdicts of `setup.compensator` (an adaptive design, made for `setup.plant`) frozen
/// at `points` ratios over the range it is retuned to (`CompensatorSpec::retune_bounds`;
/// `gate_ratios`: at least `GATE_POINTS`, odd so that r = 1 is one of them), on `rig` (the setup's plant, or the machine under a condition) at the
/// setup's K_BF. The margin is `OnRig`'s: the Nyquist crossings for the shaper, the sampled
/// loop's eigenvalues otherwise, as `analyze`'s.
pub fn adaptive_gate(
    setup: &LoopSetup,
    points: usize,
    rig: &PlantParams,
) -> Result<Vec<FrozenVerdict>, DesignError> {
    let k_bf = setup.loop_params.k_bf;
    check("kbf", k_bf, 0.0, MAX_KBF)?;
    let Some(adapt) = setup.compensator.adapt() else {
        return Err(ParamError::Invalid {
            name: "compensator",
            message: format!(
                "{} is not adaptive; the gate judges an adaptive design's range",
                setup.compensator.kind()
            ),
        }
        .into());
    };
    if points < GATE_POINTS || points % 2 == 0 {
        return Err(ParamError::Invalid {
            name: "points",
            message: format!("{points} ratios; an odd number of at least {GATE_POINTS}"),
        }
        .into());
    }
    let bounds = adapt.retune_bounds(setup.compensator.kind());
    gate_ratios(bounds, points)
        .into_iter()
        .map(|ratio| {
            let frozen = LoopSetup {
                compensator: setup.compensator.frozen_at(ratio),
                ..setup.clone()
            };
            let max_stable_kbf = OnRig::new(&frozen)?.max_stable_kbf(*rig, MAX_KBF)?;
            Ok(FrozenVerdict {
                ratio,
                stable: max_stable_kbf.is_none_or(|m| m > k_bf),
                max_stable_kbf,
            })
        })
        .collect()
}
