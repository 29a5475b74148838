//! The identification test: a known multisine moves the cab while the person holds the
//! device, the device's motion is recorded but never fed to the valve, and the person's
//! feedthrough is estimated at the excited frequencies (`docs/identification.md`).
//!
//! What crosses the link and the API: the multisine's design (`MultisineSpec`, carried by
//! `TargetSpec::Identification`), the task the person is given, and what the test measured
//! (`FrfPoint`s and the seated body fitted to them, `BodyFit`).

use std::collections::BTreeMap;

use serde::{Deserialize, Deserializer, Serialize};

use crate::params::{BodyModel, ParamError, check};

/// What the person is asked to do while the cab moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum IdentificationTask {
    /// Keep the pointer still at the centre (the position task: a stiff arm).
    #[default]
    HoldStill,
    /// Hold the device lightly and let the arm go with the motion (the relax task).
    Relax,
}

impl IdentificationTask {
    pub const ALL: [Self; 2] = [Self::HoldStill, Self::Relax];

    pub fn name(self) -> &'static str {
        match self {
            Self::HoldStill => "hold-still",
            Self::Relax => "relax",
        }
    }
}

/// The cab's excitation: a sum of sines on the grid 1/period_s, one period a whole number
/// of ticks, random phases from `seed`, run for `transient_periods` (dropped) and then
/// `periods` (averaged). A parameter left out takes its default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct MultisineSpec {
    /// Lowest excited frequency (Hz).
    pub f_min_hz: f64,
    /// Highest excited frequency (Hz).
    pub f_max_hz: f64,
    /// How many frequencies are excited (log-spaced, at most one per grid line).
    pub lines: u32,
    /// One period (s): the frequency grid's resolution is its inverse.
    pub period_s: f64,
    /// Periods recorded and averaged after the transient.
    pub periods: u32,
    /// Whole periods run first and dropped, so the loop and the body reach steady state.
    pub transient_periods: u32,
    /// RMS of the cylinder reference the multisine drives (mm).
    pub rms_mm: f64,
    /// Seed of the phases (the server derives it from the study seed).
    pub seed: u64,
}

/// Limits of a multisine a study may ask for: (lo, hi) per parameter.
pub mod limits {
    pub const F_MIN_HZ: (f64, f64) = (0.1, 5.0);
    pub const F_MAX_HZ: (f64, f64) = (1.0, 20.0);
    pub const LINES: (u32, u32) = (3, 60);
    pub const PERIOD_S: (f64, f64) = (2.0, 60.0);
    pub const PERIODS: (u32, u32) = (2, 30);
    pub const TRANSIENT_PERIODS: (u32, u32) = (1, 5);
    pub const RMS_MM: (f64, f64) = (0.1, 10.0);
}

impl Default for MultisineSpec {
    fn default() -> Self {
        Self {
            f_min_hz: 0.5,
            f_max_hz: 8.0,
            lines: 20,
            period_s: 10.0,
            periods: 6,
            transient_periods: 1,
            rms_mm: 6.0,
            seed: 0,
        }
    }
}

impl MultisineSpec {
    /// Checks every parameter against `limits` (the error names the parameter and its
    /// allowed range), the band's order, and that the band holds `lines` grid lines.
    pub fn validate(&self) -> Result<(), ParamError> {
        let int = |name: &'static str, v: u32, (lo, hi): (u32, u32)| {
            check(name, f64::from(v), f64::from(lo), f64::from(hi))
        };
        check(
            "multisine.f_min_hz",
            self.f_min_hz,
            limits::F_MIN_HZ.0,
            limits::F_MIN_HZ.1,
        )?;
        check(
            "multisine.f_max_hz",
            self.f_max_hz,
            limits::F_MAX_HZ.0,
            limits::F_MAX_HZ.1,
        )?;
        int("multisine.lines", self.lines, limits::LINES)?;
        check(
            "multisine.period_s",
            self.period_s,
            limits::PERIOD_S.0,
            limits::PERIOD_S.1,
        )?;
        int("multisine.periods", self.periods, limits::PERIODS)?;
        int(
            "multisine.transient_periods",
            self.transient_periods,
            limits::TRANSIENT_PERIODS,
        )?;
        check(
            "multisine.rms_mm",
            self.rms_mm,
            limits::RMS_MM.0,
            limits::RMS_MM.1,
        )?;
        if self.f_max_hz <= self.f_min_hz {
            return Err(ParamError::Invalid {
                name: "multisine.f_max_hz",
                message: format!(
                    "{} Hz is not above f_min_hz = {} Hz",
                    self.f_max_hz, self.f_min_hz
                ),
            });
        }
        let grid_lines = ((self.f_max_hz - self.f_min_hz) * self.period_s).floor() as u64 + 1;
        if u64::from(self.lines) > grid_lines {
            return Err(ParamError::Invalid {
                name: "multisine.lines",
                message: format!(
                    "{} lines asked, but {}–{} Hz holds only {grid_lines} lines of the \
                     1/{} s grid: lower lines, widen the band or lengthen period_s",
                    self.lines, self.f_min_hz, self.f_max_hz, self.period_s
                ),
            });
        }
        Ok(())
    }

    /// The test's whole length (s): transient and recorded periods.
    pub fn duration_s(&self) -> f64 {
        f64::from(self.transient_periods + self.periods) * self.period_s
    }
}

/// The feedthrough at one excited frequency: device position over cab acceleration, with
/// 95 % bounds and the coherence over the periods. The bounds are the projections of the
/// 95 % confidence disc about the complex estimate (they hold jointly); a phase bound may
/// leave (−180, 180] so that lo ≤ phase ≤ hi.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct FrfPoint {
    pub f_hz: f64,
    /// |device / cab acceleration| (mm per m/s²).
    pub magnitude: f64,
    pub magnitude_lo: f64,
    pub magnitude_hi: f64,
    /// Phase of device / cab acceleration (degrees, in (−180, 180]).
    pub phase_deg: f64,
    pub phase_lo_deg: f64,
    pub phase_hi_deg: f64,
    /// Squared coherence between cab acceleration and device over the periods (0–1).
    pub coherence: f64,
    /// Standard deviation of the complex estimate, (E|Ĥ − H|²)^½ (mm per m/s²), from the
    /// period-to-period spread: what the body fit weights the point by.
    pub std_dev: f64,
    /// Periods averaged: the spread behind `std_dev` has 2·(periods − 1) degrees of
    /// freedom, which the bounds and the fit's intervals account for.
    pub periods: u32,
}

/// An estimate with its 95 % interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Estimate {
    pub value: f64,
    pub lo: f64,
    pub hi: f64,
}

/// The seated body (`BodyModel::Seated`) fitted to one person's measured feedthrough.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct BodyFit {
    pub k_h: Estimate,
    pub torso_f_hz: Estimate,
    pub torso_zeta: Estimate,
    pub arm_f_hz: Estimate,
    pub arm_zeta: Estimate,
    /// RMS of the fit's residual, |log(model / measured)| over the points (natural log).
    pub residual_rms: f64,
    /// Parameters the data could not pin down (their interval spans more than a factor of
    /// 10, or the fit's information matrix is singular along them), by name, with why.
    /// Fits stored before the reasons were kept listed the names only.
    #[serde(deserialize_with = "names_or_reasons")]
    #[cfg_attr(feature = "openapi", schema(value_type = BTreeMap<String, String>))]
    pub unidentified: BTreeMap<String, String>,
}

/// An interval end this large is no bound at all: the fit's [0, f64::MAX] along a direction
/// the data do not inform, stored as a number before such parameters were left empty.
pub const UNBOUNDED: f64 = 1e300;

/// The reason of a parameter named unidentified by a fit stored before reasons were kept.
const UNRECORDED: &str = "the fit could not pin it down; its reason was not recorded";

/// `unidentified` as stored now (name → why) or before reasons were kept (names).
fn names_or_reasons<'de, D: Deserializer<'de>>(d: D) -> Result<BTreeMap<String, String>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Stored {
        Names(Vec<String>),
        Reasons(BTreeMap<String, String>),
    }
    Ok(match Stored::deserialize(d)? {
        Stored::Names(names) => names.into_iter().map(|n| (n, UNRECORDED.into())).collect(),
        Stored::Reasons(r) => r,
    })
}

/// One fitted parameter as the API and the exports report it: its value and 95 % interval,
/// or none of them and why, when the data did not identify it (a number there would be read
/// as a measurement).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Reported {
    pub value: Option<f64>,
    pub lo: Option<f64>,
    pub hi: Option<f64>,
    /// Why the data did not identify it; null when they did.
    pub not_identified: Option<String>,
}

impl Reported {
    /// The exports' status of the parameter: `identified` or `not identified: why`.
    pub fn status(&self) -> String {
        match &self.not_identified {
            None => "identified".into(),
            Some(why) => format!("not identified: {why}"),
        }
    }
}

/// A `BodyFit` as the API reports it (`BodyFit::report`).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct FitReport {
    pub k_h: Reported,
    pub torso_f_hz: Reported,
    pub torso_zeta: Reported,
    pub arm_f_hz: Reported,
    pub arm_zeta: Reported,
    pub residual_rms: f64,
}

impl BodyFit {
    /// The fitted parameters' names, in the order of `estimates`.
    pub const PARAMETERS: [&'static str; 5] =
        ["k_h", "torso_f_hz", "torso_zeta", "arm_f_hz", "arm_zeta"];

    /// The fitted parameters, in the order of `PARAMETERS`.
    pub fn estimates(&self) -> [Estimate; 5] {
        [
            self.k_h,
            self.torso_f_hz,
            self.torso_zeta,
            self.arm_f_hz,
            self.arm_zeta,
        ]
    }

    /// The fit with every parameter whose value or interval end is not a finite number
    /// below `UNBOUNDED` named unidentified: what every stored fit goes through, so that a
    /// fit stored before such parameters were named (or with their reasons) is reported
    /// right too.
    pub fn checked(mut self) -> Self {
        for (name, e) in Self::PARAMETERS.into_iter().zip(self.estimates()) {
            if ![e.value, e.lo, e.hi]
                .iter()
                .all(|x| x.is_finite() && x.abs() < UNBOUNDED)
            {
                self.unidentified
                    .entry(name.into())
                    .or_insert_with(|| "its 95 % interval is unbounded".into());
            }
        }
        self
    }

    /// Each parameter as reported, in the order of `PARAMETERS`.
    pub fn reported(&self) -> [Reported; 5] {
        let estimates = self.estimates();
        std::array::from_fn(|i| {
            let why = self.unidentified.get(Self::PARAMETERS[i]).cloned();
            let known = |x: f64| why.is_none().then_some(x);
            Reported {
                value: known(estimates[i].value),
                lo: known(estimates[i].lo),
                hi: known(estimates[i].hi),
                not_identified: why,
            }
        })
    }

    /// The fit as the API reports it.
    pub fn report(&self) -> FitReport {
        let [k_h, torso_f_hz, torso_zeta, arm_f_hz, arm_zeta] = self.reported();
        FitReport {
            k_h,
            torso_f_hz,
            torso_zeta,
            arm_f_hz,
            arm_zeta,
            residual_rms: self.residual_rms,
        }
    }

    /// The body the fit describes, when the data identified every parameter of it: what the
    /// stability analyses, per-subject designs and the fitted curve may use. Otherwise why
    /// not (the first parameter not identified, and why): a value the data did not pin down
    /// is no person's body.
    pub fn identified_body(&self) -> Result<BodyModel, String> {
        match self.unidentified.iter().next() {
            None => Ok(self.body()),
            Some((name, why)) => Err(format!(
                "{name} was not identified ({why}){}",
                match self.unidentified.len() {
                    1 => String::new(),
                    n => format!(", nor {} other parameter(s)", n - 1),
                }
            )),
        }
    }

    /// The body the fit describes, every value as fitted (identified or not): for the
    /// stability gate and per-subject designs use `identified_body`.
    pub fn body(&self) -> BodyModel {
        BodyModel::Seated {
            k_h: self.k_h.value,
            torso_f_hz: self.torso_f_hz.value,
            torso_zeta: self.torso_zeta.value,
            arm_f_hz: self.arm_f_hz.value,
            arm_zeta: self.arm_zeta.value,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unbounded_or_unidentified_parameter_is_reported_empty_with_why() {
        let e = |value, lo, hi| Estimate { value, lo, hi };
        // A fit as stored before reasons were kept: names only, the singular direction's
        // interval [0, f64::MAX] and a damping no body has.
        let stored = r#"{"k_h":{"value":0.5,"lo":0.4,"hi":0.6},
            "torso_f_hz":{"value":4.36e-8,"lo":0.0,"hi":1.7976931348623157e308},
            "torso_zeta":{"value":4955376.8,"lo":1.0,"hi":1e12},
            "arm_f_hz":{"value":2.0,"lo":1.8,"hi":2.2},
            "arm_zeta":{"value":0.3,"lo":0.2,"hi":0.4},
            "residual_rms":0.1,"unidentified":["torso_zeta"]}"#;
        let fit: BodyFit = serde_json::from_str(stored).unwrap();
        let fit = fit.checked();
        let r = fit.report();
        assert_eq!(r.k_h.value, Some(0.5));
        assert_eq!(r.k_h.status(), "identified");
        for p in [&r.torso_f_hz, &r.torso_zeta] {
            assert_eq!((p.value, p.lo, p.hi), (None, None, None), "{p:?}");
            assert!(p.status().starts_with("not identified: "), "{p:?}");
        }
        assert!(r.torso_f_hz.status().contains("unbounded"));
        // Stored again, the reasons are kept.
        let again: BodyFit = serde_json::from_str(&serde_json::to_string(&fit).unwrap()).unwrap();
        assert_eq!(again.unidentified, fit.unidentified);
        assert_eq!(again.arm_f_hz, e(2.0, 1.8, 2.2));
    }

    #[test]
    fn the_default_multisine_is_valid_and_lasts_its_periods() {
        let m = MultisineSpec::default();
        m.validate().unwrap();
        assert_eq!(m.duration_s(), 70.0);
    }

    #[test]
    fn a_bad_multisine_names_what_is_wrong() {
        let bad = |f: fn(&mut MultisineSpec)| {
            let mut m = MultisineSpec::default();
            f(&mut m);
            m.validate().unwrap_err().to_string()
        };
        assert!(bad(|m| m.rms_mm = 50.0).starts_with("multisine.rms_mm = 50"));
        assert!(bad(|m| m.f_max_hz = 0.4).starts_with("multisine.f_max_hz"));
        assert!(bad(|m| m.f_max_hz = 1.0).contains("holds only"));
        assert!(bad(|m| m.periods = 0).starts_with("multisine.periods"));
    }
}
