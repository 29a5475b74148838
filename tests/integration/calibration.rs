//! Calibration of a study's synthetic population through the real server and command line:
//! bad tables refused with a 422 naming the row, a fit stored as the study's next population
//! version with its audit row, cancel, and the model card's validation table command.

use std::process::Command;
use std::time::Duration;

use bdft_tests::binary;
use bdft_tests::server::{Server, eventually, short_study};
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
    assert_eq!(fit["predictions"].as_array().unwrap().len(), 10, "{fit}");
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
}

#[test]
fn the_validation_table_is_one_command() {
    let out = Command::new(binary("bdft-server"))
        .args([
            "findings",
            "--subjects",
            "8",
            "--seed",
            "1",
            "--trial-s",
            "10",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
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
