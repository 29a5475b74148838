//! Whole-body vibration exposure as ISO 2631-1 and Directive 2002/44/EC judge it: a test's
//! frequency-weighted r.m.s. a_w and vibration dose value VDV, a day's A(8) and VDV, the
//! Directive's action and limit values, and what the server hands the controller as the
//! allowance a test may still add to its subject's day (the in-loop exposure guard).
//!
//! Units: a_w and A(8) in m/s², VDV in m/s^1.75; a test's energy ∫a_w² dt in m²/s³ and its
//! fourth-power dose ∫a_w⁴ dt (= VDV⁴) in m⁴/s⁷.

use serde::{Deserialize, Serialize};

use crate::params::{ParamError, check};

/// 2002/44/EC, whole-body: daily exposure action value A(8) (m/s²).
pub const ACTION_A8_M_S2: f64 = 0.5;
/// 2002/44/EC, whole-body: daily exposure limit value A(8) (m/s²).
pub const LIMIT_A8_M_S2: f64 = 1.15;
/// 2002/44/EC, whole-body: action value as a vibration dose value (m/s^1.75).
pub const ACTION_VDV_M_S175: f64 = 9.1;
/// 2002/44/EC, whole-body: limit value as a vibration dose value (m/s^1.75).
pub const LIMIT_VDV_M_S175: f64 = 21.0;
/// The reference duration of A(8): eight hours (s).
pub const EIGHT_HOURS_S: f64 = 8.0 * 3600.0;
/// ISO 2631-1 §6.3.3: the estimated VDV of a signal known only by its r.m.s.,
/// eVDV = 1.4·a_w·T^¼ (what a test without a record is counted at, with the interlock's limit
/// as its r.m.s.).
pub const EVDV_FACTOR: f64 = 1.4;

/// What one test may still add to its subject's day: the controller stops the test (fault
/// `exposure-budget`) once its weighted cab acceleration has used either up.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ExposureAllowance {
    /// ∫a_w² dt left (m²/s³): 8 h × (budget A(8)² − the day's A(8)² so far).
    pub energy_m2_s3: f64,
    /// ∫a_w⁴ dt left (m⁴/s⁷): budget VDV⁴ − the day's VDV⁴ so far.
    pub vdv4_m4_s7: f64,
}

impl ExposureAllowance {
    pub fn validate(&self) -> Result<(), ParamError> {
        let most = |v: f64| v * v * v * v;
        check(
            "exposure_allowance.energy_m2_s3",
            self.energy_m2_s3,
            0.0,
            LIMIT_A8_M_S2 * LIMIT_A8_M_S2 * EIGHT_HOURS_S,
        )?;
        check(
            "exposure_allowance.vdv4_m4_s7",
            self.vdv4_m4_s7,
            0.0,
            most(LIMIT_VDV_M_S175),
        )
    }
}

/// A test's ISO 2631-1 figures: the W_d-weighted fore-aft cab acceleration over its record.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct TrialExposure {
    /// Frequency-weighted r.m.s. a_w (m/s²).
    pub aw_m_s2: f64,
    /// Vibration dose value (∫a_w⁴ dt)^¼ (m/s^1.75).
    pub vdv_m_s175: f64,
    /// Length of the record the figures are over (s).
    pub duration_s: f64,
}

impl TrialExposure {
    /// ∫a_w² dt (m²/s³).
    pub fn energy(&self) -> f64 {
        self.aw_m_s2 * self.aw_m_s2 * self.duration_s
    }

    /// ∫a_w⁴ dt (m⁴/s⁷).
    pub fn vdv4(&self) -> f64 {
        self.vdv_m_s175.powi(4)
    }
}

/// A person's exposure summed over tests: the energy sum of A(8) and the fourth-power sum
/// of the day's VDV (ISO 2631-1 §6.3.1, 2002/44/EC Annex B).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct DoseSum {
    /// Σ a_w,i²·T_i (m²/s³).
    pub energy_m2_s3: f64,
    /// Σ VDV_i⁴ (m⁴/s⁷).
    pub vdv4_m4_s7: f64,
}

impl DoseSum {
    pub fn add(&mut self, energy_m2_s3: f64, vdv4_m4_s7: f64) {
        self.energy_m2_s3 += energy_m2_s3;
        self.vdv4_m4_s7 += vdv4_m4_s7;
    }

    /// A(8) = √(Σ a_w,i²·T_i / 8 h) (m/s²).
    pub fn a8(&self) -> f64 {
        (self.energy_m2_s3 / EIGHT_HOURS_S).sqrt()
    }

    /// The day's VDV = (Σ VDV_i⁴)^¼ (m/s^1.75).
    pub fn vdv(&self) -> f64 {
        self.vdv4_m4_s7.powf(0.25)
    }

    /// What is left of a budget (A(8), VDV) after this sum; never negative.
    pub fn allowance(&self, budget_a8: f64, budget_vdv: f64) -> ExposureAllowance {
        ExposureAllowance {
            energy_m2_s3: (budget_a8 * budget_a8 * EIGHT_HOURS_S - self.energy_m2_s3).max(0.0),
            vdv4_m4_s7: (budget_vdv.powi(4) - self.vdv4_m4_s7).max(0.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a8_and_the_day_vdv_follow_the_directive_s_sums() {
        // Two hours at 0.5 m/s² and two at 1 m/s²: A(8) = √((0.25·2 + 1·2)/8) = 0.559 m/s².
        let mut day = DoseSum::default();
        let two_h = 7200.0;
        for aw in [0.5, 1.0] {
            let t = TrialExposure {
                aw_m_s2: aw,
                vdv_m_s175: 2.0,
                duration_s: two_h,
            };
            day.add(t.energy(), t.vdv4());
        }
        assert!((day.a8() - (2.5f64 / 8.0).sqrt()).abs() < 1e-12);
        // Two VDVs of 2: (2·16)^¼ = 2·2^¼.
        assert!((day.vdv() - 2.0 * 2f64.powf(0.25)).abs() < 1e-12);
        // Eight hours at exactly the budget leave nothing; less leaves the difference.
        let full = DoseSum {
            energy_m2_s3: 0.25 * EIGHT_HOURS_S,
            vdv4_m4_s7: 0.0,
        };
        let left = full.allowance(ACTION_A8_M_S2, ACTION_VDV_M_S175);
        assert_eq!(left.energy_m2_s3, 0.0);
        assert!((left.vdv4_m4_s7 - 9.1f64.powi(4)).abs() < 1e-9);
    }
}
