//! The statistics against scipy and pingouin (`tools/fixtures/make_stats_fixtures.py` made
//! `server/fixtures/stats_reference.json` from data it drew itself).

use serde_json::Value;

use super::nonparametric::{friedman, holm, wilcoxon};
use super::rm_anova::{Effect, rm_anova2};
use super::special::{chi2_sf, f_sf, normal_sf};

fn reference() -> Value {
    serde_json::from_str(include_str!("../../../../fixtures/stats_reference.json")).unwrap()
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

fn nums(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(num).collect()
}

#[track_caller]
fn close(got: f64, want: f64, rel: f64, what: &str) {
    let tol = rel * want.abs().max(1e-300);
    assert!(
        (got - want).abs() <= tol.max(1e-15),
        "{what}: {got} against the reference {want}"
    );
}

#[test]
fn tail_probabilities_match_scipy() {
    let r = reference();
    for c in r["special"]["chi2_sf"].as_array().unwrap() {
        let c = nums(c);
        close(
            chi2_sf(c[0], c[1]),
            c[2],
            1e-11,
            &format!("chi2.sf({}, {})", c[0], c[1]),
        );
    }
    for c in r["special"]["f_sf"].as_array().unwrap() {
        let c = nums(c);
        close(f_sf(c[0], c[1], c[2]), c[3], 1e-10, &format!("f.sf({c:?})"));
    }
    for c in r["special"]["normal_sf"].as_array().unwrap() {
        let c = nums(c);
        close(normal_sf(c[0]), c[1], 1e-11, &format!("norm.sf({})", c[0]));
    }
}

#[test]
fn friedman_matches_scipy_and_kendalls_w_pingouin() {
    for (i, c) in reference()["friedman"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
    {
        let rows: Vec<Vec<f64>> = c["rows"].as_array().unwrap().iter().map(nums).collect();
        let f = friedman(&rows).unwrap();
        close(f.chi2, num(&c["chi2"]), 1e-12, &format!("case {i}: chi2"));
        close(
            f.p_value,
            num(&c["p_value"]),
            1e-10,
            &format!("case {i}: p"),
        );
        close(
            f.kendall_w,
            num(&c["kendall_w"]),
            1e-12,
            &format!("case {i}: W"),
        );
    }
}

#[test]
fn wilcoxon_matches_scipy_and_the_rank_biserial_pingouin() {
    for (i, c) in reference()["wilcoxon"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
    {
        let w = wilcoxon(&nums(&c["a"]), &nums(&c["b"])).unwrap();
        assert_eq!(w.exact, c["exact"].as_bool().unwrap(), "case {i}: exact");
        close(
            w.statistic,
            num(&c["statistic"]),
            1e-12,
            &format!("case {i}: statistic"),
        );
        close(
            w.p_value,
            num(&c["p_value"]),
            1e-10,
            &format!("case {i}: p"),
        );
        close(
            w.rank_biserial,
            num(&c["rank_biserial"]),
            1e-12,
            &format!("case {i}: r"),
        );
    }
}

#[test]
fn holm_matches_pingouin() {
    let r = reference();
    let adjusted = holm(&nums(&r["holm"]["p"]));
    for (got, want) in adjusted.iter().zip(nums(&r["holm"]["adjusted"])) {
        close(*got, want, 1e-12, "holm");
    }
}

#[test]
fn two_way_rm_anova_matches_pingouin() {
    for (i, c) in reference()["rm_anova"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
    {
        let y: Vec<Vec<Vec<f64>>> = c["y"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s.as_array().unwrap().iter().map(nums).collect())
            .collect();
        let aov = rm_anova2(&y).unwrap();
        for (name, e) in [("a", aov.a), ("b", aov.b), ("ab", aov.ab)] {
            let want = &c[name];
            let check = |got: f64, key: &str| {
                close(
                    got,
                    num(&want[key]),
                    1e-9,
                    &format!("case {i} {name}: {key}"),
                )
            };
            let Effect {
                ss,
                df1,
                df2,
                f,
                p_unc,
                eps,
                p_gg,
                ng2,
            } = e;
            check(ss, "ss");
            check(df1, "df1");
            check(df2, "df2");
            check(f, "f");
            check(p_unc, "p_unc");
            check(eps, "eps");
            check(p_gg, "p_gg");
            check(ng2, "ng2");
        }
    }
}
