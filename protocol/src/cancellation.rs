//! Model-based cancellation of feedthrough (issue 38): the model a test cancels with, as
//! `StartTrial::cancellation` carries it. The controller runs it (`bdft_controller::
//! cancellation`): the device's reading less the body's predicted feedthrough,
//! u = device − Ĥ(z)·a_cab, Ĥ = −k_h·g·N/(D_t·D_a) with a phase lag φ at f_ref
//! (`docs/cancellation.md`).

use serde::{Deserialize, Serialize};

use crate::params::{BodyModel, ParamError, check};

/// The body a test's cancellation predicts, and how wrong it is made on purpose (the
/// robustness arm): the seated body's five parameters as the identification fits them, a
/// gain factor and a phase lag at a frequency, and the guard's bound on the output.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct CancellationModel {
    pub k_h: f64,
    pub torso_f_hz: f64,
    pub torso_zeta: f64,
    pub arm_f_hz: f64,
    pub arm_zeta: f64,
    /// The model's gain over the body's (1: none added).
    #[serde(default = "one")]
    pub gain: f64,
    /// A phase lag added at `phase_ref_hz` (degrees, 0 to 170; 0: none).
    #[serde(default)]
    pub phase_lag_deg: f64,
    #[serde(default = "two")]
    pub phase_ref_hz: f64,
    /// The guard: an output past this (mm of device travel) turns cancellation off for the
    /// rest of the test.
    #[serde(default = "default_limit")]
    pub limit_mm: f64,
}

fn one() -> f64 {
    1.0
}

fn two() -> f64 {
    2.0
}

/// Twice the device's largest travel a person commands in the study (±40 mm targets at
/// K_BF 0.78 ≈ 51 mm of device): a prediction past it is no body's.
pub const DEFAULT_LIMIT_MM: f64 = 100.0;

fn default_limit() -> f64 {
    DEFAULT_LIMIT_MM
}

impl CancellationModel {
    /// The model of a seated body, neither gain nor phase added, the default guard (None:
    /// another kind of body, which the identification does not fit).
    pub fn of_seated(body: &BodyModel) -> Option<Self> {
        match *body {
            BodyModel::Seated {
                k_h,
                torso_f_hz,
                torso_zeta,
                arm_f_hz,
                arm_zeta,
            } => Some(Self {
                k_h,
                torso_f_hz,
                torso_zeta,
                arm_f_hz,
                arm_zeta,
                gain: 1.0,
                phase_lag_deg: 0.0,
                phase_ref_hz: 2.0,
                limit_mm: DEFAULT_LIMIT_MM,
            }),
            _ => None,
        }
    }

    /// The seated body the model predicts (its gain and phase error aside).
    pub fn body(&self) -> BodyModel {
        BodyModel::Seated {
            k_h: self.k_h,
            torso_f_hz: self.torso_f_hz,
            torso_zeta: self.torso_zeta,
            arm_f_hz: self.arm_f_hz,
            arm_zeta: self.arm_zeta,
        }
    }

    /// Each field in its range, or the first that is not, named with its range. The
    /// resonances' and dampings' ranges are the identification's plausible box.
    pub fn validate(&self) -> Result<(), ParamError> {
        check("cancellation.k_h", self.k_h, 0.0, 10.0)?;
        check("cancellation.torso_f_hz", self.torso_f_hz, 0.3, 10.0)?;
        check("cancellation.torso_zeta", self.torso_zeta, 0.05, 2.0)?;
        check("cancellation.arm_f_hz", self.arm_f_hz, 0.3, 10.0)?;
        check("cancellation.arm_zeta", self.arm_zeta, 0.05, 2.0)?;
        check("cancellation.gain", self.gain, 0.0, 3.0)?;
        check("cancellation.phase_lag_deg", self.phase_lag_deg, 0.0, 170.0)?;
        check("cancellation.phase_ref_hz", self.phase_ref_hz, 0.1, 20.0)?;
        check("cancellation.limit_mm", self.limit_mm, 0.01, 1000.0)
    }
}
