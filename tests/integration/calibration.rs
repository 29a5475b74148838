//! Calibration of a study's synthetic population through the real server and command line:
//! bad tables refused with a 422 naming the row, a fit stored as the study's next population
//! version with its audit row, cancel, the model card's validation table command, and the
//! dashboard's form in Chromium.

use std::time::Duration;

use bdft_tests::exports::parse_csv;
use bdft_tests::server::{Server, eventually, pilot_copy, short_study};
use bdft_tests::webdriver::Driver;
use bdft_tests::{TempDir, server_command, server_output};
use serde_json::{Value, json};

/// A 10-cell table of tracking error (sd and n) a paper might print.
const TABLE: &str = "controller,station,metric,mean,sd,n
pid,on,mse_tracking_mm2,160,60,8
pid,off,mse_tracking_mm2,110,40,8
pid-notch,on,mse_tracking_mm2,150,55,8
pid-notch,off,mse_tracking_mm2,115,40,8
pid-shaper,on,mse_tracking_mm2,145,50,8
pid-shaper,off,mse_tracking_mm2,120,45,8
lqr,on,mse_tracking_mm2,170,70,8
lqr,off,mse_tracking_mm2,90,30,8
lqr-cabvel,on,mse_tracking_mm2,140,50,8
lqr-cabvel,off,mse_tracking_mm2,95,35,8
";

fn finished(api: &bdft_tests::server::Api) -> Value {
    eventually(Duration::from_secs(600), || {
        let (_, s) = api.get("/api/calibration");
        (s["running"] == false && (s["report"].is_object() || s["error"].is_string())).then_some(s)
    })
}

#[test]
fn a_calibration_is_refused_naming_the_row_or_stored_as_the_next_population_version() {
    let server = Server::start("calibration");
    let api = server.experimenter();
    // 10 s tests keep the simulated trials cheap; the fit runs them in full.
    let study = short_study(&api, 10.0, 1.0);
    let path = format!("/api/studies/{study}/calibrate");
    let bad = [
        (
            "pid,on,mse_tracking_mm2,160\nplain,off,mse_tracking_mm2,110\n",
            "table row 2: controller \"plain\" is not one of",
        ),
        (
            "pid,on,mse_tracking_mm2,160\npid,off,mse_tracking_mm2,-3\n",
            "table row 2: mean -3: must be positive",
        ),
        (
            "pid,on,mse_tracking_mm2,160\npid,off,mse_tracking_mm2,110\n",
            "table: 2 cells give 2 moments, too few for the 4 parameters",
        ),
    ];
    for (rows, said) in bad {
        let table = format!("controller,station,metric,mean\n{rows}");
        let (code, e) = api.post(&path, json!({ "table": table, "simulated_subjects": 8 }));
        assert_eq!(code, 422, "{e}");
        assert!(e["error"].as_str().unwrap().starts_with(said), "{e}");
    }
    // A study without completed tests has nothing of its own to calibrate to.
    let (code, e) = api.post(&path, json!({ "simulated_subjects": 8 }));
    assert_eq!(code, 422, "{e}");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .contains("no cell with completed tests"),
        "{e}"
    );
    let (code, e) = api.post(&path, json!({ "table": TABLE, "simulated_subjects": 4 }));
    assert_eq!(code, 422, "{e}");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .starts_with("simulated_subjects"),
        "{e}"
    );

    // Cancelled: nothing stored.
    api.ok(&path, json!({ "table": TABLE, "simulated_subjects": 512 }));
    eventually(Duration::from_secs(120), || {
        let (_, s) = api.get("/api/calibration");
        (s["done"].as_u64().unwrap_or(0) > 0 || s["running"] == false).then_some(())
    });
    api.ok("/api/calibration/cancel", json!({}));
    let s = finished(&api);
    assert!(s["error"].as_str().unwrap().contains("cancel"), "{s}");
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(st["population_version"], 0, "{st}");

    // Fitted: the study's next population version, audited, with every cell's fit and the
    // metric the table did not carry predicted.
    api.ok(
        &path,
        json!({ "table": TABLE, "simulated_subjects": 8, "seed": 2 }),
    );
    let s = finished(&api);
    let report = &s["report"];
    assert!(report.is_object(), "{s}");
    assert_eq!(report["population_version"], 1, "{s}");
    let fit = &report["fit"];
    assert_eq!(fit["cells"].as_array().unwrap().len(), 10, "{fit}");
    // Cab acceleration in every cell, and the four ratings: nothing observed of a table.
    let predictions = fit["predictions"].as_array().unwrap();
    assert_eq!(predictions.len(), 10 + 40, "{fit}");
    let ratings: Vec<&Value> = predictions
        .iter()
        .filter(|p| p["metric"].as_str().unwrap().starts_with("rating_"))
        .collect();
    assert_eq!(ratings.len(), 40, "{fit}");
    for r in ratings {
        let mean = r["prediction"].as_f64().unwrap();
        assert!(
            (1.0..=7.0).contains(&mean) && r["observed"].is_null(),
            "{r}"
        );
    }
    assert!(
        fit["objective"].as_f64().unwrap() < fit["objective_before"].as_f64().unwrap(),
        "{fit}"
    );
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(st["population_version"], 1, "{st}");
    assert_eq!(
        st["params"]["population"], fit["population"],
        "the study reads its newest population"
    );
    let (_, audit) = api.get("/api/audit?limit=20");
    let row = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["action"] == "population.calibrate")
        .unwrap_or_else(|| panic!("no audit row: {audit}"));
    assert_eq!(row["target"], format!("study:{study}"));
    assert_eq!(row["detail"]["version"], 1, "{row}");
    // The log alone says whether the stored population fits.
    assert_eq!(
        row["detail"]["verdict"], fit["goodness_of_fit"]["verdict"],
        "{row}"
    );
    assert_eq!(row["detail"]["at_bound"], fit["at_bound"], "{row}");
}

/// A calibration to a study's own tests (here a pilot's synthetic subjects in its dry-run
/// copy, who answer the surveys as people do) fits their tracking error and predicts their
/// ratings, each beside the mean the subjects gave: what the exports hold.
#[test]
fn a_calibration_to_a_studys_own_tests_predicts_the_ratings_beside_the_subjects_own() {
    let server = Server::start("calibration-own");
    let api = server.experimenter();
    let study = short_study(&api, 10.0, 1.0);
    let copy = pilot_copy(&api, study, 3);
    api.ok(
        &format!("/api/studies/{copy}/calibrate"),
        json!({ "simulated_subjects": 8, "seed": 3 }),
    );
    let s = finished(&api);
    let fit = &s["report"]["fit"];
    assert!(fit.is_object(), "{s}");
    assert!(
        fit["source"].as_str().unwrap().contains("completed tests"),
        "{fit}"
    );

    // What the subjects rated, per cell and item, from the trials export: the latest
    // attempt of each completed scored test.
    let (code, text) = api.get_text(&format!("/api/studies/{copy}/export/trials"));
    assert_eq!(code, 200, "{text}");
    let rows = parse_csv(&text);
    let col = |name: &str| rows[0].iter().position(|h| h == name).unwrap();
    let given = |controller: &str, station: &str, item: &str| -> Vec<f64> {
        let c = col(&format!("rating_{item}_1to7"));
        rows[1..]
            .iter()
            .filter(|r| {
                r[col("controller")] == controller
                    && r[col("station")] == station
                    && r[col("phase")] != "practice"
                    && r[col("status")] == "complete"
                    && r[col("latest")] == "1"
                    && !r[c].is_empty()
            })
            .map(|r| r[c].parse().unwrap())
            .collect()
    };
    let ratings: Vec<&Value> = fit["predictions"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["metric"].as_str().unwrap().starts_with("rating_"))
        .collect();
    assert_eq!(ratings.len(), 40, "{fit}");
    let mut observed = 0;
    for r in ratings {
        let item = r["metric"].as_str().unwrap().trim_start_matches("rating_");
        let (controller, station) = (
            r["controller"].as_str().unwrap(),
            r["station"].as_str().unwrap(),
        );
        let theirs = given(controller, station, item);
        let mean = r["prediction"].as_f64().unwrap();
        assert!((1.0..=7.0).contains(&mean), "{r}");
        if theirs.is_empty() {
            assert!(r["observed"].is_null(), "{r}");
            continue;
        }
        observed += 1;
        let want = theirs.iter().sum::<f64>() / theirs.len() as f64;
        assert!(
            (r["observed"].as_f64().unwrap() - want).abs() < 1e-9
                && r["observed_n"] == theirs.len(),
            "{r} vs the export's {theirs:?}"
        );
    }
    // The three subjects complete their tests: every cell and item was rated.
    assert_eq!(observed, 40, "{fit}");
}

#[test]
fn the_validation_table_is_one_command() {
    let out = server_command([
        "findings",
        "--subjects",
        "8",
        "--seed",
        "1",
        "--trial-s",
        "10",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.starts_with("8 subjects, seed 1, 10 s tests"), "{text}");
    for controller in ["pid", "pid-notch", "pid-shaper", "lqr", "lqr-cabvel"] {
        for station in ["on", "off"] {
            // A row in the findings and one in the surveys.
            assert_eq!(
                text.matches(&format!("| {controller} | {station} |"))
                    .count(),
                2,
                "{controller} {station}: {text}"
            );
        }
    }
    assert!(
        text.contains("ICC(3,1) of log tracking error: 0."),
        "{text}"
    );
    // The first 8 answer the surveys: every cell's mean ratings, a row each.
    assert!(text.contains("Surveys of the first 8 subjects"), "{text}");
}

/// `bdft-server calibrate --hold-out` on a real study: bad input (a table mixing units, a
/// row held out and fitted, a metric the study does not record, a hold-out item naming no
/// fitted row) refused naming the row or item, by the command and by the API (422); and a
/// small fit with rows held out, each printed with its prediction, 95 % interval and the
/// table's value.
#[test]
fn the_calibrate_command_holds_rows_out_and_refuses_bad_ones_naming_them() {
    let server = Server::start("calibrate-hold-out");
    let api = server.experimenter();
    let study = short_study(&api, 10.0, 1.0);
    let dir = TempDir::new("calibrate-hold-out");
    let db = server.store();
    let study_arg = study.to_string();
    // The command's arguments, with `table` written to the file it reads.
    let calibrate = |table: &str, hold_out: Option<&str>| -> Vec<String> {
        let path = dir.path().join("table.csv");
        std::fs::write(&path, table).unwrap();
        let mut args = vec![
            "calibrate",
            "--db",
            &db,
            "--study",
            &study_arg,
            "--table",
            path.to_str().unwrap(),
            "--subjects",
            "8",
            "--seed",
            "2",
        ];
        if let Some(h) = hold_out {
            args.extend(["--hold-out", h]);
        }
        args.into_iter().map(String::from).collect()
    };
    let head = "controller,station,metric,mean,sd,n,unit,use\n";
    let fit_rows: String = TABLE
        .lines()
        .skip(1)
        .map(|l| format!("{l},mm2,fit\n"))
        .collect();
    let bad: [(String, Option<&str>, &str); 5] = [
        (
            format!(
                "{head}{fit_rows}pid,off,ms_cab_accel,3.02,,,1e5mm2/s4,\npid,on,ms_cab_accel,450000,,,mm2/s4,\n"
            ),
            None,
            "table row 12: ms_cab_accel in mm2/s4, but row 11 gave it in 1e5mm2/s4; a table gives each metric in one unit",
        ),
        (
            format!("{head}{fit_rows}lqr,on,mse_tracking_mm2,150,,,,hold-out\n"),
            None,
            "table row 11: lqr at on (mse_tracking_mm2) is held out here and fitted on row 7; a cell is fitted or held out, not both",
        ),
        (
            format!("{head}{fit_rows}lqr,on,rating_accuracy,5,,,,\n"),
            None,
            "table row 11: metric \"rating_accuracy\" is not one the study records; allowed mse_tracking_mm2 (mm2), ms_cab_accel (mm2/s4)",
        ),
        (
            format!("{head}{fit_rows}"),
            Some("lqr:on:ms_cab_accel"),
            "hold_out item 1 \"lqr:on:ms_cab_accel\": the target has no lqr at on (ms_cab_accel) to hold out",
        ),
        (
            format!("{head}{fit_rows}"),
            Some("lqr:on,pid:on:speed"),
            "hold_out item 2 \"pid:on:speed\": metric \"speed\" is not one the study records",
        ),
    ];
    for (table, hold_out, said) in &bad {
        let out = server_output(calibrate(table, *hold_out));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(said), "{said}: {err}");
        let (code, e) = api.post(
            &format!("/api/studies/{study}/calibrate"),
            json!({ "table": table, "hold_out": hold_out, "simulated_subjects": 8 }),
        );
        assert_eq!(code, 422, "{e}");
        assert!(
            e["error"].as_str().unwrap().starts_with(said),
            "{said}: {e}"
        );
    }
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(st["population_version"], 0, "nothing stored: {st}");

    // Fitted on 8 of the 10 rows; the two held out are predicted beside their targets.
    let out = server_command(calibrate(TABLE, Some("lqr:on, pid:off:mse_tracking_mm2")));
    let err = String::from_utf8_lossy(&out.stderr);
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    let fit = &report["fit"];
    assert_eq!(fit["cells"].as_array().unwrap().len(), 8, "{fit}");
    let held = fit["held_out"].as_array().unwrap();
    let want = [("lqr", "on", 170.0), ("pid", "off", 110.0)];
    assert_eq!(held.len(), want.len(), "{fit}");
    for (c, (controller, station, target)) in held.iter().zip(want) {
        assert_eq!(
            (
                c["controller"].as_str(),
                c["station"].as_str(),
                c["metric"].as_str()
            ),
            (Some(controller), Some(station), Some("mse_tracking_mm2")),
            "{c}"
        );
        assert_eq!(c["target"].as_f64(), Some(target), "{c}");
        let (p, low, high) = (
            c["prediction"].as_f64().unwrap(),
            c["low"].as_f64().unwrap(),
            c["high"].as_f64().unwrap(),
        );
        assert!(low < p && p < high, "{c}");
        assert_eq!(
            c["inside"].as_bool(),
            Some(low <= target && target <= high),
            "{c}"
        );
        let line = format!(
            "held out {controller} {station} mse_tracking_mm2: predicted {p:.4} [{low:.4}, {high:.4}], target {target:.4}: "
        );
        assert!(err.contains(&line), "{line} in {err}");
    }
    // Neither is among the plain predictions; the verdict is printed and in the report.
    assert_eq!(
        fit["predictions"].as_array().unwrap().len(),
        10 + 40,
        "cab acceleration in every cell and the ratings: {fit}"
    );
    let verdict = fit["goodness_of_fit"]["verdict"].as_str().unwrap();
    assert!(err.contains(&format!("verdict: {verdict}")), "{err}");
    assert!(fit["at_bound"].is_array(), "{fit}");
}

/// The dashboard's calibration form: a held-out row the target does not have is refused with
/// the server's words and nothing runs; a good one calibrates on the rest and the result shows
/// the held-out cell predicted beside its target, whether it fell inside its interval, and the
/// fit's verdict — what the report says.
#[test]
fn in_chromium_the_calibration_form_holds_a_row_out_and_shows_it_predicted() {
    let server = Server::start("calibration-form");
    let api = server.experimenter();
    let study = short_study(&api, 10.0, 1.0);
    let downloads = TempDir::new("calibration-form");
    let driver = Driver::start();
    let dash = driver.dashboard_on(downloads.path(), &server.base, study);
    dash.choose("#cal-source", "table");
    dash.type_into("#cal-table", TABLE);
    dash.type_into("#cal-subjects", "8");
    dash.type_into("#cal-seed", "2");
    dash.type_into("#cal-hold-out", "lqr:on:ms_cab_accel");
    dash.click("#cal-start");
    let said = dash.wait_until(
        "const s = document.querySelector('#cal-status'); return !s.hidden && s.classList.contains('err') && s.textContent || null;",
        json!([]),
    );
    assert!(
        said.as_str()
            .unwrap()
            .contains("the target has no lqr at on (ms_cab_accel) to hold out"),
        "{said}"
    );
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(st["population_version"], 0, "nothing stored: {st}");

    dash.type_into("#cal-hold-out", "lqr:on");
    dash.click("#cal-start");
    let s = finished(&api);
    let fit = &s["report"]["fit"];
    let held = &fit["held_out"].as_array().unwrap()[..];
    assert_eq!(held.len(), 1, "{fit}");
    // The held-out rows are the result's second table body, after its heading row.
    let rows = dash.wait_until(
        "const b = document.querySelectorAll('#cal-result table')[1]?.tBodies[1]; \
         return b && b.rows[0].textContent.startsWith('Held out of the fit') \
           ? [...b.rows].slice(1).map((r) => [...r.cells].map((c) => c.textContent)) : null;",
        json!([]),
    );
    let row: Vec<&str> = rows[0]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap())
        .collect();
    assert_eq!(row[0], "lqr on", "{row:?}");
    assert_eq!(row[1], "mse_tracking_mm2");
    assert_eq!(row[2], "170.0", "the table's target beside the prediction");
    let inside = if held[0]["inside"] == true {
        "inside"
    } else {
        "OUTSIDE"
    };
    assert_eq!(row[6], inside, "{row:?} {}", held[0]);
    let verdict = fit["goodness_of_fit"]["verdict"].as_str().unwrap();
    let shown = dash.text("#cal-result");
    assert!(shown.contains(&format!("Verdict: {verdict}.")), "{shown}");
}
