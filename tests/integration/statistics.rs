//! The study's statistics over HTTP, on a pilot's data: the table has every analysis, its
//! Friedman statistic agrees with one computed here from the trials export, and at a
//! pilot's small n every pairwise comparison says it cannot reach significance.

use std::collections::BTreeMap;

use std::time::Duration;

use bdft_tests::server::{Server, eventually, pilot_copy, short_study};
use serde_json::{Value, json};

#[test]
fn a_pilots_statistics_agree_with_its_export_and_state_the_small_n_floor() {
    let server = Server::start("statistics");
    let api = server.experimenter();
    let study = short_study(&api, 1.0, 0.3);
    let copy = pilot_copy(&api, study, 3);
    let (code, table) = api.get(&format!("/api/studies/{copy}/stats"));
    assert_eq!(code, 200, "{table}");
    let rows = table.as_array().unwrap();
    let find = |test: &str, metric: &str, station: &str| -> Vec<&Value> {
        rows.iter()
            .filter(|r| r["test"] == test && r["metric"] == metric && r["station"] == station)
            .collect()
    };
    // Friedman of tracking error on the machine, recomputed from the export: ranks within
    // each subject (continuous values: no ties).
    let (_, csv) = api.get_text(&format!("/api/studies/{copy}/export/trials"));
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    // subject → compensator → value (the export is in each subject's own random order).
    let mut by_subject: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    for line in lines {
        let r: Vec<&str> = line.split(',').collect();
        if r[col("phase")] == "practice"
            || r[col("station")] != "on"
            || r[col("status")] != "complete"
        {
            continue;
        }
        by_subject
            .entry(r[col("subject_code")].to_string())
            .or_default()
            .insert(
                r[col("controller")].to_string(),
                r[col("mse_tracking_mm2")].parse().unwrap(),
            );
    }
    assert_eq!(by_subject.len(), 3, "{by_subject:?}");
    let k = by_subject.values().next().unwrap().len();
    assert_eq!(k, 5);
    let mut rank_sums = vec![0.0; k];
    for values in by_subject.values() {
        let values: Vec<f64> = values.values().copied().collect();
        for (i, v) in values.iter().enumerate() {
            rank_sums[i] += 1.0 + values.iter().filter(|w| *w < v).count() as f64;
        }
    }
    let (n, kf) = (3.0, k as f64);
    let chi2 = 12.0 / (n * kf * (kf + 1.0)) * rank_sums.iter().map(|r| r * r).sum::<f64>()
        - 3.0 * n * (kf + 1.0);
    let f = find("friedman", "mse_tracking_mm2", "on");
    assert_eq!(f.len(), 1, "{table}");
    assert_eq!(f[0]["n"], 3);
    assert!(
        (f[0]["statistic"].as_f64().unwrap() - chi2).abs() < 1e-9,
        "{} vs {chi2}",
        f[0]
    );
    // Ten pairs per seat, none able to reach significance with 3 subjects, and saying so.
    for seat in ["on", "off"] {
        let pairs = find("wilcoxon", "mse_tracking_mm2", seat);
        assert_eq!(pairs.len(), 10, "{seat}");
        for p in pairs {
            assert_eq!(p["reachable"], false, "{p}");
            assert!(p["note"].as_str().unwrap().contains("cannot reach"), "{p}");
            assert!(p["p_adjusted"].as_f64().unwrap() >= p["p_value"].as_f64().unwrap());
        }
    }
    assert_eq!(find("wilcoxon_on_off", "ms_cab_accel", "on-off").len(), 5);
    let aov = find("rm_anova", "log_mse_tracking_mm2", "both");
    assert_eq!(aov.len(), 3, "{table}");
    // The same table as CSV, from the API (and `bdft-server export --kind stats`).
    let (code, stats_csv) = api.get_text(&format!("/api/studies/{copy}/export/stats"));
    assert_eq!(code, 200);
    let mut lines = stats_csv.lines();
    let head = lines.next().unwrap();
    assert!(
        head.starts_with("test,metric,station,a,b,n,statistic,p_value,p_adjusted,effect_size"),
        "{head}"
    );
    let stats_rows: Vec<&str> = lines.collect();
    assert_eq!(stats_rows.len(), rows.len());
    // Every variable the stats and summary exports name is a column of the trials export
    // (its unit in its name), or the logarithm of one.
    let (code, summary_csv) = api.get_text(&format!("/api/studies/{copy}/export/summary"));
    assert_eq!(code, 200);
    let summary_rows: Vec<&str> = summary_csv.lines().skip(1).collect();
    assert!(!summary_rows.is_empty());
    let named: Vec<&str> = stats_rows
        .iter()
        .map(|r| r.split(',').nth(1).unwrap())
        .chain(summary_rows.iter().map(|r| r.split(',').nth(2).unwrap()))
        .collect();
    for name in &named {
        let column = name.strip_prefix("log_").unwrap_or(name);
        assert!(header.contains(&column), "{name} is no trials column");
    }
    for want in ["ms_cab_accel_mm2_s4", "rating_accuracy_1to7"] {
        assert!(named.contains(&want), "{want} missing from {named:?}");
    }
    // The planner on the pilot's spread: 8 subjects cannot make any of the 10 pairs
    // significant (2/2^8 × 10 > 0.05), 12 can be simulated; bad requests (422) name the field.
    let (code, plan) = api.post(
        &format!("/api/studies/{copy}/plan"),
        json!({ "subjects": [8, 12], "metric": "mse_tracking_mm2", "station": "on", "draws": 200, "seed": 7 }),
    );
    assert_eq!(code, 200, "{plan}");
    let plans = plan["plans"].as_array().unwrap();
    assert_eq!(plans[0]["subjects"], 8);
    assert!(
        plans[0]["note"].as_str().unwrap().contains("0.078"),
        "{plan}"
    );
    assert!(
        plans[0]["pairs"]
            .as_array()
            .unwrap()
            .iter()
            .all(|p| p["possible"] == false && p["power"] == 0.0)
    );
    assert_eq!(plans[1]["draws"], 200);
    assert!(
        plans[1]["pairs"]
            .as_array()
            .unwrap()
            .iter()
            .all(|p| p["possible"] == true)
    );
    assert_eq!(plan["model"]["pilot_n"], 3);
    for (body, field) in [
        (
            json!({ "subjects": [1], "metric": "mse_tracking_mm2", "station": "on" }),
            "subjects",
        ),
        (
            json!({ "subjects": [8], "metric": "rating_speed", "station": "on" }),
            "metric",
        ),
        (
            json!({ "subjects": [8], "metric": "ms_cab_accel", "station": "roof" }),
            "station",
        ),
    ] {
        let (code, e) = api.post(&format!("/api/studies/{copy}/plan"), body);
        assert_eq!(code, 422, "{e}");
        assert!(e["error"].as_str().unwrap().starts_with(field), "{e}");
    }
}

#[test]
fn the_population_planner_runs_whole_simulated_studies_in_the_background_with_progress() {
    let server = Server::start("plan-population");
    let api = server.experimenter();
    // 10 s tests keep the simulated trials cheap; the planner runs them in full.
    let study = short_study(&api, 10.0, 1.0);
    let plan = |draws: usize| {
        json!({ "source": "population", "subjects": [8, 12], "metric": "mse_tracking_mm2",
                "station": "on", "draws": draws, "seed": 3 })
    };
    // Bad requests name the field; a population plan is a background job only.
    let (code, e) = api.post(&format!("/api/studies/{study}/plan"), plan(20));
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().starts_with("source"), "{e}");
    let (code, e) = api.post(&format!("/api/studies/{study}/plan-job"), plan(5));
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().starts_with("draws"), "{e}");
    let (code, e) = api.post(
        &format!("/api/studies/{study}/plan-job"),
        json!({ "source": "population", "subjects": [200], "metric": "mse_tracking_mm2",
                "station": "on", "draws": 10000 }),
    );
    assert_eq!(code, 422, "{e}");
    assert!(
        e["error"].as_str().unwrap().starts_with("draws × subjects"),
        "{e}"
    );

    let run = || {
        api.ok(&format!("/api/studies/{study}/plan-job"), plan(20));
        eventually(Duration::from_secs(600), || {
            let (_, s) = api.get("/api/plan-job");
            (s["running"] == false && (s["report"].is_object() || s["error"].is_string()))
                .then_some(s)
        })
    };
    let status = run();
    assert!(status["error"].is_null(), "{status}");
    // Progress counted every simulated trial: 20 studies × 12 subjects × 5 compensators.
    assert_eq!(status["total"], 20 * 12 * 5, "{status}");
    assert_eq!(status["done"], status["total"]);
    let report = &status["report"];
    assert_eq!(report["source"], "population");
    let plans = report["plans"].as_array().unwrap();
    // 8 subjects: the exact floor rules every pair out, nothing is simulated for it.
    assert!(
        plans[0]["note"].as_str().unwrap().contains("0.078"),
        "{report}"
    );
    assert_eq!(plans[0]["draws"], 0);
    // 12 subjects: simulated, each power a probability.
    assert_eq!(plans[1]["draws"], 20);
    for p in plans[1]["pairs"].as_array().unwrap() {
        let power = p["power"].as_f64().unwrap();
        assert!(p["possible"] == true && (0.0..=1.0).contains(&power), "{p}");
    }
    // The model is estimated from the simulated subjects that completed every test.
    let n = report["model"]["pilot_n"].as_u64().unwrap();
    assert!((2..=240).contains(&n), "{n}");
    assert_eq!(report["model"]["compensators"].as_array().unwrap().len(), 5);

    // Seeded: the same plan again — and from the command line, in another process on
    // another thread split — is the same plan.
    assert_eq!(run()["report"], *report);
    let out = bdft_tests::server_command([
        "plan",
        "--db",
        &server.store(),
        "--study",
        &study.to_string(),
        "--subjects",
        "8,12",
        "--draws",
        "20",
        "--seed",
        "3",
        "--station",
        "on",
    ]);
    let cli: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(cli, *report);
    // A bad argument is refused with the allowed values.
    let out = bdft_tests::server_output([
        "plan",
        "--db",
        &server.store(),
        "--subjects",
        "8",
        "--source",
        "guess",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("population") && err.contains("pilot"), "{err}");
}
