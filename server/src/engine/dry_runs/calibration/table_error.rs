//! A table's sampling error on the calibration's moments, for the bootstrap.
//!
//! The model: a within-subject table's cells come from the same people. Subject s's log
//! metric in cell i is μ_i + e_si, where e_s· is the subject's own deviation across the
//! cells, with sd σ_i in cell i and correlation ρ_ij between cells i and j (a person who
//! tracks worse than the median does so with every controller: the population's ICC of log
//! tracking error is about 0.6). A cell's log mean then errs by ē_i, with
//!
//!   cov(ē_i, ē_j) = ρ_ij σ_i σ_j · n_ij / (n_i n_j),
//!
//! n_ij the subjects in both cells, taken as min(n_i, n_j) (a cell with fewer subjects holds
//! a subset of the others', as drop-outs give); for n_i = n_j = n that is ρ_ij σ_i σ_j / n,
//! and the diagonal is the cell's own σ_i²/n_i. σ_i is the table's log sd (its mean and sd
//! read as a log-normal's); ρ_ij, which a table does not give, is the correlation of the
//! fitted population's simulated subjects' log metric between the two cells, over the
//! subjects with both trials (common random numbers: every simulated subject has a value in
//! every cell). A cell without sd and n (known to ±10 % by judgement, from no subjects the
//! table names) and the mean-log-spread moment err on their own.
//!
//! Redrawing each cell independently instead averages the shared deviation out over the
//! cells and understates the uncertainty of whatever moves every cell together (the delay),
//! by up to √(1 + (k − 1)ρ) for k cells.

use bdft_controller::rng::Rng;
use bdft_protocol::trial::Metrics;
use nalgebra::{DMatrix, DVector};

use super::sim::Cell;
use super::target::{Target, mean_sd};

/// A correlation from fewer subjects than this is taken as none.
const MIN_PAIRS: usize = 3;

/// The table's error on its moments as a factor L of their covariance (L Lᵀ): a replicate's
/// errors are L z with z independent standard normals.
#[derive(Debug)]
pub struct TableError {
    factor: DMatrix<f64>,
    /// The mean correlation between the cells with a spread (0 with fewer than two).
    pub mean_correlation: f64,
    /// How far the correlation matrix was pulled towards the identity for its Cholesky
    /// factor (0: not at all; a singular or, from pairwise estimates, indefinite one needs
    /// a little).
    pub shrink: f64,
}

impl TableError {
    /// The error of `target`'s moments (`Problem::target_moments`' order: one per target
    /// cell, then the mean log spread if any cell has one) with variances `var`; `rows` the
    /// simulated subjects' metrics in `cells`.
    pub fn new(
        target: &Target,
        var: &DVector<f64>,
        cells: &[Cell],
        rows: &[Vec<Option<Metrics>>],
    ) -> TableError {
        let spread = target.with_spread();
        let logs: Vec<Vec<Option<f64>>> = spread
            .iter()
            .map(|&i| {
                let t = &target.cells[i];
                let j = cells
                    .iter()
                    .position(|&c| c == t.cell)
                    .expect("a simulated cell");
                rows.iter()
                    .map(|r| r[j].map(|m| t.metric.of(&m).max(1e-12).ln()))
                    .collect()
            })
            .collect();
        let k = spread.len();
        let corr = DMatrix::from_fn(k, k, |a, b| {
            if a == b {
                1.0
            } else {
                correlation(&logs[a], &logs[b])
            }
        });
        let mean_correlation = if k < 2 {
            0.0
        } else {
            (corr.sum() - k as f64) / (k * (k - 1)) as f64
        };
        let n = |i: usize| target.cells[i].n.unwrap_or(1) as f64;
        let covariance = |shrink: f64| {
            let mut c = DMatrix::from_diagonal(var);
            for (a, &i) in spread.iter().enumerate() {
                for (b, &j) in spread.iter().enumerate() {
                    if a != b {
                        let overlap = n(i).min(n(j)) / (n(i) * n(j)).sqrt();
                        c[(i, j)] =
                            (1.0 - shrink) * corr[(a, b)] * (var[i] * var[j]).sqrt() * overlap;
                    }
                }
            }
            c
        };
        // The correlations are shrunk towards none only as far as a Cholesky factor needs:
        // not at all unless the matrix is singular (two cells the simulated subjects rank
        // alike) or indefinite (pairwise estimates where trials were stopped), then by the
        // least step of the ladder that works. At shrink 1 the covariance is diagonal.
        let mut shrink = 0.0;
        loop {
            if let Some(ch) = covariance(shrink).cholesky() {
                return TableError {
                    factor: ch.l(),
                    mean_correlation,
                    shrink,
                };
            }
            if shrink >= 1.0 {
                // Only a variance that is not a positive number can end here.
                return TableError {
                    factor: DMatrix::from_diagonal(&var.map(|v| v.max(0.0).sqrt())),
                    mean_correlation,
                    shrink,
                };
            }
            shrink = if shrink == 0.0 {
                1e-9
            } else {
                (shrink * 10.0).min(1.0)
            };
        }
    }

    /// One replicate of the moments' errors.
    pub fn draw(&self, rng: &mut Rng) -> DVector<f64> {
        &self.factor * DVector::from_fn(self.factor.ncols(), |_, _| rng.normal())
    }

    /// The covariance the replicates are drawn from.
    #[cfg(test)]
    pub fn covariance(&self) -> DMatrix<f64> {
        &self.factor * self.factor.transpose()
    }
}

/// Pearson's correlation of `x` and `y` over the subjects with both; 0 with fewer than
/// `MIN_PAIRS` of them or no spread in either.
fn correlation(x: &[Option<f64>], y: &[Option<f64>]) -> f64 {
    let (a, b): (Vec<f64>, Vec<f64>) = x
        .iter()
        .zip(y)
        .filter_map(|(x, y)| Some(((*x)?, (*y)?)))
        .unzip();
    if a.len() < MIN_PAIRS {
        return 0.0;
    }
    let ((ma, sa), (mb, sb)) = (mean_sd(&a), mean_sd(&b));
    if sa <= 0.0 || sb <= 0.0 {
        return 0.0;
    }
    let cov = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - ma) * (y - mb))
        .sum::<f64>()
        / (a.len() - 1) as f64;
    (cov / (sa * sb)).clamp(-1.0, 1.0)
}
