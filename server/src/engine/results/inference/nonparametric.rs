//! Rank tests for a within-subject design: Friedman's test across the compensators (with
//! Kendall's W), the Wilcoxon signed-rank test of a pair (exact for n ≤ 25, with the
//! matched-pairs rank-biserial correlation), and Holm's step-down adjustment; and for a
//! factor between subjects (the machine's condition), the Kruskal–Wallis test. The
//! conventions are scipy's and pingouin's, so that their numbers can check ours.

use super::special::{chi2_sf, normal_sf};

/// Midranks (1-based) of `values`; ties share the mean of the ranks they span.
pub fn midranks(values: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&i, &j| values[i].total_cmp(&values[j]));
    let mut ranks = vec![0.0; values.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && values[order[j + 1]] == values[order[i]] {
            j += 1;
        }
        let rank = (i + j) as f64 / 2.0 + 1.0;
        for &o in &order[i..=j] {
            ranks[o] = rank;
        }
        i = j + 1;
    }
    ranks
}

/// Sizes of the groups of equal values (only groups of two or more matter for corrections).
fn tie_sizes(values: &[f64]) -> Vec<f64> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let mut sizes = Vec::new();
    let mut i = 0;
    while i < sorted.len() {
        let j = sorted[i..].iter().take_while(|v| **v == sorted[i]).count();
        sizes.push(j as f64);
        i += j;
    }
    sizes
}

/// Friedman's test of k related samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Friedman {
    pub n: usize,
    pub k: usize,
    /// The tie-corrected χ² statistic (scipy's `friedmanchisquare`).
    pub chi2: f64,
    pub p_value: f64,
    /// Kendall's coefficient of concordance, χ² / (n (k − 1)) (pingouin's `friedman`).
    pub kendall_w: f64,
}

/// Friedman's test on `rows`: one row per subject, one column per condition (every row the
/// same length k ≥ 2, n ≥ 2 rows). `None` when there is nothing to test.
pub fn friedman(rows: &[Vec<f64>]) -> Option<Friedman> {
    let n = rows.len();
    let k = rows.first()?.len();
    if n < 2 || k < 2 || rows.iter().any(|r| r.len() != k) {
        return None;
    }
    let mut rank_sums = vec![0.0; k];
    let mut ties = 0.0;
    for row in rows {
        for (s, r) in rank_sums.iter_mut().zip(midranks(row)) {
            *s += r;
        }
        ties += tie_sizes(row).iter().map(|t| t * t * t - t).sum::<f64>();
    }
    let (nf, kf) = (n as f64, k as f64);
    let ssr: f64 = rank_sums.iter().map(|r| r * r).sum();
    let correction = 1.0 - ties / (nf * kf * (kf * kf - 1.0));
    if correction <= 0.0 {
        // Every subject tied every condition: no evidence of any difference.
        return Some(Friedman {
            n,
            k,
            chi2: 0.0,
            p_value: 1.0,
            kendall_w: 0.0,
        });
    }
    let chi2 = (12.0 / (nf * kf * (kf + 1.0)) * ssr - 3.0 * nf * (kf + 1.0)) / correction;
    Some(Friedman {
        n,
        k,
        chi2,
        p_value: chi2_sf(chi2, kf - 1.0),
        kendall_w: chi2 / (nf * (kf - 1.0)),
    })
}

/// Largest n for which the signed-rank test uses its exact distribution.
pub const EXACT_MAX_N: usize = 25;

/// The Wilcoxon signed-rank test of paired samples a and b (differences a − b, zero
/// differences dropped as scipy's default `zero_method="wilcox"` does).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wilcoxon {
    /// Pairs with a non-zero difference.
    pub n: usize,
    /// min(R⁺, R⁻), scipy's two-sided statistic.
    pub statistic: f64,
    pub r_plus: f64,
    pub r_minus: f64,
    /// Two-sided.
    pub p_value: f64,
    /// Whether `p_value` is from the exact distribution (else the normal approximation).
    pub exact: bool,
    /// Matched-pairs rank-biserial correlation (R⁺ − R⁻) / (R⁺ + R⁻): +1 when every a > b.
    pub rank_biserial: f64,
}

pub fn wilcoxon(a: &[f64], b: &[f64]) -> Option<Wilcoxon> {
    if a.len() != b.len() {
        return None;
    }
    let d: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(x, y)| x - y)
        .filter(|d| *d != 0.0)
        .collect();
    let n = d.len();
    if n == 0 {
        return None;
    }
    let abs: Vec<f64> = d.iter().map(|v| v.abs()).collect();
    let ranks = midranks(&abs);
    let r_plus: f64 = d
        .iter()
        .zip(&ranks)
        .filter(|(d, _)| **d > 0.0)
        .map(|(_, r)| r)
        .sum();
    let total = (n * (n + 1)) as f64 / 2.0;
    let r_minus = total - r_plus;
    let exact = n <= EXACT_MAX_N;
    let p_value = if exact {
        exact_two_sided(&ranks, r_plus)
    } else {
        let ties: f64 = tie_sizes(&abs).iter().map(|t| t * t * t - t).sum();
        let nf = n as f64;
        let var = nf * (nf + 1.0) * (2.0 * nf + 1.0) / 24.0 - ties / 48.0;
        let z = (r_plus - total / 2.0) / var.sqrt();
        (2.0 * normal_sf(z.abs())).min(1.0)
    };
    Some(Wilcoxon {
        n,
        statistic: r_plus.min(r_minus),
        r_plus,
        r_minus,
        p_value,
        exact,
        rank_biserial: (r_plus - r_minus) / total,
    })
}

/// Two-sided p of R⁺ under the null (each rank's sign a fair coin): the exact distribution
/// of the sum of the given ranks, by counting subsets. Midranks are halves at worst, so the
/// count runs over doubled ranks, which are whole numbers; without ties this is the
/// classical exact test (scipy's `method="exact"`), with ties the exact conditional one.
fn exact_two_sided(ranks: &[f64], r_plus: f64) -> f64 {
    let doubled: Vec<usize> = ranks.iter().map(|r| (r * 2.0).round() as usize).collect();
    let max: usize = doubled.iter().sum();
    // counts[s]: number of sign patterns with doubled R⁺ = s (as f64: 2^25 fits exactly).
    let mut counts = vec![0.0f64; max + 1];
    counts[0] = 1.0;
    let mut reach = 0;
    for &r in &doubled {
        for s in (0..=reach).rev() {
            let c = counts[s];
            if c > 0.0 {
                counts[s + r] += c;
            }
        }
        reach += r;
    }
    let total = 2f64.powi(ranks.len() as i32);
    let t = (r_plus * 2.0).round() as usize;
    let below: f64 = counts[..=t].iter().sum();
    let above: f64 = counts[t..].iter().sum();
    (2.0 * below.min(above) / total).min(1.0)
}

/// The smallest two-sided p the exact signed-rank test can give with n pairs: 2 / 2ⁿ (every
/// difference of one sign).
pub fn wilcoxon_floor(n: usize) -> f64 {
    2.0 / 2f64.powi(n as i32)
}

/// The Kruskal–Wallis test of k independent groups.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KruskalWallis {
    /// Values in all groups.
    pub n: usize,
    pub k: usize,
    /// The tie-corrected H (scipy's `kruskal`).
    pub h: f64,
    /// From χ² with k − 1 degrees of freedom (asymptotic, as scipy's).
    pub p_value: f64,
    /// ε² = H / (n − 1) (Tomczak & Tomczak 2014): the share of the ranks' variance between
    /// the groups.
    pub epsilon2: f64,
}

/// The Kruskal–Wallis test on `groups` (at least two non-empty, n ≥ 3 values in all);
/// `None` when there is nothing to test.
pub fn kruskal_wallis(groups: &[Vec<f64>]) -> Option<KruskalWallis> {
    let k = groups.len();
    let all: Vec<f64> = groups.iter().flatten().copied().collect();
    let n = all.len();
    if k < 2 || n < 3 || groups.iter().any(Vec::is_empty) {
        return None;
    }
    let ranks = midranks(&all);
    let nf = n as f64;
    let mut at = 0;
    let mut between = 0.0;
    for g in groups {
        let sum: f64 = ranks[at..at + g.len()].iter().sum();
        between += sum * sum / g.len() as f64;
        at += g.len();
    }
    let ties: f64 = tie_sizes(&all).iter().map(|t| t * t * t - t).sum();
    let correction = 1.0 - ties / (nf * nf * nf - nf);
    let h = if correction <= 0.0 {
        // Every value equal: no evidence of any difference.
        0.0
    } else {
        (12.0 / (nf * (nf + 1.0)) * between - 3.0 * (nf + 1.0)) / correction
    };
    Some(KruskalWallis {
        n,
        k,
        h,
        p_value: chi2_sf(h, (k - 1) as f64),
        epsilon2: h / (nf - 1.0),
    })
}

/// Holm's step-down adjustment of a family of p-values (returned in the given order).
pub fn holm(p: &[f64]) -> Vec<f64> {
    let m = p.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&i, &j| p[i].total_cmp(&p[j]));
    let mut adjusted = vec![0.0; m];
    let mut running = 0.0f64;
    for (rank, &i) in order.iter().enumerate() {
        running = running.max(((m - rank) as f64 * p[i]).min(1.0));
        adjusted[i] = running;
    }
    adjusted
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn midranks_share_ties() {
        assert_eq!(midranks(&[3.0, 1.0, 3.0, 2.0]), vec![3.5, 1.0, 3.5, 2.0]);
    }

    #[test]
    fn exact_signed_rank_matches_enumeration_of_every_sign_pattern() {
        // An independent count: every one of the 2^n sign patterns, by brute force.
        let a = [1.2, 3.4, 0.5, 2.2, 2.2, 5.0, 0.1, 4.4];
        let b = [0.2, 3.0, 1.5, 1.2, 1.2, 2.0, 0.2, 0.4];
        let w = wilcoxon(&a, &b).unwrap();
        let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
        let ranks = midranks(&d.iter().map(|v| v.abs()).collect::<Vec<_>>());
        let n = ranks.len();
        let (mut lo, mut hi) = (0u32, 0u32);
        for mask in 0u32..(1 << n) {
            let s: f64 = (0..n)
                .filter(|i| mask >> i & 1 == 1)
                .map(|i| ranks[i])
                .sum();
            lo += u32::from(s <= w.r_plus + 1e-9);
            hi += u32::from(s >= w.r_plus - 1e-9);
        }
        let p = (2.0 * f64::from(lo.min(hi)) / f64::from(1u32 << n)).min(1.0);
        assert!((w.p_value - p).abs() < 1e-15, "{} vs {p}", w.p_value);
        assert!(w.exact);
    }

    #[test]
    fn the_floor_is_reached_when_every_difference_has_one_sign() {
        let a: Vec<f64> = (1..=8).map(f64::from).collect();
        let b = vec![0.0; 8];
        let w = wilcoxon(&a, &b).unwrap();
        assert_eq!(w.p_value, wilcoxon_floor(8));
        assert_eq!(w.rank_biserial, 1.0);
        assert_eq!(w.statistic, 0.0);
    }

    #[test]
    fn kruskal_wallis_is_the_analysis_of_variance_of_the_ranks() {
        // With ties: H = (n − 1) · SS_between / SS_total of the midranks, an equivalent form
        // that needs no tie correction.
        let groups = vec![
            vec![2.0, 3.5, 3.5, 7.0],
            vec![1.0, 3.5, 5.0],
            vec![6.0, 8.0, 9.0, 9.0, 10.0],
        ];
        let kw = kruskal_wallis(&groups).unwrap();
        let ranks = midranks(&groups.concat());
        let mean = ranks.iter().sum::<f64>() / ranks.len() as f64;
        let total: f64 = ranks.iter().map(|r| (r - mean).powi(2)).sum();
        let mut at = 0;
        let mut between = 0.0;
        for g in &groups {
            let m = ranks[at..at + g.len()].iter().sum::<f64>() / g.len() as f64;
            between += g.len() as f64 * (m - mean).powi(2);
            at += g.len();
        }
        let h = (ranks.len() - 1) as f64 * between / total;
        assert!((kw.h - h).abs() < 1e-12, "{} against {h}", kw.h);
        assert_eq!((kw.n, kw.k), (12, 3));
    }

    #[test]
    fn kruskal_wallis_of_two_groups_is_the_rank_sum_tests_z_squared() {
        // Separated groups of three: rank sums 6 and 15, H = 12/42 · (36 + 225)/3 − 21 =
        // 27/7, and with two groups H = z² of the Mann–Whitney normal approximation, so
        // p = erfc(√(H/2)) = 2·Φ(−√H).
        let kw = kruskal_wallis(&[vec![1.0, 2.0, 3.0], vec![4.0, 5.0, 6.0]]).unwrap();
        assert!((kw.h - 27.0 / 7.0).abs() < 1e-12, "{}", kw.h);
        let u: f64 = 0.0;
        let z = (u - 9.0 / 2.0) / (9.0 * 7.0 / 12.0f64).sqrt();
        assert!((kw.h - z * z).abs() < 1e-12);
        assert!((kw.p_value - 2.0 * normal_sf(z.abs())).abs() < 1e-12);
        assert!(kruskal_wallis(&[vec![1.0], vec![]]).is_none());
        let tied = kruskal_wallis(&[vec![2.0, 2.0], vec![2.0]]).unwrap();
        assert_eq!((tied.h, tied.p_value), (0.0, 1.0));
    }

    #[test]
    fn holm_is_monotone_and_capped() {
        let adj = holm(&[0.01, 0.04, 0.03, 0.5]);
        assert_eq!(adj, vec![0.04, 0.09, 0.09, 0.5]);
        assert_eq!(holm(&[0.6, 0.7]), vec![1.0, 1.0]);
    }
}
