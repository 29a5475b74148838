//! What a fit says of itself and of what it did not fit: each metric's model discrepancy,
//! the goodness-of-fit verdict, the parameters left at a bound, and the 95 % prediction
//! interval of every cell × metric outside the fitted target. The arithmetic only: `fit`
//! gives it the residuals, weights, Jacobians and bootstrap draws.
//!
//! Discrepancy: per metric, the variance τ²_m of the model's own error on a cell's log
//! mean, by the method of moments from that metric's fitted moments: with residuals r_i and
//! variances v_i (target + Monte-Carlo), E[Σ r_i²] ≈ (1 − p/N) Σ v_i + n_m τ²_m (p
//! identified parameters, N moments, n_m the metric's), so τ²_m = max(0, (Σ r_i² −
//! (1 − p/N) Σ v_i) / n_m): 0 when the metric's misfit is no more than what the Monte-Carlo
//! and target errors allow. A metric with no fitted moment has an unknown discrepancy (None),
//! which its intervals leave out and say so.
//!
//! Verdict: the misfit X² = Σ w_i r_i² (w = 1/v, the fit's criterion at its optimum) against
//! χ² with N − p degrees of freedom; "lack of fit" at p < `LACK_OF_FIT_P`, naming the worst
//! moments by |z| = |r|·√w. The target's cells share the people who gave them, which the
//! criterion's diagonal weights leave out, so the χ² is approximate.

use bdft_controller::special::gamma_q;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::target::Metric;

/// Below this p-value the verdict is "lack of fit".
pub const LACK_OF_FIT_P: f64 = 0.05;

/// Within this distance in log of a bound, a parameter is "at its bound" (1 %).
pub const AT_BOUND_LOG: f64 = 0.01;

/// The prior range of a knob the target does not identify: its value ×/÷ this factor,
/// within its bounds, read as a 95 % range on the log scale.
pub const PRIOR_FACTOR: f64 = 2.0;

/// z of a two-sided 95 % interval.
pub const Z95: f64 = 1.959_963_984_540_054;

/// A metric's model discrepancy, as the report gives it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct MetricDiscrepancy {
    pub metric: String,
    /// The metric's fitted moments (cells in the target).
    pub fitted_cells: usize,
    /// √τ²: the sd of the model's own error on a cell's log mean; None where the target
    /// held none of the metric (unknown, left out of its intervals).
    pub log_sd: Option<f64>,
}

/// The goodness-of-fit test of the fit at its optimum.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct GoodnessOfFit {
    /// Σ w r² at the optimum (the fit's objective).
    pub misfit: f64,
    /// Moments − identified parameters.
    pub dof: i64,
    /// P(χ²_dof ≥ misfit); None with no degrees of freedom.
    pub p_value: Option<f64>,
    /// "fits: …", "lack of fit: …" (naming the worst cells) or "no test of fit: …"; then
    /// the parameters that ended at a bound, if any.
    pub verdict: String,
}

/// Position of `m` in `Metric::ALL`.
pub fn metric_index(m: Metric) -> usize {
    Metric::ALL
        .iter()
        .position(|&x| x == m)
        .expect("a metric of ALL")
}

/// τ²_m per metric (`Metric::ALL` order) by the method of moments (module doc): `metric[i]`
/// the metric of moment i (None for the mean-log-spread moment, which has none), `r` the
/// residuals, `w` the weights 1/v, `p` the identified parameters.
pub fn discrepancies(
    metric: &[Option<Metric>],
    r: &DVector<f64>,
    w: &DVector<f64>,
    p: usize,
) -> Vec<Option<f64>> {
    let n = r.len().max(1) as f64;
    let keep = (1.0 - p as f64 / n).max(0.0);
    Metric::ALL
        .iter()
        .map(|&m| {
            let at: Vec<usize> = (0..r.len()).filter(|&i| metric[i] == Some(m)).collect();
            if at.is_empty() {
                return None;
            }
            let excess: f64 = at.iter().map(|&i| r[i] * r[i] - keep / w[i]).sum();
            let tau2 = (excess / at.len() as f64).max(0.0);
            Some(if tau2.is_finite() { tau2 } else { 0.0 })
        })
        .collect()
}

/// The verdict of the misfit `x2` on `dof` degrees of freedom; `worst` the moments' labels
/// with their z (|z| largest first are named), `at_bound` the parameters at a bound.
pub fn goodness(x2: f64, dof: i64, worst: &[(String, f64)], at_bound: &[String]) -> GoodnessOfFit {
    let p_value = (dof > 0 && x2.is_finite()).then(|| gamma_q(dof as f64 / 2.0, x2 / 2.0));
    let mut verdict = match p_value {
        None => format!(
            "no test of fit: {dof} degrees of freedom (as many parameters as moments, or more)"
        ),
        Some(p) if p < LACK_OF_FIT_P => {
            let mut by: Vec<&(String, f64)> = worst.iter().filter(|w| w.1.is_finite()).collect();
            by.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
            format!(
                "lack of fit: misfit {x2:.3} against χ² with {dof} degrees of freedom (p = {p:.2e} < {LACK_OF_FIT_P}); worst: {}",
                by.iter()
                    .take(3)
                    .map(|(label, z)| format!("{label} (z = {z:+.1})"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        }
        Some(p) => format!(
            "fits: misfit {x2:.3} against χ² with {dof} degrees of freedom (p = {p:.3}): within what the Monte-Carlo and the target's errors allow"
        ),
    };
    if !at_bound.is_empty() {
        verdict += &format!("; at a bound: {}", at_bound.join(", "));
    }
    GoodnessOfFit {
        misfit: x2,
        dof,
        p_value,
        verdict,
    }
}

/// The log-sd of a knob's prior range: its value `v` ×/÷ `PRIOR_FACTOR` within `bounds`,
/// a 95 % range.
pub fn prior_log_sd(v: f64, bounds: (f64, f64)) -> f64 {
    let lo = (v / PRIOR_FACTOR).max(bounds.0).max(1e-12);
    let hi = (v * PRIOR_FACTOR).min(bounds.1);
    ((hi / lo).ln() / (2.0 * Z95)).max(0.0)
}

/// The variance parts of one output's log prediction.
#[derive(Debug, Clone, Copy, Default)]
pub struct Parts {
    /// The identified parameters' uncertainty (their bootstrap draws through the Jacobian).
    pub parameters: f64,
    /// The unidentified knobs' prior range through the Jacobian.
    pub prior: f64,
    /// The Monte-Carlo error of the simulated mean.
    pub monte_carlo: f64,
    /// The metric's model discrepancy (0 where unknown).
    pub discrepancy: f64,
    /// The target's own error (a held-out row's), else 0.
    pub target: f64,
}

impl Parts {
    pub fn total(&self) -> f64 {
        self.parameters + self.prior + self.monte_carlo + self.discrepancy + self.target
    }
}

/// Per output (row of `jac`, the Jacobian of every cell × metric's log mean in every knob's
/// log), the variance of its log prediction from the identified knobs' bootstrap `draws`
/// (each a vector over `identified`, the change of their log values) and from the
/// unidentified knobs' prior log-sds `prior_sd` (by knob; ignored for identified ones).
pub fn parameter_and_prior(
    jac: &DMatrix<f64>,
    identified: &[usize],
    draws: &[DVector<f64>],
    prior_sd: &[f64],
) -> Vec<(f64, f64)> {
    (0..jac.nrows())
        .map(|o| {
            let params = if identified.is_empty() {
                0.0
            } else if draws.len() < 2 {
                f64::NAN
            } else {
                let moved: Vec<f64> = draws
                    .iter()
                    .map(|d| {
                        identified
                            .iter()
                            .enumerate()
                            .map(|(i, &k)| jac[(o, k)] * d[i])
                            .sum::<f64>()
                    })
                    .collect();
                let mean = moved.iter().sum::<f64>() / moved.len() as f64;
                moved.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (moved.len() - 1) as f64
            };
            let prior = (0..jac.ncols())
                .filter(|k| !identified.contains(k))
                .map(|k| (jac[(o, k)] * prior_sd[k]).powi(2))
                .sum::<f64>();
            (params, prior)
        })
        .collect()
}

/// The 95 % interval of a mean predicted at `mean` with log-variance `var`: None when
/// either is not a usable number.
pub fn interval(mean: f64, var: f64) -> Option<(f64, f64)> {
    (mean > 0.0 && mean.is_finite() && var.is_finite() && var >= 0.0).then(|| {
        let half = Z95 * var.sqrt();
        (mean * (-half).exp(), mean * half.exp())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_misfit_within_its_errors_has_no_discrepancy_and_one_beyond_them_has_its_excess() {
        // Two tracking moments with residuals of one standard error each, none of cab
        // acceleration: with p = 0, Σ r² = Σ v exactly, so τ² = 0; the metric without a
        // moment is unknown.
        let metric = [
            Some(Metric::MseTrackingMm2),
            Some(Metric::MseTrackingMm2),
            None,
        ];
        let w = DVector::from_vec(vec![100.0, 25.0, 1.0]);
        let r = DVector::from_vec(vec![0.1, -0.2, 5.0]);
        let tau = discrepancies(&metric, &r, &w, 0);
        assert!(tau[0].unwrap().abs() < 1e-15, "{tau:?}");
        assert_eq!(tau[1], None);
        // Residuals of 0.3 in each: Σ r² = 0.18 against Σ v = 0.05, so τ² = 0.065; with
        // one of three moments fitted away, (0.18 − (2/3)·0.05)/2.
        let r = DVector::from_vec(vec![0.3, 0.3, 0.0]);
        assert!((discrepancies(&metric, &r, &w, 0)[0].unwrap() - 0.065).abs() < 1e-12);
        let want = (0.18 - 2.0 / 3.0 * 0.05) / 2.0;
        assert!((discrepancies(&metric, &r, &w, 1)[0].unwrap() - want).abs() < 1e-12);
    }

    #[test]
    fn the_verdict_reads_the_chi_square_tail_and_names_the_worst_cells_and_bounds() {
        // χ²₂'s tail is e^{−x/2}: 5.991 is its 95th percentile.
        let g = goodness(5.991_464_547_107_979, 2, &[], &[]);
        assert!((g.p_value.unwrap() - 0.05).abs() < 1e-9, "{g:?}");
        let g = goodness(2.0, 2, &[], &[]);
        assert!((g.p_value.unwrap() - (-1.0f64).exp()).abs() < 1e-12);
        assert!(g.verdict.starts_with("fits: misfit 2.000"), "{}", g.verdict);
        let worst = [
            ("pid on".to_string(), 1.0),
            ("lqr on".to_string(), -4.0),
            ("lqr off".to_string(), 3.0),
            ("pid off".to_string(), 0.5),
        ];
        let g = goodness(
            26.0,
            2,
            &worst,
            &["reaction_delay_s (its lower bound 0.1)".into()],
        );
        assert!(
            g.verdict.starts_with("lack of fit")
                && g.verdict
                    .contains("worst: lqr on (z = -4.0), lqr off (z = +3.0), pid on")
                && !g.verdict.contains("pid off")
                && g.verdict
                    .ends_with("at a bound: reaction_delay_s (its lower bound 0.1)"),
            "{}",
            g.verdict
        );
        assert_eq!(goodness(1.0, 0, &[], &[]).p_value, None);
    }

    #[test]
    fn a_prediction_carries_the_parameters_draws_and_the_unidentified_priors() {
        // Output 0 moves 2× knob 0 (identified, draws ±0.1: variance 0.01·4 = 0.04 for
        // two draws ±0.1 around 0, sample variance 0.02 of the draws) and 0.5× knob 1
        // (unidentified, prior sd ln 4 / (2·1.96)).
        let jac = DMatrix::from_row_slice(1, 2, &[2.0, 0.5]);
        let draws = [DVector::from_vec(vec![0.1]), DVector::from_vec(vec![-0.1])];
        let sd1 = prior_log_sd(1.0, (0.01, 100.0));
        assert!((sd1 - 4f64.ln() / (2.0 * Z95)).abs() < 1e-12);
        let got = parameter_and_prior(&jac, &[0], &draws, &[0.0, sd1]);
        assert!((got[0].0 - 4.0 * 0.02).abs() < 1e-12, "{got:?}");
        assert!((got[0].1 - (0.5 * sd1).powi(2)).abs() < 1e-12, "{got:?}");
        // Against a bound the range is cut: 1 ×/÷ 2 within [0.8, 10] is [0.8, 2].
        assert!((prior_log_sd(1.0, (0.8, 10.0)) - (2.0f64 / 0.8).ln() / (2.0 * Z95)).abs() < 1e-12);
        let (lo, hi) = interval(100.0, 0.01).unwrap();
        assert!((lo - 100.0 * (-Z95 * 0.1).exp()).abs() < 1e-9 && (hi * lo - 1e4).abs() < 1e-6);
        assert_eq!(interval(100.0, f64::NAN), None);
    }
}
