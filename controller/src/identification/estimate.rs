//! The feedthrough at the excited lines, from one identification test's record.
//!
//! The record (from t = 0) holds `transient_periods` periods, dropped, then `periods`
//! periods. Each recorded period p is Fourier-transformed at the excited bins k, giving
//! U_p(k) (cab acceleration) and Y_p(k) (device), and averaged: Ū, Ȳ. The estimate is
//! Ĥ = Ȳ/Ū, the errors-in-variables-robust estimator for periodic excitation (Pintelon &
//! Schoukens, *System Identification*, 2nd ed., §2.5): noise on the measured acceleration
//! and on the device (the remnant) averages out of both means instead of biasing Ĥ as a
//! cross-spectrum over an auto-spectrum would.
//!
//! Its variance comes from the period-to-period sample (co)variances of Y and U (P
//! periods, divided by P for the means), linearized (ibid., §2.5.3):
//! σ²_Ĥ = |Ĥ|²·(σ²_Ȳ/|Ȳ|² + σ²_Ū/|Ū|² − 2·Re(σ²_ȲŪ/(Ȳ·Ū*))).
//! Ĥ's error is circular complex normal with that variance, estimated from P − 1 complex
//! degrees of freedom, so |Ĥ − H|²/σ̂²_Ĥ follows F(2, 2P − 2) and the 95 % confidence disc
//! about Ĥ has radius r = σ̂_Ĥ·√F₀.₉₅(2, 2P − 2) (F(2, m) has the closed-form quantile
//! m/2·((1 − q)^(−2/m) − 1)). The magnitude bounds are |Ĥ| ± r (the lower one at least 0),
//! the phase bounds ± asin(r/|Ĥ|) (±180° when the disc holds the origin): the disc's
//! projections, so they hold jointly.
//!
//! The squared coherence over the periods is |Σ Y_p U_p*|²/(Σ|Y_p|²·Σ|U_p|²).

use bdft_protocol::identification::{FrfPoint, MultisineSpec};
use nalgebra::Complex;

use super::IdentificationError;
use super::multisine::{excited_bins, ticks_per_period};

/// The confidence of every interval the identification reports.
pub const CONFIDENCE: f64 = 0.95;

/// The q-quantile of the F(2, m) distribution (CDF 1 − (1 + 2x/m)^(−m/2)).
pub fn f2_quantile(q: f64, m: f64) -> f64 {
    m / 2.0 * ((1.0 - q).powf(-2.0 / m) - 1.0)
}

/// One excited line's averaged spectra and their period-to-period spread.
#[derive(Debug, Clone, Copy)]
struct LineSpectra {
    u: Complex<f64>,
    y: Complex<f64>,
    /// Variances of the means Ū, Ȳ and their covariance (Σ(Y−Ȳ)(U−Ū)*/(P(P−1))).
    var_u: f64,
    var_y: f64,
    cov_yu: Complex<f64>,
    coherence: f64,
}

/// Estimates the feedthrough device/cab acceleration at every excited line of `spec` from
/// a test's full record at `dt` (channels `cab_accel_mm_s2` and `device_mm` of
/// `RECORD_CHANNELS`, from t = 0). Magnitudes are in mm per m/s².
pub fn estimate(
    spec: &MultisineSpec,
    dt: f64,
    cab_accel_mm_s2: &[f32],
    device_mm: &[f32],
) -> Result<Vec<FrfPoint>, IdentificationError> {
    let bins = excited_bins(spec)?;
    let n = ticks_per_period(spec, dt)?;
    if cab_accel_mm_s2.len() != device_mm.len() {
        return Err(IdentificationError::Record(format!(
            "cab_accel_mm_s2 has {} samples but device_mm has {}",
            cab_accel_mm_s2.len(),
            device_mm.len()
        )));
    }
    let periods = spec.periods as usize;
    let start = spec.transient_periods as usize * n;
    let needed = start + periods * n;
    if cab_accel_mm_s2.len() < needed {
        return Err(IdentificationError::Record(format!(
            "{} samples; the test needs {needed} ({} transient and {periods} recorded periods \
             of {n} ticks)",
            cab_accel_mm_s2.len(),
            spec.transient_periods
        )));
    }
    let (u, y) = (&cab_accel_mm_s2[start..needed], &device_mm[start..needed]);
    for (name, xs) in [("cab_accel_mm_s2", u), ("device_mm", y)] {
        if let Some(i) = xs.iter().position(|x| !x.is_finite()) {
            return Err(IdentificationError::Record(format!(
                "{name} is not finite at sample {}",
                start + i
            )));
        }
    }
    // One period of the unit circle: bin k at sample t is turn (k·t mod n)/n.
    let twiddle: Vec<Complex<f64>> = (0..n)
        .map(|t| Complex::from_polar(1.0, -2.0 * std::f64::consts::PI * t as f64 / n as f64))
        .collect();
    let p = periods as f64;
    Ok(bins
        .iter()
        .map(|&k| {
            let dft = |xs: &[f32]| -> Complex<f64> {
                xs.iter()
                    .enumerate()
                    .map(|(t, &x)| twiddle[k * t % n] * f64::from(x))
                    .sum::<Complex<f64>>()
                    * (2.0 / n as f64)
            };
            let per: Vec<(Complex<f64>, Complex<f64>)> = (0..periods)
                .map(|i| (dft(&u[i * n..(i + 1) * n]), dft(&y[i * n..(i + 1) * n])))
                .collect();
            let line = spectra(&per, p);
            point(k as f64 / spec.period_s, &line, p)
        })
        .collect())
}

fn spectra(per: &[(Complex<f64>, Complex<f64>)], p: f64) -> LineSpectra {
    let u = per.iter().map(|(u, _)| u).sum::<Complex<f64>>() / p;
    let y = per.iter().map(|(_, y)| y).sum::<Complex<f64>>() / p;
    let (mut var_u, mut var_y, mut cov_yu) = (0.0, 0.0, Complex::new(0.0, 0.0));
    let (mut s_uu, mut s_yy, mut s_yu) = (0.0, 0.0, Complex::new(0.0, 0.0));
    for &(up, yp) in per {
        let (du, dy) = (up - u, yp - y);
        var_u += du.norm_sqr();
        var_y += dy.norm_sqr();
        cov_yu += dy * du.conj();
        s_uu += up.norm_sqr();
        s_yy += yp.norm_sqr();
        s_yu += yp * up.conj();
    }
    let of_mean = 1.0 / (p * (p - 1.0));
    LineSpectra {
        u,
        y,
        var_u: var_u * of_mean,
        var_y: var_y * of_mean,
        cov_yu: cov_yu * of_mean,
        coherence: s_yu.norm_sqr() / (s_uu * s_yy),
    }
}

fn point(f_hz: f64, s: &LineSpectra, p: f64) -> FrfPoint {
    // mm per (mm/s²) → mm per (m/s²).
    let h = s.y / s.u * 1e3;
    let rel = s.var_y / s.y.norm_sqr() + s.var_u / s.u.norm_sqr()
        - 2.0 * (s.cov_yu / (s.y * s.u.conj())).re;
    let var_h = h.norm_sqr() * rel.max(0.0);
    let r = (var_h * f2_quantile(CONFIDENCE, 2.0 * p - 2.0)).sqrt();
    let (mag, phase) = (h.norm(), h.arg().to_degrees());
    let dphase = if r < mag {
        (r / mag).asin().to_degrees()
    } else {
        180.0
    };
    FrfPoint {
        f_hz,
        magnitude: mag,
        magnitude_lo: (mag - r).max(0.0),
        magnitude_hi: mag + r,
        phase_deg: phase,
        phase_lo_deg: phase - dphase,
        phase_hi_deg: phase + dphase,
        coherence: s.coherence,
        std_dev: var_h.sqrt(),
        periods: p as u32,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_f2_quantile_inverts_its_cdf() {
        // F(2, m) → χ²₂/2 as m → ∞: the 95 % point is ln 20.
        assert!((f2_quantile(0.95, 1e9) - 20f64.ln()).abs() < 1e-6);
        // m = 10: 5·(0.05^(−0.2) − 1) = 4.1028 (tables: F₀.₉₅(2, 10) = 4.10).
        assert!((f2_quantile(0.95, 10.0) - 4.1028).abs() < 1e-4);
    }

    /// A record in which the device is exactly g times the acceleration at every line, with
    /// `noise` (mm) added to the device from a fixed sequence.
    fn record(
        spec: &MultisineSpec,
        g: Complex<f64>,
        noise: f64,
        seed: u64,
    ) -> (Vec<f32>, Vec<f32>) {
        let m = crate::identification::Multisine::new(spec, 1e-3).unwrap();
        let n = m.period_ticks();
        let total = (spec.transient_periods + spec.periods) as usize * n;
        let mut rng = crate::rng::Rng::new(seed);
        let (mut u, mut y) = (vec![], vec![]);
        for t in 0..total {
            let (mut a, mut d) = (0.0, 0.0);
            for l in &m.lines {
                let phase = 2.0 * std::f64::consts::PI * (l.bin * t % n) as f64 / n as f64;
                let x = Complex::from_polar(l.amplitude_mm * 100.0, phase + l.phase);
                a += x.re;
                // g in mm per m/s²: device = g·1e-3·acceleration.
                d += (x * g * 1e-3).re;
            }
            u.push(a as f32);
            y.push((d + noise * rng.normal()) as f32);
        }
        (u, y)
    }

    #[test]
    fn a_known_response_is_recovered_with_bounds_that_hold_it() {
        let spec = MultisineSpec {
            period_s: 2.0,
            lines: 8,
            periods: 4,
            ..MultisineSpec::default()
        };
        let g = Complex::from_polar(3.0, 0.7);
        let (u, y) = record(&spec, g, 0.0, 5);
        for p in estimate(&spec, 1e-3, &u, &y).unwrap() {
            assert!((p.magnitude - 3.0).abs() < 1e-4 && (p.phase_deg - 40.107).abs() < 0.01);
            assert!(p.coherence > 0.999_999 && p.periods == 4);
        }
        // With noise, the 95 % disc about each estimate holds the truth 95 % of the time:
        // 20 records × 15 lines.
        let spec = MultisineSpec { lines: 15, ..spec };
        let (mut inside, mut all) = (0, 0);
        for seed in 0..20 {
            let (u, y) = record(&spec, g, 0.5, seed);
            for p in estimate(&spec, 1e-3, &u, &y).unwrap() {
                let h = Complex::from_polar(p.magnitude, p.phase_deg.to_radians());
                let r = p.magnitude_hi - p.magnitude;
                inside += usize::from((h - g).norm() <= r);
                all += 1;
                assert!(p.std_dev > 0.0 && p.coherence < 1.0);
            }
        }
        let share = inside as f64 / all as f64;
        assert!((0.9..=0.99).contains(&share), "{inside} of {all}");
    }

    #[test]
    fn a_record_that_cannot_be_estimated_says_why() {
        let spec = MultisineSpec {
            period_s: 2.0,
            lines: 8,
            periods: 2,
            ..MultisineSpec::default()
        };
        let (u, y) = record(&spec, Complex::new(1.0, 0.0), 0.0, 5);
        let err = |u: &[f32], y: &[f32]| estimate(&spec, 1e-3, u, y).unwrap_err().to_string();
        assert!(err(&u[..5_000], &y[..5_000]).contains("needs 6000"));
        assert!(err(&u, &y[1..]).contains("device_mm has 5999"));
        let mut bad = y.clone();
        bad[4_321] = f32::NAN;
        assert!(err(&u, &bad).contains("device_mm is not finite at sample 4321"));
        let mut bad = u.clone();
        bad[2_000] = f32::INFINITY;
        assert!(err(&bad, &y).contains("cab_accel_mm_s2 is not finite at sample 2000"));
        // The transient is not looked at.
        let mut early = u.clone();
        early[10] = f32::NAN;
        assert!(estimate(&spec, 1e-3, &early, &y).is_ok());
        let at = estimate(&spec, 1.5e-3, &u, &y).unwrap_err().to_string();
        assert!(at.contains("whole number of ticks"), "{at}");
    }
}
