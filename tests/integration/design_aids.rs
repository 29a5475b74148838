//! The design aids end to end: a study with Williams orders and difficulty-matched targets
//! is refused with the field named when its values cannot work, and otherwise runs a pilot
//! whose subjects' orders are the design's rows and whose every target has the same
//! mean-squared step change; the learning curve's points are the exported trials' values
//! and its slope is the one computed here from the export; and the dashboard (in Chromium)
//! sets both aids from its study form and shows the curve and the slope.

use std::collections::BTreeMap;
use std::time::Duration;

use bdft_tests::TempDir;
use bdft_tests::server::{Api, Server, eventually, pilot_copy};
use bdft_tests::webdriver::{Driver, artifacts_dir};
use serde_json::{Value, json};

/// The Williams design for 5 compensators, written out from its textbook construction (the
/// cyclic square of 0, 1, 4, 2, 3, then its mirror images).
const WILLIAMS_5: [[usize; 5]; 10] = [
    [0, 1, 4, 2, 3],
    [1, 2, 0, 3, 4],
    [2, 3, 1, 4, 0],
    [3, 4, 2, 0, 1],
    [4, 0, 3, 1, 2],
    [3, 2, 4, 1, 0],
    [4, 3, 0, 2, 1],
    [0, 4, 1, 3, 2],
    [1, 0, 2, 4, 3],
    [2, 1, 3, 0, 4],
];

/// The default parameters with short tests and the design aids on.
fn design_params(api: &Api) -> Value {
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(2.0);
    params["practice_s"] = json!(2.0);
    params["step_interval_s"] = json!(0.5);
    params["order_design"] = json!("williams");
    params["matched_targets"] = json!(true);
    params
}

fn create(api: &Api, params: &Value) -> (u16, Value) {
    api.post(
        "/api/studies",
        json!({ "name": "design aids", "params": params, "seed": 9 }),
    )
}

/// Least-squares slope of y on x.
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

#[test]
fn design_aids_are_validated_followed_by_enrolment_and_drawn_from_the_export() {
    let server = Server::start("design_aids");
    let api = server.experimenter();

    // Bad values: 422 naming the field and what is allowed.
    let mut bad = design_params(&api);
    bad["order_design"] = json!("latin");
    let (code, body) = create(&api, &bad);
    assert_eq!(code, 422, "{body}");
    let msg = body["error"].as_str().unwrap();
    assert!(
        msg.contains("order_design") && msg.contains("random") && msg.contains("williams"),
        "{msg}"
    );
    let mut bad = design_params(&api);
    bad["matched_targets"] = json!("yes");
    let (code, body) = create(&api, &bad);
    assert_eq!(code, 422, "{body}");
    assert!(body["error"].as_str().unwrap().contains("matched_targets"));
    // Two steps of a target cannot have the matched step change (±a: always 2.5 a²).
    let mut short = design_params(&api);
    short["practice_s"] = json!(1.0);
    let (code, body) = create(&api, &short);
    assert_eq!(code, 422, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .starts_with("matched_targets:"),
        "{body}"
    );

    let params = design_params(&api);
    let (code, body) = create(&api, &params);
    assert_eq!(code, 200, "{body}");
    let study = body["id"].as_i64().unwrap();
    let copy = pilot_copy(&api, study, 4);
    let kinds: Vec<String> = params["controllers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["kind"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(kinds.len(), 5);
    let std = params["target_std_mm"].as_f64().unwrap();
    let range = params["target_range_mm"].as_f64().unwrap();

    // Orders: the machine runs row i mod 10, the desk row (i + 5) mod 10.
    let (_, subjects) = api.get(&format!("/api/studies/{copy}/subjects"));
    let subjects = subjects.as_array().unwrap();
    assert_eq!(subjects.len(), 4);
    for s in subjects {
        let index = s["subject"]["enrol_index"].as_u64().unwrap() as usize;
        let id = s["subject"]["id"].as_i64().unwrap();
        let (_, detail) = api.get(&format!("/api/subjects/{id}"));
        let trials: Vec<&Value> = detail["trials"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| &t["trial"])
            .filter(|t| t["attempt"] == 1)
            .collect();
        for (seat, row) in [("on", index % 10), ("off", (index + 5) % 10)] {
            let mut at_seat: Vec<&&Value> = trials
                .iter()
                .filter(|t| t["phase"] == "test" && t["station"] == seat)
                .collect();
            at_seat.sort_by_key(|t| t["position"].as_i64());
            let order: Vec<&str> = at_seat
                .iter()
                .map(|t| t["controller"].as_str().unwrap())
                .collect();
            let want: Vec<&str> = WILLIAMS_5[row].iter().map(|&c| kinds[c].as_str()).collect();
            assert_eq!(order, want, "subject {index} at {seat}");
        }
        // Every target, the practice's included: the study's step change, exact mean and
        // std, within range; and recorded as drawn.
        let wanted = 2.0 * std * std;
        for t in &trials {
            let levels: Vec<f64> =
                serde_json::from_str(t["target_levels_json"].as_str().unwrap()).unwrap();
            let n = levels.len() as f64;
            let mut prev = 0.0;
            let ms = levels
                .iter()
                .map(|l| {
                    let step = l - prev;
                    prev = *l;
                    step * step
                })
                .sum::<f64>()
                / n;
            let mean = levels.iter().sum::<f64>() / n;
            let sd = (levels.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / n).sqrt();
            assert!((ms / wanted - 1.0).abs() < 1e-9, "{ms} against {wanted}");
            assert!(mean.abs() < 1e-9 && (sd / std - 1.0).abs() < 1e-9);
            assert!(levels.iter().all(|l| l.abs() <= range));
            let recorded = t["target_ms_step_mm2"].as_f64().unwrap();
            assert!((recorded / ms - 1.0).abs() < 1e-12, "{t}");
        }
    }

    // The learning curve against the trials export.
    let (_, csv) = api.get_text(&format!("/api/studies/{copy}/export/trials"));
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    // subject → position → (seat, MSE) of the latest attempt of each scored test if complete.
    let mut exported: BTreeMap<String, BTreeMap<u32, (String, f64)>> = BTreeMap::new();
    for r in &rows {
        let later = rows.iter().any(|u| {
            u[col("subject_code")] == r[col("subject_code")]
                && u[col("slot")] == r[col("slot")]
                && u[col("attempt")].parse::<u32>().unwrap()
                    > r[col("attempt")].parse::<u32>().unwrap()
        });
        if r[col("phase")] == "practice" || r[col("status")] != "complete" || later {
            continue;
        }
        // The export carries each test's realized step change: matched, 2·std².
        let ms_step: f64 = r[col("target_ms_step_mm2")].parse().unwrap();
        assert!(
            (ms_step / (2.0 * std * std) - 1.0).abs() < 1e-8,
            "{ms_step}"
        );
        let position = (r[col("block")].parse::<u32>().unwrap() - 1) * 5
            + r[col("position")].parse::<u32>().unwrap();
        exported
            .entry(r[col("subject_code")].to_string())
            .or_default()
            .insert(
                position,
                (
                    r[col("station")].to_string(),
                    r[col("mse_tracking_mm2")].parse().unwrap(),
                ),
            );
    }
    assert_eq!(exported.len(), 4);
    let (code, curve) = api.get(&format!("/api/studies/{copy}/learning"));
    assert_eq!(code, 200, "{curve}");
    assert_eq!(curve["positions"], 10);
    let close = |a: f64, b: f64| (a / b - 1.0).abs() < 1e-6;
    let mut slopes = vec![];
    for s in curve["subjects"].as_array().unwrap() {
        let want = &exported[s["code"].as_str().unwrap()];
        let points = s["points"].as_array().unwrap();
        assert_eq!(points.len(), want.len(), "{s}");
        for p in points {
            let (seat, mse) = &want[&(p["position"].as_u64().unwrap() as u32)];
            assert_eq!(p["station"], seat.as_str());
            assert!(close(p["mse_tracking_mm2"].as_f64().unwrap(), *mse), "{p}");
        }
        let logs: Vec<(f64, f64)> = want
            .iter()
            .map(|(x, (_, y))| (f64::from(*x), y.ln()))
            .collect();
        let b = slope(&logs);
        assert!(
            (s["slope"].as_f64().unwrap() - b).abs() < 1e-6,
            "{s} against {b}"
        );
        slopes.push(b);
    }
    // The median of four slopes: the mean of the middle two.
    slopes.sort_by(f64::total_cmp);
    let median = (slopes[1] + slopes[2]) / 2.0;
    assert!(
        (curve["slope"].as_f64().unwrap() - median).abs() < 1e-6,
        "{curve}"
    );
    assert_eq!(curve["slope_n"], 4);
    assert_eq!(curve["slope_unit"], "ln(mm²) per test position");
    // Medians per seat and position over the subjects there.
    for m in curve["median"].as_array().unwrap() {
        let mut xs: Vec<f64> = exported
            .values()
            .filter_map(|v| v.get(&(m["position"].as_u64().unwrap() as u32)))
            .filter(|(seat, _)| seat == m["station"].as_str().unwrap())
            .map(|(_, y)| *y)
            .collect();
        xs.sort_by(f64::total_cmp);
        let mid = xs.len() / 2;
        let med = if xs.len() % 2 == 1 {
            xs[mid]
        } else {
            (xs[mid - 1] + xs[mid]) / 2.0
        };
        assert_eq!(m["n"], xs.len());
        assert!(close(m["mse_tracking_mm2"].as_f64().unwrap(), med), "{m}");
    }

    // The figure: one line per subject and seat, a median line per seat; PNG as well.
    let (code, svg) = api.get_text(&format!("/api/studies/{copy}/plots/learning_curve.svg"));
    assert_eq!(code, 200);
    assert!(svg.starts_with("<svg"), "{svg}");
    assert_eq!(svg.matches("<polyline").count(), 4 * 2 + 2, "{svg}");
    // (The PNG's bytes are checked in the unit test; here that it is served.)
    let (code, _) = api.get(&format!("/api/studies/{copy}/plots/learning_curve.png"));
    assert_eq!(code, 200);
    let (code, body) = api.get(&format!("/api/studies/{copy}/plots/learning.svg"));
    assert_eq!(code, 422, "{body}");
    assert!(body["error"].as_str().unwrap().contains("learning_curve"));
}

#[test]
fn the_dashboard_sets_the_design_aids_and_shows_the_learning_curve() {
    let server = Server::start("design_aids_browser");
    let base = server.base.clone();
    let api = server.experimenter();
    let downloads = TempDir::new("downloads");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.log_in_to_dashboard(&base);
    // The form shows the defaults of a study that leaves the design aids out.
    assert_eq!(
        dash.exec(
            "return document.querySelector('#p-order_design').value;",
            json!([])
        ),
        "random"
    );
    assert_eq!(
        dash.exec(
            "return document.querySelector('#p-matched_targets').value;",
            json!([])
        ),
        "false"
    );
    dash.type_into("#study-name", "Design aids");
    dash.type_into("#p-trial_s", "2");
    dash.type_into("#p-practice_s", "2");
    dash.type_into("#p-step_interval_s", "0.5");
    dash.choose("#p-order_design", "williams");
    dash.choose("#p-matched_targets", "true");
    dash.click("#study-create");
    let study = eventually(Duration::from_secs(20), || {
        api.get("/api/studies").1.as_array()?.first()?["id"].as_i64()
    });
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(st["params"]["order_design"], "williams");
    assert_eq!(st["params"]["matched_targets"], true);

    let copy = pilot_copy(&api, study, 2);
    dash.goto(&format!("{base}/"));
    dash.find("#estop");
    dash.select_study(copy);
    dash.wait_until(
        "const i = document.querySelector('img[src*=\"learning_curve.svg\"]'); return i && i.complete && i.naturalWidth > 0;",
        json!([]),
    );
    let slope = dash.wait_until(
        "const p = document.querySelector('#learning-slope'); return p && p.textContent.includes('per test position') && p.textContent;",
        json!([]),
    );
    let (_, curve) = api.get(&format!("/api/studies/{copy}/learning"));
    assert!(
        slope
            .as_str()
            .unwrap()
            .contains(&format!("over {} subjects", curve["slope_n"])),
        "{slope}"
    );
    dash.exec(
        "document.querySelector('#learning-slope').scrollIntoView();",
        json!([]),
    );
    dash.screenshot(&artifacts_dir().join("design-aids-learning-curve.png"));
}
