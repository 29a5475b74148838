//! Inferential statistics of a within-subject study, pure functions on numbers: rank tests
//! (Friedman with Kendall's W, exact Wilcoxon signed-rank with Holm adjustment and the
//! rank-biserial r), the two-way repeated-measures ANOVA with Greenhouse–Geisser correction,
//! bootstrap intervals of median differences, and the special functions behind the
//! p-values. Checked against scipy and pingouin (`tools/fixtures/make_stats_fixtures.py`).

pub mod bootstrap;
pub mod nonparametric;
pub mod quantile;
pub mod rm_anova;
pub mod special;

#[cfg(test)]
mod fixtures;
