//! Two-way repeated-measures ANOVA (both factors within subjects: compensator × seat) with
//! the Greenhouse–Geisser correction and generalized η² (Bakeman 2005), as pingouin's
//! `rm_anova(within=[a, b])` computes them: sums of squares of the balanced design, ε from
//! the covariance of orthonormal contrasts of each effect (main effects on the subjects'
//! means over the other factor; the interaction on the Kronecker product of the contrasts).

use nalgebra::DMatrix;

use super::special::f_sf;

/// One effect's row of the table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Effect {
    pub ss: f64,
    pub df1: f64,
    pub df2: f64,
    pub f: f64,
    pub p_unc: f64,
    /// Greenhouse–Geisser ε (1 for an effect with one degree of freedom).
    pub eps: f64,
    pub p_gg: f64,
    /// Generalized η².
    pub ng2: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RmAnova {
    pub n: usize,
    pub a: Effect,
    pub b: Effect,
    pub ab: Effect,
}

/// The ANOVA of `y[s][i][j]`: subject s, level i of factor a, level j of factor b (a
/// complete, balanced design: every subject every cell). `None` with fewer than 2 subjects
/// or levels, or a ragged array.
pub fn rm_anova2(y: &[Vec<Vec<f64>>]) -> Option<RmAnova> {
    let ns = y.len();
    let na = y.first()?.len();
    let nb = y.first()?.first()?.len();
    if ns < 2
        || na < 2
        || nb < 2
        || y.iter()
            .any(|s| s.len() != na || s.iter().any(|c| c.len() != nb))
    {
        return None;
    }
    let (fs, fa, fb) = (ns as f64, na as f64, nb as f64);
    let at = |s: usize, i: usize, j: usize| y[s][i][j];
    let mean = |f: &dyn Fn(usize, usize, usize) -> bool| {
        let (mut sum, mut count) = (0.0, 0.0);
        for s in 0..ns {
            for i in 0..na {
                for j in 0..nb {
                    if f(s, i, j) {
                        sum += at(s, i, j);
                        count += 1.0;
                    }
                }
            }
        }
        sum / count
    };
    let mu = mean(&|_, _, _| true);
    let sq = |v: f64| (v - mu) * (v - mu);
    let mut ss_tot = 0.0;
    for s in 0..ns {
        for i in 0..na {
            for j in 0..nb {
                ss_tot += sq(at(s, i, j));
            }
        }
    }
    let ss_s = fa * fb * (0..ns).map(|s| sq(mean(&|t, _, _| t == s))).sum::<f64>();
    let ss_a = fb * fs * (0..na).map(|i| sq(mean(&|_, u, _| u == i))).sum::<f64>();
    let ss_b = fa * fs * (0..nb).map(|j| sq(mean(&|_, _, v| v == j))).sum::<f64>();
    let ss_ab = fs
        * (0..na)
            .flat_map(|i| (0..nb).map(move |j| (i, j)))
            .map(|(i, j)| sq(mean(&|_, u, v| u == i && v == j)))
            .sum::<f64>()
        - ss_a
        - ss_b;
    let ss_as = fb
        * (0..na)
            .flat_map(|i| (0..ns).map(move |s| (i, s)))
            .map(|(i, s)| sq(mean(&|t, u, _| u == i && t == s)))
            .sum::<f64>()
        - ss_s
        - ss_a;
    let ss_bs = fa
        * (0..nb)
            .flat_map(|j| (0..ns).map(move |s| (j, s)))
            .map(|(j, s)| sq(mean(&|t, _, v| v == j && t == s)))
            .sum::<f64>()
        - ss_s
        - ss_b;
    let ss_abs = ss_tot - ss_a - ss_b - ss_s - ss_ab - ss_as - ss_bs;
    let (df_a, df_b, df_s) = (fa - 1.0, fb - 1.0, fs - 1.0);
    let df_ab = df_a * df_b;
    let generalized = ss_s + ss_as + ss_bs + ss_abs;
    let effect = |ss: f64, df1: f64, ss_err: f64, df2: f64, eps: f64| {
        let f = (ss / df1) / (ss_err / df2);
        Effect {
            ss,
            df1,
            df2,
            f,
            p_unc: f_sf(f, df1, df2),
            eps,
            p_gg: f_sf(f, (df1 * eps).max(1.0), (df2 * eps).max(1.0)),
            ng2: ss / (ss + generalized),
        }
    };
    // Wide data of each effect: one row per subject.
    let wide_a = DMatrix::from_fn(ns, na, |s, i| {
        (0..nb).map(|j| at(s, i, j)).sum::<f64>() / fb
    });
    let wide_b = DMatrix::from_fn(ns, nb, |s, j| {
        (0..na).map(|i| at(s, i, j)).sum::<f64>() / fa
    });
    let wide_ab = DMatrix::from_fn(ns, na * nb, |s, c| at(s, c / nb, c % nb));
    let (ca, cb) = (orthonormal_contrasts(na), orthonormal_contrasts(nb));
    Some(RmAnova {
        n: ns,
        a: effect(ss_a, df_a, ss_as, df_a * df_s, gg_epsilon(&wide_a, &ca)),
        b: effect(ss_b, df_b, ss_bs, df_b * df_s, gg_epsilon(&wide_b, &cb)),
        ab: effect(
            ss_ab,
            df_ab,
            ss_abs,
            df_ab * df_s,
            gg_epsilon(&wide_ab, &ca.kronecker(&cb)),
        ),
    })
}

/// k × (k − 1) orthonormal contrasts (columns orthonormal and orthogonal to the ones):
/// normalized Helmert contrasts. ε does not depend on which orthonormal basis is used.
fn orthonormal_contrasts(k: usize) -> DMatrix<f64> {
    DMatrix::from_fn(k, k - 1, |row, col| {
        let c = col + 1;
        let norm = ((c * (c + 1)) as f64).sqrt();
        match row.cmp(&c) {
            std::cmp::Ordering::Less => 1.0 / norm,
            std::cmp::Ordering::Equal => -(c as f64) / norm,
            std::cmp::Ordering::Greater => 0.0,
        }
    })
}

/// Greenhouse–Geisser ε = tr(M)² / (d · tr(M²)) for M = Cᵀ S C, S the sample covariance of
/// the wide data, C the contrasts (d columns); 1 when d ≤ 1.
fn gg_epsilon(wide: &DMatrix<f64>, c: &DMatrix<f64>) -> f64 {
    let d = c.ncols();
    if d <= 1 {
        return 1.0;
    }
    let n = wide.nrows() as f64;
    let means = wide.row_mean();
    let centred = DMatrix::from_fn(wide.nrows(), wide.ncols(), |r, k| wide[(r, k)] - means[k]);
    let s = centred.transpose() * &centred / (n - 1.0);
    let m = c.transpose() * s * c;
    let tr = m.trace();
    (tr * tr / (d as f64 * (&m * &m).trace())).min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contrasts_are_orthonormal_and_sum_to_zero() {
        for k in 2..7 {
            let c = orthonormal_contrasts(k);
            let g = c.transpose() * &c;
            assert!((g - DMatrix::identity(k - 1, k - 1)).norm() < 1e-12);
            assert!(c.row_sum().norm() < 1e-12);
        }
    }
}
