//! A study's cancellation factor (issue 38): the arms crossed with the compensators on the
//! machine, and the model each arm cancels with. Every compensator on the machine also runs
//! uncancelled (`off`); at the desk no body rides, so the factor is not offered there.

use serde::{Deserialize, Serialize};

use crate::cancellation::{CancellationModel, DEFAULT_LIMIT_MM};
use crate::params::{BodyModel, ParamError, PopulationParams, check};

/// What a test on the machine cancels with.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum CancellationArm {
    /// No cancellation (every test at the desk, and the machine's control arm).
    #[default]
    Off,
    /// The subject's own body, as their identification test fitted it.
    Personal,
    /// The population's median body (`PopulationParams::median_body`): one model for all.
    Generic,
    /// The subject's own body with the study's stated gain and phase error (robustness).
    Wrong,
}

impl CancellationArm {
    pub const ALL: [CancellationArm; 4] = [Self::Off, Self::Personal, Self::Generic, Self::Wrong];

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::Personal => "personal",
            Self::Generic => "generic",
            Self::Wrong => "wrong",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|a| a.as_str() == s)
    }
}

impl std::fmt::Display for CancellationArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl TryFrom<String> for CancellationArm {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        Self::parse(&s).ok_or_else(|| format!("unknown cancellation arm {s:?}"))
    }
}

/// The wrong model's error on the subject's own body: a gain and a phase lag at a frequency.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ModelError {
    /// The model's gain over the body's.
    pub gain: f64,
    /// Phase lag added at `phase_ref_hz` (degrees).
    #[serde(default)]
    pub phase_lag_deg: f64,
    #[serde(default = "default_ref_hz")]
    pub phase_ref_hz: f64,
}

fn default_ref_hz() -> f64 {
    2.0
}

/// The stated ranges of the wrong model's error: far enough off to test robustness (the
/// literature's subject- and task-mismatch is tens of percent and tens of degrees), not so
/// far that the arm is no model at all.
pub const ERROR_GAIN: (f64, f64) = (0.5, 2.0);
pub const ERROR_PHASE_LAG_DEG: (f64, f64) = (0.0, 90.0);
pub const ERROR_PHASE_REF_HZ: (f64, f64) = (0.5, 5.0);

/// A study's cancellation factor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct CancellationParams {
    /// The cancelling arms, besides `off`, which every compensator on the machine runs too
    /// (each of `personal`, `generic`, `wrong` at most once).
    pub arms: Vec<CancellationArm>,
    /// The `wrong` arm's error (required with it, refused without it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrong: Option<ModelError>,
    /// The tick's guard: an output past this (mm of device travel) turns cancellation off for
    /// the rest of the test.
    #[serde(default = "default_limit")]
    pub limit_mm: f64,
}

fn default_limit() -> f64 {
    DEFAULT_LIMIT_MM
}

impl Default for CancellationParams {
    fn default() -> Self {
        Self {
            arms: vec![CancellationArm::Personal],
            wrong: None,
            limit_mm: DEFAULT_LIMIT_MM,
        }
    }
}

impl CancellationParams {
    /// The arms each compensator runs on the machine: off, then the study's in its order.
    pub fn machine_arms(&self) -> Vec<CancellationArm> {
        std::iter::once(CancellationArm::Off)
            .chain(self.arms.iter().copied())
            .collect()
    }

    /// Each field in its range, or the first that is not, named with what is allowed.
    /// `identification`: whether the study has an identification test (every cancelling
    /// arm is gated on the subject's identified body, and two of them cancel it).
    pub fn validate(&self, identification: bool) -> Result<(), ParamError> {
        let invalid = |message: String| {
            Err(ParamError::Invalid {
                name: "cancellation.arms",
                message,
            })
        };
        if self.arms.is_empty() {
            return invalid("no arm given; allowed: personal, generic, wrong".into());
        }
        for (i, a) in self.arms.iter().enumerate() {
            if *a == CancellationArm::Off {
                return invalid(
                    "off is not listed: every compensator on the machine runs it; list \
                     personal, generic or wrong"
                        .into(),
                );
            }
            if self.arms[..i].contains(a) {
                return invalid(format!("{a} is listed twice"));
            }
        }
        if !identification {
            return Err(ParamError::Invalid {
                name: "cancellation",
                message: "a cancelling arm needs the study's identification test \
                          (identification): its body is what the personal and wrong models \
                          cancel, and what every cancelling test is checked against before it \
                          starts"
                    .into(),
            });
        }
        let has_wrong = self.arms.contains(&CancellationArm::Wrong);
        match (&self.wrong, has_wrong) {
            (None, true) => {
                return Err(ParamError::Invalid {
                    name: "cancellation.wrong",
                    message: "the wrong arm needs its error: gain, phase_lag_deg, phase_ref_hz"
                        .into(),
                });
            }
            (Some(_), false) => {
                return Err(ParamError::Invalid {
                    name: "cancellation.wrong",
                    message: "given without the wrong arm in cancellation.arms".into(),
                });
            }
            (Some(e), true) => {
                check(
                    "cancellation.wrong.gain",
                    e.gain,
                    ERROR_GAIN.0,
                    ERROR_GAIN.1,
                )?;
                check(
                    "cancellation.wrong.phase_lag_deg",
                    e.phase_lag_deg,
                    ERROR_PHASE_LAG_DEG.0,
                    ERROR_PHASE_LAG_DEG.1,
                )?;
                check(
                    "cancellation.wrong.phase_ref_hz",
                    e.phase_ref_hz,
                    ERROR_PHASE_REF_HZ.0,
                    ERROR_PHASE_REF_HZ.1,
                )?;
                if e.gain == 1.0 && e.phase_lag_deg == 0.0 {
                    return Err(ParamError::Invalid {
                        name: "cancellation.wrong",
                        message: "no error stated (gain 1, no phase lag): that is the personal \
                                  arm"
                        .into(),
                    });
                }
            }
            (None, false) => {}
        }
        check("cancellation.limit_mm", self.limit_mm, 0.1, 1000.0)
    }

    /// The model a test of `arm` cancels with for a subject whose identified body is `own`
    /// (none: not identified), in a study whose population is `population`; why there is
    /// none otherwise. `off` has none.
    pub fn model(
        &self,
        arm: CancellationArm,
        own: Option<&BodyModel>,
        population: &PopulationParams,
    ) -> Result<CancellationModel, String> {
        let own = || own.ok_or_else(|| "the subject's body was not identified".to_string());
        let seated = |body: &BodyModel| {
            CancellationModel::of_seated(body)
                .ok_or_else(|| "the body is not a seated one".to_string())
        };
        let model = match arm {
            CancellationArm::Off => return Err("the off arm does not cancel".into()),
            CancellationArm::Personal => seated(own()?)?,
            CancellationArm::Generic => seated(&population.median_body())?,
            CancellationArm::Wrong => {
                let e = self
                    .wrong
                    .ok_or_else(|| "the study states no error".to_string())?;
                CancellationModel {
                    gain: e.gain,
                    phase_lag_deg: e.phase_lag_deg,
                    phase_ref_hz: e.phase_ref_hz,
                    ..seated(own()?)?
                }
            }
        };
        Ok(CancellationModel {
            limit_mm: self.limit_mm,
            ..model
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body() -> BodyModel {
        BodyModel::Seated {
            k_h: 0.5,
            torso_f_hz: 2.5,
            torso_zeta: 0.3,
            arm_f_hz: 5.0,
            arm_zeta: 0.3,
        }
    }

    #[test]
    fn each_arm_cancels_with_its_model() {
        let p = CancellationParams {
            arms: vec![
                CancellationArm::Personal,
                CancellationArm::Generic,
                CancellationArm::Wrong,
            ],
            wrong: Some(ModelError {
                gain: 1.3,
                phase_lag_deg: 0.0,
                phase_ref_hz: 2.0,
            }),
            limit_mm: 50.0,
        };
        p.validate(true).unwrap();
        let pop = PopulationParams::default();
        let personal = p
            .model(CancellationArm::Personal, Some(&body()), &pop)
            .unwrap();
        assert_eq!(personal.body(), body());
        assert_eq!((personal.gain, personal.limit_mm), (1.0, 50.0));
        let generic = p
            .model(CancellationArm::Generic, Some(&body()), &pop)
            .unwrap();
        assert_eq!(generic.body(), pop.median_body());
        let wrong = p
            .model(CancellationArm::Wrong, Some(&body()), &pop)
            .unwrap();
        assert_eq!((wrong.body(), wrong.gain), (body(), 1.3));
        // Without an identified body only the generic model is there.
        assert!(p.model(CancellationArm::Personal, None, &pop).is_err());
        assert!(p.model(CancellationArm::Wrong, None, &pop).is_err());
        assert!(p.model(CancellationArm::Generic, None, &pop).is_ok());
        assert_eq!(
            p.machine_arms(),
            [
                CancellationArm::Off,
                CancellationArm::Personal,
                CancellationArm::Generic,
                CancellationArm::Wrong
            ]
        );
    }

    #[test]
    fn bad_settings_are_refused_naming_the_field() {
        let err = |p: CancellationParams, id: bool| p.validate(id).unwrap_err().to_string();
        let ok = CancellationParams::default();
        assert!(err(ok.clone(), false).starts_with("cancellation: a cancelling arm needs"));
        let with = |arms: Vec<CancellationArm>, wrong| CancellationParams {
            arms,
            wrong,
            ..ok.clone()
        };
        assert!(err(with(vec![], None), true).starts_with("cancellation.arms: no arm"));
        assert!(
            err(with(vec![CancellationArm::Off], None), true)
                .starts_with("cancellation.arms: off is not listed")
        );
        assert!(
            err(
                with(
                    vec![CancellationArm::Generic, CancellationArm::Generic],
                    None
                ),
                true
            )
            .starts_with("cancellation.arms: generic is listed twice")
        );
        assert!(
            err(with(vec![CancellationArm::Wrong], None), true)
                .starts_with("cancellation.wrong: the wrong arm needs its error")
        );
        let e = |gain, phase_lag_deg| {
            Some(ModelError {
                gain,
                phase_lag_deg,
                phase_ref_hz: 2.0,
            })
        };
        assert!(
            err(with(vec![CancellationArm::Personal], e(1.3, 0.0)), true)
                .starts_with("cancellation.wrong: given without the wrong arm")
        );
        assert!(
            err(with(vec![CancellationArm::Wrong], e(2.5, 0.0)), true)
                .starts_with("cancellation.wrong.gain = 2.5 is out of range")
        );
        assert!(
            err(with(vec![CancellationArm::Wrong], e(1.0, 120.0)), true)
                .starts_with("cancellation.wrong.phase_lag_deg = 120 is out of range")
        );
        assert!(
            err(with(vec![CancellationArm::Wrong], e(1.0, 0.0)), true)
                .starts_with("cancellation.wrong: no error stated")
        );
        with(vec![CancellationArm::Wrong], e(1.0, 60.0))
            .validate(true)
            .unwrap();
        let json = r#"{"arms":["personal","off-ish"]}"#;
        assert!(serde_json::from_str::<CancellationParams>(json).is_err());
    }
}
