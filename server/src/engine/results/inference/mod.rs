//! Inferential statistics of a within-subject study, pure functions on numbers: rank tests
//! (Friedman with Kendall's W, exact Wilcoxon signed-rank with Holm adjustment and the
//! rank-biserial r), the two-way repeated-measures ANOVA with Greenhouse–Geisser correction,
//! bootstrap intervals of median differences, and the special functions behind the
//! p-values (`special`: the controller crate's, which the identification's t quantiles use
//! too). Checked against scipy and pingouin (`tools/fixtures/make_stats_fixtures.py`).

pub mod bootstrap;
pub mod nonparametric;
pub mod quantile;
pub mod rm_anova;
pub use bdft_controller::special;

#[cfg(test)]
mod fixtures;
