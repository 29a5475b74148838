//! The study's daily vibration exposure budget and how a subject's tests count against it
//! (ISO 2631-1 W_d, 2002/44/EC; docs/exposure.md).
//!
//! - Only tests the subject rode the machine for count (seat `on`, the practice too when it
//!   is on the machine): at the desk nobody is shaken by the cab.
//! - A test counts at the figures its loop measured; one without them (a lost controller,
//!   a test running now, one filed before the figures existed) at its worst case: the
//!   interlock's cab limit held for as long as it ran (for a running one, its whole length),
//!   weighted by W_d's largest gain, its VDV estimated as the standard's eVDV = 1.4·a_w·T^¼.
//! - A subject's day, as reported, is the UTC calendar date a test started on. The budget is
//!   checked against every test that started in the 24 hours before the new one: whatever
//!   calendar (time zone) a day is counted in, all of it before the new test lies in those
//!   24 hours, so no day of the subject's can exceed the budget.
//! - A test on the machine starts only with the remainder of the budget as its allowance;
//!   the controller's exposure guard stops it when the allowance is used (one tick's share
//!   past it at most). So a test's worst case is the smaller of the interlock's limit held
//!   for the whole test and the remainder — within the budget whenever something remains,
//!   and a test is refused (409) when nothing does.

use bdft_controller::exposure::WD_PEAK_GAIN;
use bdft_protocol::exposure::{
    ACTION_A8_M_S2, ACTION_VDV_M_S175, DoseSum, EVDV_FACTOR, ExposureAllowance, LIMIT_A8_M_S2,
    LIMIT_VDV_M_S175,
};
use bdft_protocol::params::Seat;
use bdft_protocol::study::StudyParams;
use serde::Serialize;
use sqlx::AnyConnection;

use crate::error::{AppError, Result};
use crate::store;
use crate::store::exposure::RiddenTest;
use crate::store::subjects::Subject;

/// The window the budget is checked over (ms).
pub const DAY_MS: i64 = 24 * 3600 * 1000;

/// The worst case of `seconds` on the machine: the interlock's limit (mm/s² r.m.s. over its
/// window) held all along, raised by W_d's largest gain; its VDV by the standard's eVDV.
pub fn interlock_held(params: &StudyParams, seconds: f64) -> DoseSum {
    let aw = WD_PEAK_GAIN * params.max_cab_rms_mm_s2 * 1e-3;
    DoseSum {
        energy_m2_s3: aw * aw * seconds,
        vdv4_m4_s7: (EVDV_FACTOR * aw).powi(4) * seconds,
    }
}

/// What `test` counts at `now_ms`, and whether the loop measured it.
fn dose(params: &StudyParams, test: &RiddenTest) -> (DoseSum, bool) {
    if let (Some(aw), Some(vdv), Some(t)) = (test.cab_aw_m_s2, test.cab_vdv_m_s175, test.exposure_s)
    {
        let mut d = DoseSum::default();
        d.add(aw * aw * t, vdv.powi(4));
        return (d, true);
    }
    let ran = match test.finished_at {
        Some(end) => ((end - test.started_at) as f64 / 1000.0).clamp(0.0, test.duration_s),
        None => test.duration_s,
    };
    (interlock_held(params, ran), false)
}

/// The subject's exposure from the tests that started in the 24 hours before `now_ms`.
pub async fn last_24h(
    db: &mut AnyConnection,
    params: &StudyParams,
    subject_id: i64,
    now_ms: i64,
) -> Result<DoseSum> {
    let mut sum = DoseSum::default();
    for t in store::exposure::ridden_since(&mut *db, subject_id, now_ms - DAY_MS).await? {
        let (d, _) = dose(params, &t);
        sum.add(d.energy_m2_s3, d.vdv4_m4_s7);
    }
    Ok(sum)
}

/// One UTC day of a subject's exposure.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ExposureDay {
    /// The UTC date the tests started on (YYYY-MM-DD).
    pub date: String,
    /// Tests on the machine that day.
    pub tests: u32,
    /// Of those, counted at their worst case (no measured figures).
    pub worst_case_tests: u32,
    /// A(8) (m/s²).
    pub a8_m_s2: f64,
    /// The day's VDV (m/s^1.75).
    pub vdv_m_s175: f64,
}

/// A subject's exposure day by day, against the study's budget.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct SubjectExposure {
    pub days: Vec<ExposureDay>,
    pub budget_a8_m_s2: f64,
    pub budget_vdv_m_s175: f64,
    pub action_a8_m_s2: f64,
    pub action_vdv_m_s175: f64,
    pub limit_a8_m_s2: f64,
    pub limit_vdv_m_s175: f64,
}

/// The subject's exposure per UTC day, oldest first.
pub async fn days(
    db: &mut AnyConnection,
    params: &StudyParams,
    subject_id: i64,
) -> Result<SubjectExposure> {
    let mut days: Vec<(ExposureDay, DoseSum)> = Vec::new();
    for t in store::exposure::ridden_since(&mut *db, subject_id, i64::MIN).await? {
        let date = utc_date(t.started_at);
        let (d, measured) = dose(params, &t);
        if days.last().is_none_or(|(day, _)| day.date != date) {
            days.push((
                ExposureDay {
                    date,
                    tests: 0,
                    worst_case_tests: 0,
                    a8_m_s2: 0.0,
                    vdv_m_s175: 0.0,
                },
                DoseSum::default(),
            ));
        }
        let (day, sum) = days.last_mut().expect("pushed");
        day.tests += 1;
        day.worst_case_tests += u32::from(!measured);
        sum.add(d.energy_m2_s3, d.vdv4_m4_s7);
        day.a8_m_s2 = sum.a8();
        day.vdv_m_s175 = sum.vdv();
    }
    Ok(SubjectExposure {
        days: days.into_iter().map(|(d, _)| d).collect(),
        budget_a8_m_s2: params.exposure_budget_a8_m_s2,
        budget_vdv_m_s175: params.exposure_budget_vdv_m_s175,
        action_a8_m_s2: ACTION_A8_M_S2,
        action_vdv_m_s175: ACTION_VDV_M_S175,
        limit_a8_m_s2: LIMIT_A8_M_S2,
        limit_vdv_m_s175: LIMIT_VDV_M_S175,
    })
}

/// The UTC date of a time in ms since the epoch (YYYY-MM-DD).
pub fn utc_date(ms: i64) -> String {
    // The first ten characters of the one time format the exports use.
    store::db::rfc3339(ms).chars().take(10).collect()
}

/// The allowance a test of `duration_s` on the machine starts with, or the 409 that
/// refuses it: the day so far, the test's worst case and the budget named.
pub fn allowance(
    params: &StudyParams,
    subject_code: &str,
    so_far: DoseSum,
    duration_s: f64,
) -> Result<ExposureAllowance> {
    let (budget_a8, budget_vdv) = (
        params.exposure_budget_a8_m_s2,
        params.exposure_budget_vdv_m_s175,
    );
    let left = so_far.allowance(budget_a8, budget_vdv);
    if left.energy_m2_s3 > 0.0 && left.vdv4_m4_s7 > 0.0 {
        return Ok(left);
    }
    let worst = interlock_held(params, duration_s);
    Err(AppError::Conflict(format!(
        "{subject_code}'s vibration exposure budget is used up: in the 24 h before this test A(8) {:.3} m/s² and VDV {:.2} m/s^1.75 so far; \
         the test's worst case (the interlock's limit of {:.2} m/s² held for {duration_s} s, W_d-weighted: A(8) {:.3} m/s², VDV {:.2} m/s^1.75 \
         on its own) would take the day past the study's budget of A(8) {budget_a8} m/s² and VDV {budget_vdv} m/s^1.75 \
         (the exposure guard would stop it at once: nothing is left). The next test can run 24 h after the earliest of that day's tests.",
        so_far.a8(),
        so_far.vdv(),
        params.max_cab_rms_mm_s2 * 1e-3,
        worst.a8(),
        worst.vdv(),
    )))
}

/// The allowance a test of the subject on `seat` starts with now: none at the desk (nobody
/// rides the cab), else the remainder of the budget after the last 24 hours, or the 409.
pub async fn allowance_for(
    db: &mut AnyConnection,
    params: &StudyParams,
    subject: &Subject,
    seat: Seat,
    duration_s: f64,
) -> Result<Option<ExposureAllowance>> {
    if seat != Seat::On {
        return Ok(None);
    }
    let so_far = last_24h(db, params, subject.id, store::db::now_ms()).await?;
    allowance(params, &subject.code, so_far, duration_s).map(Some)
}

/// Which action values the day's sum reached with the last test (from `before` to `after`).
pub fn action_values_reached(before: DoseSum, after: DoseSum) -> Vec<&'static str> {
    let mut reached = Vec::new();
    if before.a8() < ACTION_A8_M_S2 && after.a8() >= ACTION_A8_M_S2 {
        reached.push("a8");
    }
    if before.vdv() < ACTION_VDV_M_S175 && after.vdv() >= ACTION_VDV_M_S175 {
        reached.push("vdv");
    }
    reached
}

#[cfg(test)]
mod tests {
    use super::*;
    use bdft_protocol::exposure::EIGHT_HOURS_S;

    /// A(8) as the energy it stands for over 8 h (m²/s³).
    fn a8_energy(a8: f64) -> f64 {
        a8 * a8 * EIGHT_HOURS_S
    }

    #[test]
    fn the_interlock_held_for_a_default_test_is_far_past_the_vdv_limit() {
        // The check the issue asked for: 6 m/s² held 140 s, W_d's peak 1.0126 → a_w 6.08;
        // eVDV = 1.4·6.0756·140^¼ = 29.26 > 21 (the limit value); A(8) = 6.08·√(140/28800)
        // = 0.42 m/s². Refusing on it would refuse every test: hence the guard.
        let params = crate::engine::study::schedule::default_params();
        let w = interlock_held(&params, 140.0);
        assert!((w.vdv() - 29.26).abs() < 0.01, "{}", w.vdv());
        assert!((w.a8() - 0.424).abs() < 0.002, "{}", w.a8());
    }

    #[test]
    fn a_test_is_refused_only_when_nothing_is_left_and_the_refusal_names_the_figures() {
        let params = crate::engine::study::schedule::default_params();
        let mut so_far = DoseSum::default();
        so_far.add(a8_energy(0.3), 5.0f64.powi(4));
        let left = allowance(&params, "S01", so_far, 140.0).unwrap();
        assert!((left.energy_m2_s3 - (a8_energy(0.5) - a8_energy(0.3))).abs() < 1e-6);
        assert!((left.vdv4_m4_s7 - (9.1f64.powi(4) - 625.0)).abs() < 1e-6);
        let mut spent = DoseSum::default();
        spent.add(a8_energy(0.2), 9.1f64.powi(4));
        let AppError::Conflict(msg) = allowance(&params, "S01", spent, 140.0).unwrap_err() else {
            panic!("a conflict")
        };
        for figure in [
            "A(8) 0.200",
            "VDV 9.10",
            "6.00 m/s²",
            "budget of A(8) 0.5",
            "VDV 9.1",
        ] {
            assert!(msg.contains(figure), "{figure}: {msg}");
        }
    }

    #[test]
    fn an_action_value_is_reached_once() {
        let mut before = DoseSum::default();
        before.add(a8_energy(0.45), 1.0);
        let mut after = before;
        after.add(a8_energy(0.3), 0.0);
        assert_eq!(action_values_reached(before, after), vec!["a8"]);
        assert!(action_values_reached(after, after).is_empty());
    }
}
