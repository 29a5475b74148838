//! The seated body fitted to a measured feedthrough.
//!
//! On the rig the body moves the hand by h = k_h·(1 − T·A)·x_c (`model::body`), the device
//! reads p_h − h and the seat accelerometer reads ẍ_c plus white noise (no filter:
//! `Plant::measure`), both at the same instant of the tick. With x_c = −ẍ_c/ω² at a line,
//! the feedthrough the estimator measures is
//!
//!   G(jω) = device/ẍ_c = k_h·(1 − T(jω)·A(jω))/ω²   (×1000 for mm per m/s²),
//!
//! T and A the torso's and the arm's base-excitation transmissibilities
//! (2ζωs + ω²)/(s² + 2ζωs + ω²). The simulated body is their Tustin discretization,
//! prewarped at each peak: at the band's top (8 Hz at 1 kHz) it differs from the
//! continuous response by 2·10⁻⁴ in frequency, far below any measured precision, so the fit
//! uses the continuous model.
//!
//! **The fit.** θ = ln(k_h, f_t, ζ_t, f_a, ζ_a) (`BodyFit::PARAMETERS`' order); the residual at a point is the complex log
//! ratio ln(G(jω; θ)/Ĥ) (phase wrapped), weighted by √2·|Ĥ|/σ_Ĥ — the standard deviation of
//! each of its real and imaginary parts to first order — so the cost is χ² when the points'
//! variances are right. Levenberg–Marquardt from a few starting bodies (the torso and arm
//! frequencies on a small grid, k_h from the band's top where G → k_h/ω²), the best kept.
//! T·A is symmetric in torso and arm, so the fit names the lower resonance the torso.
//!
//! **Intervals.** The covariance of θ̂ is (JᵀJ)⁻¹ of the weighted residuals' Jacobian;
//! 95 % intervals are θ̂ ± t·σ, mapped back by exp. t is Student's quantile for the points'
//! variances' degrees of freedom, 2(P − 1): the weights are estimated from P periods, not
//! known (module docs of `estimate`). A parameter whose interval spans more than a factor
//! of 10, or lies along a direction where the information matrix is singular, is named in
//! `unidentified` with why (a singular direction's parameters get the interval [0, f64::MAX],
//! which the API and the exports report as no interval: `BodyFit::report`).

use std::collections::BTreeMap;
use std::f64::consts::PI;

use bdft_protocol::identification::{BodyFit, Estimate, FrfPoint, MultisineSpec};
use nalgebra::{Complex, DMatrix, DVector, SMatrix, SVector};

use super::IdentificationError;
use super::estimate::{CONFIDENCE, estimate};
use crate::special::beta_inc;

type Theta = SVector<f64, 5>;
type Info = SMatrix<f64, 5, 5>;

/// An interval wider than this factor (hi/lo) means the data did not pin the parameter.
const UNIDENTIFIED_SPAN: f64 = 10.0;

/// The base-excitation transmissibility at s.
fn transmissibility(s: Complex<f64>, f_hz: f64, zeta: f64) -> Complex<f64> {
    let w = 2.0 * PI * f_hz;
    let num = s * (2.0 * zeta * w) + w * w;
    num / (s * s + num)
}

/// The seated body's feedthrough device/ẍ_c at f_hz (mm per m/s²) for θ = ln(parameters).
pub fn feedthrough(theta: &[f64; 5], f_hz: f64) -> Complex<f64> {
    let [k, ft, zt, fa, za] = theta.map(f64::exp);
    let w = 2.0 * PI * f_hz;
    let s = Complex::new(0.0, w);
    (Complex::from(1.0) - transmissibility(s, ft, zt) * transmissibility(s, fa, za)) * (k * 1e3)
        / (w * w)
}

/// A point ready for the fit: its frequency, ln Ĥ and the weight of its log residual.
struct Weighted {
    f_hz: f64,
    log_h: Complex<f64>,
    weight: f64,
}

fn wrap(phase: f64) -> f64 {
    (phase + PI).rem_euclid(2.0 * PI) - PI
}

/// Weighted residuals [Re, Im] per point.
fn residuals(theta: &Theta, points: &[Weighted]) -> DVector<f64> {
    let t: [f64; 5] = (*theta).into();
    let mut r = DVector::zeros(2 * points.len());
    for (i, p) in points.iter().enumerate() {
        let e = feedthrough(&t, p.f_hz).ln() - p.log_h;
        r[2 * i] = e.re * p.weight;
        r[2 * i + 1] = wrap(e.im) * p.weight;
    }
    r
}

/// The residuals' Jacobian in θ, by central differences.
fn jacobian(theta: &Theta, points: &[Weighted]) -> DMatrix<f64> {
    let h = 1e-6;
    let mut j = DMatrix::zeros(2 * points.len(), 5);
    for c in 0..5 {
        let (mut up, mut down) = (*theta, *theta);
        up[c] += h;
        down[c] -= h;
        let (ru, rd) = (residuals(&up, points), residuals(&down, points));
        for r in 0..ru.len() {
            // The phase residual is wrapped: a difference across ±π is the short way round.
            let d = if r % 2 == 1 {
                wrap(ru[r] / points[r / 2].weight - rd[r] / points[r / 2].weight)
                    * points[r / 2].weight
            } else {
                ru[r] - rd[r]
            };
            j[(r, c)] = d / (2.0 * h);
        }
    }
    j
}

/// Levenberg–Marquardt from `theta`: the minimum found and its cost.
fn levenberg_marquardt(mut theta: Theta, points: &[Weighted]) -> (Theta, f64) {
    let mut r = residuals(&theta, points);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..200 {
        let j = jacobian(&theta, points);
        let jtj: Info = Info::from_iterator((j.transpose() * &j).iter().copied());
        let g: Theta = Theta::from_iterator((j.transpose() * &r).iter().copied());
        let mut improved = false;
        while lambda < 1e10 {
            let mut a = jtj;
            for d in 0..5 {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            // Steps of more than a factor e^2 at once leave the model's region of sense.
            let step = step.map(|x| x.clamp(-2.0, 2.0));
            let trial = theta + step;
            let rt = residuals(&trial, points);
            let ct = rt.norm_squared();
            if ct.is_finite() && ct < cost {
                let small = cost - ct < 1e-10 * cost.max(1e-300) || step.norm() < 1e-10;
                theta = trial;
                r = rt;
                cost = ct;
                lambda = (lambda / 10.0).max(1e-12);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (theta, cost)
}

/// Student's t quantile q for `dof` degrees of freedom, by bisection on its CDF (the
/// regularized incomplete beta function, `special::beta_inc`).
pub fn t_quantile(q: f64, dof: f64) -> f64 {
    let cdf = |t: f64| {
        let x = dof / (dof + t * t);
        let tail = 0.5 * beta_inc(dof / 2.0, 0.5, x);
        if t >= 0.0 { 1.0 - tail } else { tail }
    };
    let (mut lo, mut hi) = (0.0, 1e3);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cdf(mid) < q {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Fits the seated body to measured feedthrough points (module doc).
pub fn fit_body(points: &[FrfPoint]) -> Result<BodyFit, IdentificationError> {
    if points.len() < 3 {
        return Err(IdentificationError::Fit(format!(
            "{} points; the seated body's 5 parameters need at least 3 (6 numbers)",
            points.len()
        )));
    }
    let mut weighted = Vec::with_capacity(points.len());
    for p in points {
        let h = Complex::from_polar(p.magnitude, p.phase_deg.to_radians());
        if !(p.f_hz > 0.0 && p.magnitude > 0.0 && p.std_dev > 0.0 && h.re.is_finite()) {
            return Err(IdentificationError::Fit(format!(
                "the point at {} Hz has no usable estimate (magnitude {}, std_dev {})",
                p.f_hz, p.magnitude, p.std_dev
            )));
        }
        weighted.push(Weighted {
            f_hz: p.f_hz,
            log_h: h.ln(),
            weight: std::f64::consts::SQRT_2 * p.magnitude / p.std_dev,
        });
    }
    // k_h from the top of the band, where G → k_h/ω²·1000.
    let mut top: Vec<f64> = points
        .iter()
        .map(|p| (p.f_hz, p.magnitude * (2.0 * PI * p.f_hz).powi(2) * 1e-3))
        .filter(|(f, _)| *f >= points.iter().fold(0.0f64, |m, p| m.max(p.f_hz)) * 0.6)
        .map(|(_, k)| k)
        .collect();
    top.sort_by(f64::total_cmp);
    let k0 = top
        .get(top.len() / 2)
        .copied()
        .unwrap_or(0.5)
        .clamp(0.01, 100.0);
    let mut best: Option<(Theta, f64)> = None;
    for ft in [0.7, 1.1, 1.7] {
        for fa in [1.5, 2.2, 3.3] {
            let start = Theta::from([k0.ln(), f64::ln(ft), 0.4f64.ln(), f64::ln(fa), 0.35f64.ln()]);
            let (theta, cost) = levenberg_marquardt(start, &weighted);
            if cost.is_finite() && best.is_none_or(|(_, c)| cost < c) {
                best = Some((theta, cost));
            }
        }
    }
    let (mut theta, _) =
        best.ok_or_else(|| IdentificationError::Fit("no start converged".into()))?;
    if theta[1] > theta[3] {
        theta.swap_rows(1, 3);
        theta.swap_rows(2, 4);
    }
    let j = jacobian(&theta, &weighted);
    let info = Info::from_iterator((j.transpose() * &j).iter().copied());
    let eig = info.symmetric_eigen();
    let max_eig = eig.eigenvalues.max();
    let mut cov = Info::zeros();
    let mut singular = [false; 5];
    for (i, &l) in eig.eigenvalues.iter().enumerate() {
        let v = eig.eigenvectors.column(i);
        if l > 1e-10 * max_eig && l > 0.0 {
            cov += v * v.transpose() / l;
        } else {
            for (p, s) in singular.iter_mut().enumerate() {
                *s |= v[p].abs() > 0.1;
            }
        }
    }
    let periods = points.iter().map(|p| p.periods).min().unwrap_or(2).max(2);
    let t = t_quantile(0.5 + CONFIDENCE / 2.0, 2.0 * f64::from(periods) - 2.0);
    let mut unidentified = BTreeMap::new();
    let est: Vec<Estimate> = (0..5)
        .map(|p| {
            let value = theta[p].exp();
            let half = t * cov[(p, p)].sqrt();
            let (lo, hi, why) = if singular[p] || !half.is_finite() {
                let why = "the data carry no information on it (the fit's information matrix is singular along it)";
                (0.0, f64::MAX, Some(why.to_string()))
            } else {
                let (lo, hi) = ((theta[p] - half).exp(), (theta[p] + half).exp());
                let span = hi / lo;
                let why = if span.is_nan() {
                    Some("its 95 % interval could not be computed".to_string())
                } else {
                    (span > UNIDENTIFIED_SPAN).then(|| {
                        format!(
                            "its 95 % interval spans a factor of {span:.3e}, more than {UNIDENTIFIED_SPAN}"
                        )
                    })
                };
                (lo, hi, why)
            };
            if let Some(why) = why {
                unidentified.insert(BodyFit::PARAMETERS[p].to_string(), why);
            }
            Estimate { value, lo, hi }
        })
        .collect();
    let t5: [f64; 5] = theta.into();
    let residual_rms = (weighted
        .iter()
        .map(|p| {
            let e = feedthrough(&t5, p.f_hz).ln() - p.log_h;
            e.re * e.re + wrap(e.im).powi(2)
        })
        .sum::<f64>()
        / weighted.len() as f64)
        .sqrt();
    Ok(BodyFit {
        k_h: est[0],
        torso_f_hz: est[1],
        torso_zeta: est[2],
        arm_f_hz: est[3],
        arm_zeta: est[4],
        residual_rms,
        unidentified,
    })
}

/// Estimates the feedthrough from a test's record and fits the seated body to it.
pub fn identify(
    spec: &MultisineSpec,
    dt: f64,
    cab_accel_mm_s2: &[f32],
    device_mm: &[f32],
) -> Result<(Vec<FrfPoint>, BodyFit), IdentificationError> {
    let points = estimate(spec, dt, cab_accel_mm_s2, device_mm)?;
    let fit = fit_body(&points)?;
    Ok((points, fit))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn students_quantiles_match_the_tables() {
        for (dof, want) in [(2.0, 4.302_653), (5.0, 2.570_582), (10.0, 2.228_139)] {
            let t = t_quantile(0.975, dof);
            assert!((t - want).abs() < 1e-5, "{dof}: {t}");
        }
        assert!((t_quantile(0.975, 1e6) - 1.959_966).abs() < 1e-4);
    }

    #[test]
    fn exact_points_give_back_the_body_and_too_few_are_refused() {
        let truth = [0.55f64, 1.2, 0.35, 2.4, 0.3];
        let theta = truth.map(f64::ln);
        let points: Vec<FrfPoint> = (0..20)
            .map(|i| {
                let f_hz = 0.5 * 16f64.powf(i as f64 / 19.0);
                let g = feedthrough(&theta, f_hz);
                // A 1 % spread, as if measured; the values themselves exact.
                let sd = 0.01 * g.norm();
                FrfPoint {
                    f_hz,
                    magnitude: g.norm(),
                    magnitude_lo: g.norm() - 2.0 * sd,
                    magnitude_hi: g.norm() + 2.0 * sd,
                    phase_deg: g.arg().to_degrees(),
                    phase_lo_deg: g.arg().to_degrees() - 1.0,
                    phase_hi_deg: g.arg().to_degrees() + 1.0,
                    coherence: 1.0,
                    std_dev: sd,
                    periods: 6,
                }
            })
            .collect();
        let fit = fit_body(&points).unwrap();
        for (e, t) in [
            fit.k_h,
            fit.torso_f_hz,
            fit.torso_zeta,
            fit.arm_f_hz,
            fit.arm_zeta,
        ]
        .iter()
        .zip(truth)
        {
            assert!((e.value / t - 1.0).abs() < 1e-6, "{e:?} vs {t}");
            assert!(e.lo < t && t < e.hi);
        }
        assert!(fit.residual_rms < 1e-6 && fit.unidentified.is_empty());
        let err = fit_body(&points[..2]).unwrap_err().to_string();
        assert!(err.contains("at least 3"), "{err}");
        // Three points cannot pin five parameters.
        let few = fit_body(&points[..3]).unwrap();
        assert!(!few.unidentified.is_empty(), "{few:?}");
    }
}
