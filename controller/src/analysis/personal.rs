//! A design tuned to one person: the LQR family's single free weight chosen so that the loop
//! closed through *this person's* body keeps the margin a study asks of its designs.
//!
//! The study's designs are checked against one assumed body; people's feedthrough differs
//! several-fold, so a design with a comfortable margin for the assumed body can have none
//! for a strongly coupled person, and one that is needlessly cautious for a loosely coupled
//! one. Each LQR design has one weight that trades tracking against that margin:
//!
//! - without cab feedback, the tracking weight α: a larger α tracks tighter and feeds more
//!   of the hand's motion back (margin falls as α grows); the largest α keeping the margin
//!   is the person's design;
//! - with cab feedback (velocity or acceleration), the damping weight β: a larger β damps
//!   the cab harder at the cost of a shakier cylinder (margin grows with β); the smallest β
//!   keeping the margin is the person's design.
//!
//! The weight stays within a band around the study's own (`ALPHA_RANGE`, `BETA_MAX`): a
//! design far from the one the study's gate and bench checked is a new design, not a
//! personalization. The margin is the one the gate reads (`LinearizedLoop::margin`), and the
//! tuned loop must also be stable off the machine.

use bdft_protocol::params::{CompensatorKind, CompensatorSpec, LqrParams};
use serde::{Deserialize, Serialize};

use super::LinearizedLoop;
use crate::closed_loop::LoopSetup;
use crate::error::DesignError;

/// The tracking weight α may range over this band of multiples of the study's α.
pub const ALPHA_RANGE: (f64, f64) = (1.0 / 16.0, 2.0);
/// The damping weight β may range from 0 to the larger of this and 4 × the study's β.
pub const BETA_MAX: f64 = 8.0;
/// Bisection stops when the bracket is this narrow (relative to the weight's range).
const TOLERANCE: f64 = 0.005;

/// Which weight of Λ = diag(α, β) a design is tuned by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Weight {
    Alpha,
    Beta,
}

/// One of a study's designs tuned to one person's body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PersonalDesign {
    /// The compensator (its key in the stored JSON: `controller`).
    #[serde(rename = "controller")]
    pub compensator: CompensatorKind,
    pub weight: Weight,
    /// The weight in the study's design.
    pub generic: f64,
    /// The weight tuned to the person; none when no value in the allowed band keeps the
    /// margin (the person then runs the study's design, and `reason` says why).
    pub value: Option<f64>,
    /// The largest K_BF the loop with the person's body is stable up to (null: up to the
    /// analysis limit): of the tuned design, or of the study's when none could be tuned.
    pub max_stable_kbf: Option<f64>,
    /// The tuned design, ready to run.
    pub spec: Option<CompensatorSpec>,
    pub reason: Option<String>,
}

/// The person's design of `setup.compensator` (the study's, with `setup.body` the person's
/// and `setup.loop_params.k_bf` the study's K_BF) that is stable up to `required_kbf`; none
/// for a design that is not of the LQR family.
pub fn personalize(
    setup: &LoopSetup,
    required_kbf: f64,
) -> Result<Option<PersonalDesign>, DesignError> {
    let Some((weight, lqr)) = tuning_weight(&setup.compensator) else {
        return Ok(None);
    };
    let generic = weight.of(lqr);
    let with = |w: f64| {
        let mut tuned = *lqr;
        match weight {
            Weight::Alpha => tuned.alpha = w,
            Weight::Beta => tuned.beta = w,
        }
        respec(&setup.compensator, tuned)
    };
    let margin_of = |w: f64| -> Result<Option<f64>, DesignError> {
        let trial = LoopSetup {
            compensator: with(w),
            ..setup.clone()
        };
        LinearizedLoop::new(&trial)?.margin(&trial)
    };
    let holds = |m: Option<f64>| m.is_none_or(|k| k >= required_kbf);

    // The cautious end of the band, and the end that gives the most (tightest tracking, or
    // least cylinder shake): margin is monotone between them in every loop we have.
    let (cautious, bold) = match weight {
        Weight::Alpha => (generic * ALPHA_RANGE.0, generic * ALPHA_RANGE.1),
        Weight::Beta => (BETA_MAX.max(4.0 * generic), 0.0),
    };
    let cautious_margin = margin_of(cautious)?;
    if !holds(cautious_margin) {
        return Ok(Some(PersonalDesign {
            max_stable_kbf: margin_of(generic)?,
            ..PersonalDesign::refused(
                &setup.compensator,
                format!(
                    "even {} = {cautious:.3}, the most cautious allowed, is stable only up to K_BF = {:.3} for this body, below the {required_kbf:.3} required",
                    weight.name(),
                    cautious_margin.unwrap_or(f64::INFINITY)
                ),
            )
        }));
    }
    let (mut safe, mut unsafe_) = (cautious, bold);
    let mut margin = cautious_margin;
    let bold_margin = margin_of(bold)?;
    if holds(bold_margin) {
        safe = bold;
        margin = bold_margin;
    } else {
        let span = (cautious - bold).abs();
        while (safe - unsafe_).abs() > TOLERANCE * span {
            // α spans a factor of 32: halve it geometrically; β from 0: arithmetically.
            let mid = match weight {
                Weight::Alpha => (safe * unsafe_).sqrt(),
                Weight::Beta => 0.5 * (safe + unsafe_),
            };
            let m = margin_of(mid)?;
            if holds(m) {
                (safe, margin) = (mid, m);
            } else {
                unsafe_ = mid;
            }
        }
    }
    let spec = with(safe);
    let off = LoopSetup {
        compensator: spec.clone(),
        ..setup.clone()
    };
    if !LinearizedLoop::new(&off)?.is_stable(0.0)? {
        return Ok(Some(PersonalDesign {
            max_stable_kbf: margin_of(generic)?,
            ..PersonalDesign::refused(
                &setup.compensator,
                format!(
                    "{} = {safe:.3} keeps the margin but is unstable off the machine",
                    weight.name()
                ),
            )
        }));
    }
    Ok(Some(PersonalDesign {
        compensator: setup.compensator.kind(),
        weight,
        generic,
        value: Some(safe),
        max_stable_kbf: margin,
        spec: Some(spec),
        reason: None,
    }))
}

impl PersonalDesign {
    /// No design of `spec`'s kind for this person, for `reason`: they run the study's.
    /// (`max_stable_kbf` is left unknown.)
    pub fn refused(spec: &CompensatorSpec, reason: String) -> Self {
        let (weight, generic) = tuning_weight(spec)
            .map(|(w, lqr)| (w, w.of(lqr)))
            .unwrap_or((Weight::Alpha, f64::NAN));
        Self {
            compensator: spec.kind(),
            weight,
            generic,
            value: None,
            max_stable_kbf: None,
            spec: None,
            reason: Some(reason),
        }
    }
}

/// The weight `spec` is tuned by, and its LQR parameters; none for a design that is not of
/// the LQR family.
fn tuning_weight(spec: &CompensatorSpec) -> Option<(Weight, &LqrParams)> {
    match spec {
        CompensatorSpec::Lqr { lqr } => Some((Weight::Alpha, lqr)),
        CompensatorSpec::LqrCabvel { lqr } | CompensatorSpec::LqrCabacc { lqr } => {
            Some((Weight::Beta, lqr))
        }
        _ => None,
    }
}

impl Weight {
    pub fn name(self) -> &'static str {
        match self {
            Self::Alpha => "alpha",
            Self::Beta => "beta",
        }
    }

    fn of(self, lqr: &LqrParams) -> f64 {
        match self {
            Self::Alpha => lqr.alpha,
            Self::Beta => lqr.beta,
        }
    }
}

/// `spec` with its LQR weights replaced by `lqr`'s.
fn respec(spec: &CompensatorSpec, lqr: LqrParams) -> CompensatorSpec {
    match spec {
        CompensatorSpec::Lqr { .. } => CompensatorSpec::Lqr { lqr },
        CompensatorSpec::LqrCabvel { .. } => CompensatorSpec::LqrCabvel { lqr },
        CompensatorSpec::LqrCabacc { .. } => CompensatorSpec::LqrCabacc { lqr },
        other => other.clone(),
    }
}

#[cfg(test)]
mod tests {
    use bdft_protocol::params::{BodyModel, LoopParams, PlantParams, Seat};

    use super::*;
    use crate::compensator::study_spec;

    fn setup(kind: CompensatorKind, body: BodyModel, k_bf: f64) -> LoopSetup {
        let plant = PlantParams::default();
        LoopSetup {
            plant,
            body,
            loop_params: LoopParams {
                k_bf,
                ..LoopParams::default()
            },
            seat: Seat::On,
            compensator: study_spec(kind, &plant),
        }
    }

    fn rigid(k_h: f64) -> BodyModel {
        BodyModel::RigidMass { k_h }
    }

    fn seated(k_h: f64) -> BodyModel {
        BodyModel::Seated {
            k_h,
            torso_f_hz: 4.0,
            torso_zeta: 0.4,
            arm_f_hz: 6.0,
            arm_zeta: 0.3,
        }
    }

    fn tuned(kind: CompensatorKind, body: BodyModel, required: f64) -> PersonalDesign {
        personalize(&setup(kind, body, 0.78), required)
            .unwrap()
            .expect("an LQR design")
    }

    fn margin(kind: CompensatorKind, body: BodyModel, w: f64) -> Option<f64> {
        let mut s = setup(kind, body, 0.78);
        s.compensator = match s.compensator {
            CompensatorSpec::Lqr { mut lqr } => {
                lqr.alpha = w;
                CompensatorSpec::Lqr { lqr }
            }
            CompensatorSpec::LqrCabvel { mut lqr } => {
                lqr.beta = w;
                CompensatorSpec::LqrCabvel { lqr }
            }
            other => panic!("not tuned here: {other:?}"),
        };
        LinearizedLoop::new(&s).unwrap().margin(&s).unwrap()
    }

    #[test]
    fn only_the_lqr_family_is_tuned() {
        for kind in [
            CompensatorKind::Pid,
            CompensatorKind::PidNotch,
            CompensatorKind::PidShaper,
        ] {
            assert_eq!(
                personalize(&setup(kind, rigid(0.56), 0.78), 1.17).unwrap(),
                None
            );
        }
    }

    #[test]
    fn the_tuned_weight_keeps_the_margin_and_a_bolder_one_does_not() {
        let required = 1.5 * 0.78;
        for (kind, body) in [
            (CompensatorKind::Lqr, seated(0.2)),
            (CompensatorKind::Lqr, rigid(0.56)),
            (CompensatorKind::LqrCabvel, seated(0.56)),
        ] {
            let d = tuned(kind, body, required);
            let w = d.value.expect("tunable");
            assert!(d.max_stable_kbf.is_none_or(|k| k >= required), "{d:?}");
            assert_eq!(margin(kind, body, w), d.max_stable_kbf);
            // One step bolder (beyond the bisection's tolerance) loses the margin.
            let bolder = match d.weight {
                Weight::Alpha => w * 1.03,
                Weight::Beta => w - 0.03 * BETA_MAX,
            };
            assert!(
                margin(kind, body, bolder).is_some_and(|k| k < required),
                "{kind:?} {body:?}: {bolder} still keeps the margin"
            );
        }
    }

    /// With a rigid-mass body the feedthrough is h = k_h·x_c and the valve reads
    /// K_BF·(p_h − h): the loop depends on K_BF·k_h alone, so the largest stable K_BF scales
    /// as 1/k_h and the design tuned for (k_h, K) is the one tuned for (2·k_h, K/2).
    #[test]
    fn a_rigid_body_twice_as_coupled_gets_the_design_of_half_the_margin() {
        for kind in [CompensatorKind::Lqr, CompensatorKind::LqrCabvel] {
            let a = tuned(kind, rigid(0.56), 1.17).value.unwrap();
            let b = tuned(kind, rigid(1.12), 0.585).value.unwrap();
            let scale = match kind {
                CompensatorKind::Lqr => a,
                _ => BETA_MAX,
            };
            assert!(
                (a - b).abs() <= 2.0 * TOLERANCE * scale,
                "{kind:?}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn a_more_coupled_person_gets_a_more_cautious_design() {
        let alpha = |k_h| {
            tuned(CompensatorKind::Lqr, seated(k_h), 1.17)
                .value
                .unwrap()
        };
        let beta = |k_h| {
            tuned(CompensatorKind::LqrCabvel, seated(k_h), 1.17)
                .value
                .unwrap()
        };
        assert!(alpha(0.1) > alpha(0.2), "{} vs {}", alpha(0.1), alpha(0.2));
        assert!(beta(0.3) < beta(0.56), "{} vs {}", beta(0.3), beta(0.56));
        // Loosely coupled: the study's damping is more than this person needs.
        assert!(beta(0.2) < 2.0, "{}", beta(0.2));
    }

    #[test]
    fn a_body_no_allowed_design_holds_is_refused_with_the_reason() {
        let d = tuned(CompensatorKind::Lqr, seated(3.0), 1.17);
        assert_eq!((d.value, &d.spec), (None, &None));
        let reason = d.reason.unwrap();
        assert!(reason.contains("alpha = 2.500"), "{reason}");
        assert!(d.max_stable_kbf.is_some_and(|k| k < 1.17));
    }
}
