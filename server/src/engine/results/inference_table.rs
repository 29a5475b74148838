//! A study's inferential statistics as one table (the dashboard's results page and `export
//! --kind stats`): per seat and metric, Friedman across the compensators and every pair by
//! exact Wilcoxon with Holm's adjustment; per compensator and metric, on against off the
//! machine; for the continuous metrics, the two-way RM-ANOVA (compensator × seat) on their
//! logarithm; in a study with cancellation, per arm on the machine, each compensator
//! uncancelled against cancelled and the RM-ANOVA compensator × cancellation; in a study
//! with a condition factor, per seat and metric, Kruskal–Wallis across its levels. Each
//! test's data are the latest attempt of every test when it is complete;
//! subjects missing a cell are left out of that analysis (n says how many remain). Ratings
//! are ordinal: rank tests only.

use serde::Serialize;
use sqlx::AnyPool;

use super::inference::bootstrap::median_interval;
use super::inference::nonparametric::{friedman, holm, kruskal_wallis, wilcoxon, wilcoxon_floor};
use super::inference::rm_anova::{Effect, rm_anova2};
use super::study_data::{Cells, SUMMARY_VARIABLES, StudyData, cancelled_key};
use crate::error::Result;
use bdft_protocol::params::Seat;
use bdft_protocol::study::CancellationArm;

/// The significance level the table's reachability statements use.
pub const ALPHA: f64 = 0.05;
/// Bootstrap resamples and seed of the median-difference intervals (fixed, so the table is
/// reproducible).
const RESAMPLES: usize = 10_000;
const BOOTSTRAP_SEED: u64 = 0x5354_4154;

/// One row of the table. Test names: `friedman`, `wilcoxon` (a pair at one seat),
/// `wilcoxon_on_off` (one compensator, on against off), `rm_anova` (`a` the effect:
/// `controller`, `station` or `controller:station`), `kruskal_condition` (`a` the
/// condition factor's levels).
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct StatsRow {
    pub test: String,
    pub metric: String,
    /// `on`, `off`, `on-off` (a seat comparison) or `both` (the ANOVA); the API's key:
    /// `station`.
    #[serde(rename = "station")]
    pub seat: String,
    pub a: String,
    pub b: String,
    /// Subjects in the analysis.
    pub n: usize,
    /// χ² (Friedman), min(R⁺, R⁻) (Wilcoxon), F (ANOVA), H (Kruskal–Wallis).
    pub statistic: f64,
    /// Friedman and Wilcoxon: the test's p; ANOVA: Greenhouse–Geisser corrected.
    pub p_value: f64,
    /// Holm-adjusted within the family (the pairs of one seat and metric, or the seat
    /// comparisons of one metric); empty for omnibus tests.
    pub p_adjusted: Option<f64>,
    pub effect_size: f64,
    /// `kendall_w`, `rank_biserial` (of a − b), `eta_g2` or `epsilon2`.
    pub effect: String,
    /// Median of a − b and its 95 % bootstrap interval (Wilcoxon rows).
    pub median_diff: Option<f64>,
    pub ci_low: Option<f64>,
    pub ci_high: Option<f64>,
    pub df1: Option<f64>,
    pub df2: Option<f64>,
    pub eps: Option<f64>,
    /// Whether this comparison can reach p < 0.05 after adjustment at this n at all (the
    /// exact test's smallest p times the family's size).
    pub reachable: bool,
    pub note: String,
}

/// The study's table.
pub async fn study_table(pool: &AnyPool, study_id: i64) -> Result<Vec<StatsRow>> {
    let data = StudyData::load(pool, study_id).await?;
    // Ten thousand resamples for each of some 150 comparisons: off the async threads.
    let _turn = crate::engine::COMPUTE
        .acquire()
        .await
        .expect("never closed");
    tokio::task::spawn_blocking(move || table(&data))
        .await
        .map_err(|e| anyhow::anyhow!("statistics task: {e}").into())
}

/// The table from each subject's cells.
pub fn table(data: &StudyData) -> Vec<StatsRow> {
    let (subjects, compensators, seats) = (&data.subjects, &data.compensators, &data.seats);
    let mut out = Vec::new();
    for (m, metric) in SUMMARY_VARIABLES.iter().enumerate() {
        let value = |s: &Cells, c: &str, seat: &str| s.get(&(c.into(), seat.into()))?[m];
        for seat in seats {
            // Subjects with every compensator at this seat.
            if let Some(f) = friedman(&data.complete_rows(&data.compensators, m, seat)) {
                out.push(row(
                    "friedman",
                    metric,
                    seat,
                    "",
                    "",
                    f.n,
                    f.chi2,
                    f.p_value,
                    f.kendall_w,
                    "kendall_w",
                ));
            }
            let pairs: Vec<(usize, usize)> = (0..compensators.len())
                .flat_map(|i| (i + 1..compensators.len()).map(move |j| (i, j)))
                .collect();
            let family: Vec<StatsRow> = pairs
                .iter()
                .filter_map(|&(i, j)| {
                    let (a, b): (Vec<f64>, Vec<f64>) = subjects
                        .iter()
                        .filter_map(|s| {
                            Some((
                                value(s, &compensators[i], seat)?,
                                value(s, &compensators[j], seat)?,
                            ))
                        })
                        .unzip();
                    pair_row(
                        "wilcoxon",
                        metric,
                        seat,
                        &compensators[i],
                        &compensators[j],
                        &a,
                        &b,
                    )
                })
                .collect();
            out.extend(adjusted(family));
        }
        if seats.len() == 2 {
            let family: Vec<StatsRow> = compensators
                .iter()
                .filter_map(|c| {
                    let (a, b): (Vec<f64>, Vec<f64>) = subjects
                        .iter()
                        .filter_map(|s| Some((value(s, c, &seats[0])?, value(s, c, &seats[1])?)))
                        .unzip();
                    let mut r = pair_row("wilcoxon_on_off", metric, "", c, c, &a, &b)?;
                    r.seat = format!("{}-{}", seats[0], seats[1]);
                    Some(r)
                })
                .collect();
            out.extend(adjusted(family));
        }
        for &arm in &data.arms {
            out.extend(cancellation_rows(data, m, metric, arm));
        }
        out.extend(condition_rows(data, m, metric));
        // The continuous metrics: their logarithm is closer to normal (errors are ratios).
        if m < 2 && seats.len() >= 2 {
            let y: Vec<Vec<Vec<f64>>> = subjects
                .iter()
                .filter_map(|s| {
                    compensators
                        .iter()
                        .map(|c| {
                            seats
                                .iter()
                                .map(|seat| value(s, c, seat).filter(|v| *v > 0.0).map(f64::ln))
                                .collect()
                        })
                        .collect()
                })
                .collect();
            if let Some(aov) = rm_anova2(&y) {
                for (name, e) in [
                    ("controller", aov.a),
                    ("station", aov.b),
                    ("controller:station", aov.ab),
                ] {
                    out.push(anova_row(metric, name, aov.n, e));
                }
            }
        }
    }
    out
}

/// The condition factor's rows for one metric, per seat: Kruskal–Wallis across its levels
/// (the study's order) of each subject's mean over the compensators there (subjects with
/// every compensator at the seat). Between subjects: each subject ran under one level.
/// None without the factor.
fn condition_rows(data: &StudyData, m: usize, metric: &str) -> Vec<StatsRow> {
    let mut levels: Vec<&str> = Vec::new();
    for c in &data.conditions {
        if !levels.contains(&c.as_str()) {
            levels.push(c);
        }
    }
    if levels.len() < 2 {
        return Vec::new();
    }
    data.seats
        .iter()
        .filter_map(|seat| {
            let groups: Vec<Vec<f64>> = levels
                .iter()
                .map(|level| {
                    data.subjects
                        .iter()
                        .zip(&data.conditions)
                        .filter(|(_, c)| c == level)
                        .filter_map(|(s, _)| {
                            let v = data
                                .compensators
                                .iter()
                                .map(|c| s.get(&(c.clone(), seat.clone()))?[m])
                                .collect::<Option<Vec<f64>>>()?;
                            Some(v.iter().sum::<f64>() / v.len() as f64)
                        })
                        .collect()
                })
                .collect();
            let kw = kruskal_wallis(&groups)?;
            let sizes: Vec<String> = groups.iter().map(|g| g.len().to_string()).collect();
            let mut r = row(
                "kruskal_condition",
                metric,
                seat,
                &levels.join(","),
                "",
                kw.n,
                kw.h,
                kw.p_value,
                kw.epsilon2,
                "epsilon2",
            );
            r.df1 = Some((kw.k - 1) as f64);
            r.note = format!(
                "between subjects, each subject's mean over the compensators; {} subjects per condition; asymptotic χ², rough below 5 per condition",
                sizes.join("/")
            );
            Some(r)
        })
        .collect()
}

/// The cancellation factor's rows for one metric and arm, on the machine (the desk has no
/// such factor): per compensator, uncancelled against cancelled by exact Wilcoxon, Holm
/// within the family of compensators; for the continuous metrics, the two-way RM-ANOVA
/// (compensator × cancellation) on their logarithm — its interaction says whether
/// cancellation helps some compensators more than others.
fn cancellation_rows(
    data: &StudyData,
    m: usize,
    metric: &str,
    arm: CancellationArm,
) -> Vec<StatsRow> {
    let on = Seat::On.as_str();
    let value = |s: &Cells, key: &str| s.get(&(key.into(), on.into()))?[m];
    let family: Vec<StatsRow> = data
        .compensators
        .iter()
        .filter_map(|c| {
            let cancelled = cancelled_key(c, arm);
            let (a, b): (Vec<f64>, Vec<f64>) = data
                .subjects
                .iter()
                .filter_map(|s| Some((value(s, c)?, value(s, &cancelled)?)))
                .unzip();
            pair_row("wilcoxon_cancellation", metric, on, c, &cancelled, &a, &b)
        })
        .collect();
    let mut out = adjusted(family);
    if m < 2 {
        let y: Vec<Vec<Vec<f64>>> = data
            .subjects
            .iter()
            .filter_map(|s| {
                data.compensators
                    .iter()
                    .map(|c| {
                        [c.clone(), cancelled_key(c, arm)]
                            .iter()
                            .map(|k| value(s, k).filter(|v| *v > 0.0).map(f64::ln))
                            .collect()
                    })
                    .collect()
            })
            .collect();
        if let Some(aov) = rm_anova2(&y) {
            for (name, e) in [
                ("controller".to_string(), aov.a),
                (format!("cancellation:{arm}"), aov.b),
                (format!("controller:cancellation:{arm}"), aov.ab),
            ] {
                let mut r = anova_row(metric, &name, aov.n, e);
                r.seat = on.into();
                out.push(r);
            }
        }
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn row(
    test: &str,
    metric: &str,
    seat: &str,
    a: &str,
    b: &str,
    n: usize,
    statistic: f64,
    p_value: f64,
    effect_size: f64,
    effect: &str,
) -> StatsRow {
    StatsRow {
        test: test.into(),
        metric: metric.into(),
        seat: seat.into(),
        a: a.into(),
        b: b.into(),
        n,
        statistic,
        p_value,
        p_adjusted: None,
        effect_size,
        effect: effect.into(),
        median_diff: None,
        ci_low: None,
        ci_high: None,
        df1: None,
        df2: None,
        eps: None,
        reachable: true,
        note: String::new(),
    }
}

fn pair_row(
    test: &str,
    metric: &str,
    seat: &str,
    a: &str,
    b: &str,
    xa: &[f64],
    xb: &[f64],
) -> Option<StatsRow> {
    let w = wilcoxon(xa, xb)?;
    let diffs: Vec<f64> = xa.iter().zip(xb).map(|(x, y)| x - y).collect();
    let ci = median_interval(&diffs, 0.95, RESAMPLES, BOOTSTRAP_SEED)?;
    let mut r = row(
        test,
        metric,
        seat,
        a,
        b,
        w.n,
        w.statistic,
        w.p_value,
        w.rank_biserial,
        "rank_biserial",
    );
    r.median_diff = Some(ci.median);
    r.ci_low = Some(ci.low);
    r.ci_high = Some(ci.high);
    if !w.exact {
        r.note = "normal approximation (n > 25)".into();
    }
    Some(r)
}

/// Holm within the family, and whether each comparison could reach significance at all:
/// the smallest adjusted p an exact test with n pairs can give is its floor times the
/// family's size (Holm's first step).
fn adjusted(mut family: Vec<StatsRow>) -> Vec<StatsRow> {
    let p: Vec<f64> = family.iter().map(|r| r.p_value).collect();
    let m = family.len();
    for (r, adj) in family.iter_mut().zip(holm(&p)) {
        r.p_adjusted = Some(adj);
        let best = (wilcoxon_floor(r.n) * m as f64).min(1.0);
        if r.n <= super::inference::nonparametric::EXACT_MAX_N && best >= ALPHA {
            r.reachable = false;
            r.note = format!(
                "cannot reach p < {ALPHA} at n = {}: the exact test's smallest p is 2/2^{} = {:.4}, \
                 × {m} comparisons (Holm) = {best:.3}",
                r.n,
                r.n,
                wilcoxon_floor(r.n)
            );
        }
    }
    family
}

fn anova_row(metric: &str, effect: &str, n: usize, e: Effect) -> StatsRow {
    let mut r = row(
        "rm_anova",
        &format!("log_{metric}"),
        "both",
        effect,
        "",
        n,
        e.f,
        e.p_gg,
        e.ng2,
        "eta_g2",
    );
    r.df1 = Some(e.df1);
    r.df2 = Some(e.df2);
    r.eps = Some(e.eps);
    r.note = format!("uncorrected p = {:.6}", e.p_unc);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cells(per: &[(&str, &str, f64)]) -> Cells {
        per.iter()
            .map(|(c, s, v)| {
                (
                    (c.to_string(), s.to_string()),
                    [Some(*v), Some(*v * 2.0), Some(3.0), None, None, None],
                )
            })
            .collect()
    }

    #[test]
    fn eight_subjects_and_ten_pairs_cannot_reach_significance_and_the_table_says_so() {
        let comps: Vec<String> = ["pid", "pid_notch", "pid_shaper", "lqr", "lqr_cab_velocity"]
            .map(String::from)
            .to_vec();
        let seats = vec!["on".to_string(), "off".to_string()];
        let subjects: Vec<Cells> = (0..8)
            .map(|s| {
                let mut v = Vec::new();
                for (i, c) in comps.iter().enumerate() {
                    for (j, seat) in ["on", "off"].iter().enumerate() {
                        // Every subject ranks the compensators the same way: the strongest effect.
                        v.push((
                            c.as_str(),
                            *seat,
                            10.0 + 5.0 * i as f64 + j as f64 + 0.1 * s as f64,
                        ));
                    }
                }
                cells(&v)
            })
            .collect();
        let t = table(&StudyData {
            compensators: comps,
            arms: vec![],
            seats,
            subjects,
            conditions: Default::default(),
        });
        let pairs: Vec<&StatsRow> = t
            .iter()
            .filter(|r| r.test == "wilcoxon" && r.metric == "mse_tracking_mm2" && r.seat == "on")
            .collect();
        assert_eq!(pairs.len(), 10);
        for r in &pairs {
            assert_eq!(r.p_value, 2.0 / 256.0);
            assert!(r.p_adjusted.unwrap() > ALPHA);
            assert!(!r.reachable && r.note.contains("cannot reach"), "{r:?}");
            assert_eq!(r.effect_size, -1.0, "a < b for every subject");
        }
        let f = t
            .iter()
            .find(|r| r.test == "friedman" && r.metric == "mse_tracking_mm2")
            .unwrap();
        assert_eq!(f.effect_size, 1.0, "perfect concordance");
        let aov: Vec<&StatsRow> = t.iter().filter(|r| r.test == "rm_anova").collect();
        assert_eq!(aov.len(), 6, "three effects of two continuous metrics");
        // A constant rating has no differences: no Wilcoxon rows for it, nothing invented.
        assert!(
            !t.iter()
                .any(|r| r.metric == "rating_accuracy" && r.test == "wilcoxon")
        );
        // Seat comparisons: one per compensator and metric with data.
        assert_eq!(
            t.iter()
                .filter(|r| r.test == "wilcoxon_on_off" && r.metric == "ms_cab_accel")
                .count(),
            5
        );
    }

    #[test]
    fn cancellation_compares_each_compensator_on_the_machine_with_itself_cancelled() {
        let comps: Vec<String> = ["pid", "lqr"].map(String::from).to_vec();
        let seats = vec!["on".to_string(), "off".to_string()];
        // Six subjects; cancelling lowers every subject's error by a fifth, with a
        // subject-dependent error so the ANOVA has a residual.
        let subjects: Vec<Cells> = (0..6)
            .map(|s| {
                let mut v = Vec::new();
                for (i, c) in ["pid", "lqr"].iter().enumerate() {
                    let off = 100.0 + 20.0 * i as f64 + 7.0 * s as f64;
                    v.push((c.to_string(), "on", off));
                    v.push((c.to_string(), "off", off * 0.6));
                    v.push((
                        format!("{c}+personal"),
                        "on",
                        off * (0.8 + 0.01 * ((s * (i + 2)) % 5) as f64),
                    ));
                }
                let v: Vec<(&str, &str, f64)> =
                    v.iter().map(|(c, s, x)| (c.as_str(), *s, *x)).collect();
                cells(&v)
            })
            .collect();
        let t = table(&StudyData {
            compensators: comps,
            arms: vec![CancellationArm::Personal],
            seats,
            subjects,
            conditions: Default::default(),
        });
        let rows: Vec<&StatsRow> = t
            .iter()
            .filter(|r| r.test == "wilcoxon_cancellation" && r.metric == "mse_tracking_mm2")
            .collect();
        assert_eq!(rows.len(), 2);
        for r in &rows {
            // All six differences (off − cancelled) positive: the exact two-sided p is
            // 2/2^6, Holm over the two compensators doubles it.
            assert_eq!((r.seat.as_str(), r.n), ("on", 6));
            assert_eq!(r.b, format!("{}+personal", r.a));
            assert_eq!(r.p_value, 2.0 / 64.0);
            assert_eq!(r.p_adjusted, Some(4.0 / 64.0));
            assert_eq!(r.effect_size, 1.0, "a > b for every subject");
        }
        // The compensators' own comparisons read the uncancelled tests alone: on the
        // machine pid < lqr for every subject, as without the factor.
        let pair = t
            .iter()
            .find(|r| r.test == "wilcoxon" && r.seat == "on" && r.metric == "mse_tracking_mm2")
            .unwrap();
        assert_eq!((pair.n, pair.effect_size), (6, -1.0));
        let effects: Vec<&str> = t
            .iter()
            .filter(|r| r.test == "rm_anova" && r.seat == "on")
            .map(|r| r.a.as_str())
            .collect();
        assert_eq!(
            effects,
            [
                "controller",
                "cancellation:personal",
                "controller:cancellation:personal"
            ]
            .repeat(2)
        );
        let cancel = t
            .iter()
            .find(|r| r.a == "cancellation:personal" && r.metric == "log_mse_tracking_mm2")
            .unwrap();
        assert!(cancel.p_value < 1e-4, "{cancel:?}");
    }
}
