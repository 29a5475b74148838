//! The learning curve: each subject's tracking error against the test's position in their
//! session (1 … 2k across both seats, k compensators), the median per seat and position,
//! and the learning slope. The same attempts count as in the box plots and statistics
//! (`study_data::analysable`).

use std::collections::BTreeMap;

use serde::Serialize;
use sqlx::AnyPool;

use super::inference::quantile::quantile;
use super::study_data::analysable;
use crate::error::Result;
use crate::store;

/// The unit of a learning slope.
pub const SLOPE_UNIT: &str = "ln(mm²) per test position";

/// One test of a subject on the curve.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct CurvePoint {
    /// 1 … 2k: the scored test's place in the subject's session, both seats counted.
    pub position: u32,
    /// `on` or `off` (the API's key: `station`).
    #[serde(rename = "station")]
    pub seat: String,
    /// The API's key: `controller`.
    #[serde(rename = "controller")]
    pub compensator: String,
    pub mse_tracking_mm2: f64,
}

/// One subject's curve.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct SubjectCurve {
    pub code: String,
    /// In position order.
    pub points: Vec<CurvePoint>,
    /// Least-squares slope of ln(MSE) on position (`SLOPE_UNIT`); none with fewer than two
    /// tests.
    pub slope: Option<f64>,
}

/// The median over subjects at one seat and position.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct MedianPoint {
    /// The API's key: `station`.
    #[serde(rename = "station")]
    pub seat: String,
    pub position: u32,
    pub mse_tracking_mm2: f64,
    /// Subjects with a value here.
    pub n: usize,
}

/// A study's learning curve and slope.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct LearningCurve {
    /// Scored tests per subject: positions run from 1 to this.
    pub positions: u32,
    pub subjects: Vec<SubjectCurve>,
    /// By seat, then position.
    pub median: Vec<MedianPoint>,
    /// The learning slope: the median over subjects of their slopes (`SLOPE_UNIT`; negative
    /// when error falls with practice); none before any subject has two tests.
    pub slope: Option<f64>,
    pub slope_unit: String,
    /// The slope as the change of error per test: 100·(e^slope − 1) %.
    pub slope_percent_per_test: Option<f64>,
    /// Subjects whose slope entered the median.
    pub slope_n: usize,
}

/// The least-squares slope of y on x; none without two distinct x.
pub fn ls_slope(points: &[(f64, f64)]) -> Option<f64> {
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (points.len() >= 2 && sxx > 0.0).then(|| sxy / sxx)
}

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    quantile(&xs, 0.5)
}

impl LearningCurve {
    /// From each subject's (code, points) in enrolment order, points in any order.
    pub fn from_points(positions: u32, subjects: Vec<(String, Vec<CurvePoint>)>) -> Self {
        let subjects: Vec<SubjectCurve> = subjects
            .into_iter()
            .map(|(code, mut points)| {
                points.sort_by_key(|p| p.position);
                let logs: Vec<(f64, f64)> = points
                    .iter()
                    .filter(|p| p.mse_tracking_mm2 > 0.0)
                    .map(|p| (f64::from(p.position), p.mse_tracking_mm2.ln()))
                    .collect();
                SubjectCurve {
                    code,
                    slope: ls_slope(&logs),
                    points,
                }
            })
            .collect();
        let mut cells: BTreeMap<(String, u32), Vec<f64>> = BTreeMap::new();
        for p in subjects.iter().flat_map(|s| &s.points) {
            cells
                .entry((p.seat.clone(), p.position))
                .or_default()
                .push(p.mse_tracking_mm2);
        }
        let median_points = cells
            .into_iter()
            .map(|((seat, position), xs)| MedianPoint {
                seat,
                position,
                n: xs.len(),
                mse_tracking_mm2: median(xs),
            })
            .collect();
        let slopes: Vec<f64> = subjects.iter().filter_map(|s| s.slope).collect();
        let slope = (!slopes.is_empty()).then(|| median(slopes.clone()));
        Self {
            positions,
            median: median_points,
            slope,
            slope_unit: SLOPE_UNIT.into(),
            slope_percent_per_test: slope.map(|b| 100.0 * (b.exp() - 1.0)),
            slope_n: slopes.len(),
            subjects,
        }
    }
}

/// The study's learning curve from its trials.
pub async fn learning_curve(pool: &AnyPool, study_id: i64) -> Result<LearningCurve> {
    let study = store::studies::get(pool, study_id).await?;
    let k = study.params.compensators.len() as u32;
    let rows =
        store::exports::trial_rows(pool, study_id, store::exports::Withdrawn::LeftOut).await?;
    let mut by_subject: BTreeMap<i64, (String, Vec<CurvePoint>)> = BTreeMap::new();
    for r in analysable(&rows) {
        let Some(mse) = r.mse_tracking_mm2 else {
            continue;
        };
        by_subject
            .entry(r.enrol_index)
            .or_insert_with(|| (r.code.clone(), vec![]))
            .1
            .push(CurvePoint {
                position: (r.block as u32 - 1) * k + r.position as u32,
                seat: r.station.as_str().into(),
                compensator: r.controller.name().into(),
                mse_tracking_mm2: mse,
            });
    }
    Ok(LearningCurve::from_points(
        2 * k,
        by_subject.into_values().collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(position: u32, seat: &str, mse: f64) -> CurvePoint {
        CurvePoint {
            position,
            seat: seat.into(),
            compensator: "pid".into(),
            mse_tracking_mm2: mse,
        }
    }

    #[test]
    fn the_slope_is_the_median_of_each_subjects_log_error_slope() {
        // S01: error halves every test → slope ln(1/2) exactly. S02: y = ln 100 + (0, 1, 1, 3)
        // at x = 1..4: x̄ = 2.5, ȳ − ln 100 = 1.25, Sxy = (−1.5)(−1.25) + (−0.5)(−0.25)
        // + (0.5)(−0.25) + (1.5)(1.75) = 4.5, Sxx = 5 → 0.9. S03: one test, no slope.
        let e = std::f64::consts::E;
        let s01 = (1..=4)
            .map(|p| {
                point(
                    p,
                    if p <= 2 { "on" } else { "off" },
                    80.0 / 2f64.powi(p as i32),
                )
            })
            .collect();
        let s02 = vec![
            point(4, "on", 100.0 * e.powi(3)),
            point(1, "off", 100.0),
            point(2, "off", 100.0 * e),
            point(3, "on", 100.0 * e),
        ];
        let s03 = vec![point(1, "on", 7.0)];
        let c = LearningCurve::from_points(
            4,
            vec![
                ("S01".into(), s01),
                ("S02".into(), s02),
                ("S03".into(), s03),
            ],
        );
        let slopes: Vec<Option<f64>> = c.subjects.iter().map(|s| s.slope).collect();
        assert!((slopes[0].unwrap() - 0.5f64.ln()).abs() < 1e-12);
        assert!((slopes[1].unwrap() - 0.9).abs() < 1e-12);
        assert_eq!(slopes[2], None);
        // The median of two slopes is their mean.
        assert!((c.slope.unwrap() - (0.5f64.ln() + 0.9) / 2.0).abs() < 1e-12);
        assert_eq!(c.slope_n, 2);
        assert_eq!(c.slope_unit, SLOPE_UNIT);
        // Points in position order; medians per seat and position over who was there.
        assert_eq!(
            c.subjects[1]
                .points
                .iter()
                .map(|p| p.position)
                .collect::<Vec<_>>(),
            [1, 2, 3, 4]
        );
        let at = |seat: &str, position| {
            c.median
                .iter()
                .find(|m| m.seat == seat && m.position == position)
                .map(|m| (m.mse_tracking_mm2, m.n))
        };
        // Position 1: S01 at the machine (40), S02 off (100), S03 on (7).
        assert_eq!(at("on", 1), Some((23.5, 2)));
        assert_eq!(at("off", 1), Some((100.0, 1)));
        assert_eq!(at("on", 2), Some((20.0, 1)));
        assert_eq!(at("off", 2), Some((100.0 * e, 1)));
    }

    #[test]
    fn a_study_without_tests_has_no_slope() {
        let c = LearningCurve::from_points(10, vec![]);
        assert_eq!((c.slope, c.slope_n, c.median.len()), (None, 0, 0));
        assert_eq!(ls_slope(&[(1.0, 2.0), (1.0, 3.0)]), None);
    }
}
