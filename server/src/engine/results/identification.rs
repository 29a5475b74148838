//! A subject's identification tests as the dashboard draws them (a Bode plot of the
//! feedthrough, device position over cab acceleration): the measured points with their
//! bounds, the seated body fitted to them as a curve, and the band the study's synthetic
//! population spans — so an experimenter sees at a glance whether this person's
//! feedthrough is typical of the population the study's designs and dry runs assume.

use bdft_controller::analysis::frequency::log_grid;
use bdft_controller::identification::fit;
use bdft_controller::population;
use bdft_protocol::params::{BodyModel, MAX_KBF, check};
use bdft_protocol::study::StudyParams;
use nalgebra::Complex;
use serde::Serialize;
use sqlx::AnyPool;

use super::inference::quantile::quantile;
use crate::engine::COMPUTE;
use crate::engine::machine::workbench_analysis::params_for;
use crate::engine::study::stability::{StabilityCache, StabilityReport};
use crate::engine::study::synthetic;
use crate::error::{AppError, Result};
use crate::store;
use crate::store::identifications::Identification;

/// The population band's subjects: enough for the 2.5 and 97.5 % points to move less than
/// the plot's line width from one set of draws to another.
const BAND_SUBJECTS: u32 = 400;
/// Frequencies of the curves (log-spaced over the excited band).
const CURVE_POINTS: usize = 60;

/// The feedthrough of a body at one frequency.
#[derive(Debug, Clone, Copy, Serialize, utoipa::ToSchema)]
pub struct CurvePoint {
    pub f_hz: f64,
    /// mm per m/s².
    pub magnitude: f64,
    pub phase_deg: f64,
}

/// The population's spread at one frequency: 2.5 %, 50 % and 97.5 % of the magnitude and
/// 2.5 % and 97.5 % of the phase over its subjects.
#[derive(Debug, Clone, Copy, Serialize, utoipa::ToSchema)]
pub struct BandPoint {
    pub f_hz: f64,
    pub magnitude_lo: f64,
    pub magnitude_median: f64,
    pub magnitude_hi: f64,
    pub phase_lo_deg: f64,
    pub phase_hi_deg: f64,
}

/// What the subject page's identification plot shows.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct IdentificationView {
    /// Every completed identification test of the subject, oldest first.
    pub tests: Vec<Identification>,
    /// The body fitted by the latest test with a fit, over the band; empty when that fit
    /// left a parameter not identified (`BodyFit::identified_body`).
    pub fitted: Vec<CurvePoint>,
    /// The study's synthetic population over the band (its drawn bodies, or only the
    /// study's preset body when the population does not draw bodies).
    pub population: Vec<BandPoint>,
}

pub async fn view(pool: &AnyPool, subject_id: i64) -> Result<IdentificationView> {
    let subject = store::subjects::get(pool, subject_id).await?;
    let study = store::studies::get(pool, subject.study_id).await?;
    let tests = store::identifications::of_subject(pool, subject_id).await?;
    let grid = grid(&study.params);
    let fitted = tests
        .iter()
        .rev()
        .find_map(|t| t.fit.as_ref())
        .and_then(|f| f.identified_body().ok())
        .map(|body| curve(&body, &grid))
        .unwrap_or_default();
    let population = band(&study.params, study.seed, &grid);
    Ok(IdentificationView {
        tests,
        fitted,
        population,
    })
}

/// Every design of the subject's study checked against the subject's own identified body.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct SubjectStability {
    pub subject: String,
    /// The body fitted by the subject's latest identification test with a fit.
    pub body: BodyModel,
    /// Each design at `k_bf` with this body, on and off the machine, and its margin (the
    /// largest stable K_BF for this subject).
    pub report: StabilityReport,
}

/// Is each of the study's designs stable for this subject at `k_bf` (default the
/// study's), and with what margin? The gate's analysis on the study's plant with the body
/// the subject's identification test fitted; a 409 when the subject has none yet.
pub async fn subject_stability(
    pool: &AnyPool,
    cache: &StabilityCache,
    subject_id: i64,
    k_bf: Option<f64>,
) -> Result<SubjectStability> {
    let subject = store::subjects::get(pool, subject_id).await?;
    let study = store::studies::get(pool, subject.study_id).await?;
    let mut params = params_for(pool, &study, Some(subject_id)).await?;
    if let Some(k) = k_bf {
        check("k_bf", k, 0.01, MAX_KBF).map_err(|e| AppError::BadRequest(e.to_string()))?;
        params.k_bf = k;
    }
    // The analysis takes seconds: one heavy read at a time, as the workbench's.
    let _turn = COMPUTE.acquire().await.expect("never closed");
    Ok(SubjectStability {
        subject: subject.code,
        body: params.body,
        report: cache.report(&params).await?,
    })
}

/// Log-spaced frequencies over the study's excited band (or the default multisine's).
fn grid(params: &StudyParams) -> Vec<f64> {
    let m = params
        .identification
        .as_ref()
        .map(|i| i.excitation)
        .unwrap_or_default();
    log_grid(m.f_min_hz, m.f_max_hz, CURVE_POINTS)
}

/// A body's feedthrough device/ẍ_c at `f_hz` (mm per m/s²): the device reads −h, and the
/// cab's displacement is −ẍ_c/ω², so it is (h/x_c)/ω².
fn feedthrough(body: &BodyModel, f_hz: f64) -> Complex<f64> {
    let w2 = (2.0 * std::f64::consts::PI * f_hz).powi(2);
    if let Some(seated) = body.seated_params() {
        return fit::feedthrough(&seated.map(f64::ln), f_hz);
    }
    match *body {
        BodyModel::Seated { .. } => unreachable!("a seated body has its parameters"),
        BodyModel::RigidMass { k_h } => Complex::from(k_h * 1e3 / w2),
        BodyModel::SingleResonance {
            k_h,
            f_hz: f0,
            zeta,
        } => {
            let (w0, s) = (
                2.0 * std::f64::consts::PI * f0,
                Complex::new(0.0, w2.sqrt()),
            );
            let num = s * (2.0 * zeta * w0) + w0 * w0;
            num / (s * s + num) * (k_h * 1e3 / w2)
        }
    }
}

fn curve(body: &BodyModel, grid: &[f64]) -> Vec<CurvePoint> {
    grid.iter()
        .map(|&f_hz| {
            let h = feedthrough(body, f_hz);
            CurvePoint {
                f_hz,
                magnitude: h.norm(),
                phase_deg: h.arg().to_degrees(),
            }
        })
        .collect()
}

/// The spread of the population's feedthrough: its first `BAND_SUBJECTS` subjects as the
/// study's seed enrols them.
fn band(params: &StudyParams, seed: u64, grid: &[f64]) -> Vec<BandPoint> {
    let curves: Vec<Vec<CurvePoint>> = (0..BAND_SUBJECTS)
        .map(|i| {
            let d = synthetic::draw(params, seed, i);
            curve(&population::body(&d, params.body), grid)
        })
        .collect();
    grid.iter()
        .enumerate()
        .map(|(k, &f_hz)| {
            let sorted = |f: fn(&CurvePoint) -> f64| {
                let mut v: Vec<f64> = curves.iter().map(|c| f(&c[k])).collect();
                v.sort_by(f64::total_cmp);
                v
            };
            let (mag, phase) = (sorted(|p| p.magnitude), sorted(|p| p.phase_deg));
            BandPoint {
                f_hz,
                magnitude_lo: quantile(&mag, 0.025),
                magnitude_median: quantile(&mag, 0.5),
                magnitude_hi: quantile(&mag, 0.975),
                phase_lo_deg: quantile(&phase, 0.025),
                phase_hi_deg: quantile(&phase, 0.975),
            }
        })
        .collect()
}
