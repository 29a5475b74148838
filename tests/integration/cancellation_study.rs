//! Model-based cancellation as a study factor, end to end through the real server and
//! controller (issue 38): a bad factor refused naming the field; a pilot whose every
//! compensator on the machine runs uncancelled and with the subject's own model (set from
//! their identification test and checked against it), the cancelled tests' records carrying
//! what was subtracted, the exports and the inferential table carrying the factor; a guard's
//! trip in the export; an identification accepted as incomplete taking its cancelling tests
//! with it, with the reason, before any of them runs; and the dashboard's study form.

use std::collections::BTreeSet;
use std::time::Duration;

use bdft_tests::TempDir;
use bdft_tests::server::{Api, Server, eventually, pilot_copy, trial_rows};
use bdft_tests::webdriver::Driver;
use serde_json::{Value, json};

/// The default study with short tests, an identification test stronger than the default
/// (9 mm, not 6: with the population's prior, a resonance the data weigh less in than the
/// population is not identified, and a seeded 3-subject pilot needs one body identified
/// whole to cancel with) and cancellation with the subject's own model.
fn cancelling_params(api: &Api) -> Value {
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(6.0);
    params["practice_s"] = json!(0.0);
    params["step_interval_s"] = json!(0.5);
    params["identification"] = json!({ "excitation": {
        "f_min_hz": 0.5, "f_max_hz": 8.0, "lines": 20, "period_s": 10.0, "periods": 6,
        "transient_periods": 1, "rms_mm": 9.0
    } });
    params["cancellation"] = json!({ "arms": ["personal"] });
    params
}

fn create(api: &Api, params: &Value) -> (u16, Value) {
    api.create_study("cancellation", params)
}

#[test]
fn a_bad_cancellation_factor_is_refused_naming_the_field_and_nothing_is_stored() {
    let server = Server::start("cancel-refused");
    let api = server.experimenter();
    let good = cancelling_params(&api);
    let mut cases: Vec<(Value, &str)> = Vec::new();
    let mut p = good.clone();
    p["identification"] = Value::Null;
    cases.push((
        p,
        "cancellation: a cancelling arm needs the study's identification",
    ));
    for (factor, named) in [
        (json!({ "arms": [] }), "cancellation.arms"),
        (json!({ "arms": ["off"] }), "cancellation.arms"),
        (
            json!({ "arms": ["personal", "personal"] }),
            "cancellation.arms",
        ),
        (json!({ "arms": ["wrong"] }), "cancellation.wrong"),
        (
            json!({ "arms": ["wrong"], "wrong": { "gain": 2.5 } }),
            "cancellation.wrong.gain",
        ),
        (
            json!({ "arms": ["wrong"], "wrong": { "gain": 1.0, "phase_lag_deg": 120.0 } }),
            "cancellation.wrong.phase_lag_deg",
        ),
        (
            json!({ "arms": ["personal"], "limit_mm": 0.0 }),
            "cancellation.limit_mm",
        ),
    ] {
        let mut p = good.clone();
        p["cancellation"] = factor;
        cases.push((p, named));
    }
    for (p, named) in cases {
        let (code, body) = create(&api, &p);
        assert_eq!(code, 422, "{named}: {body}");
        assert!(body.to_string().contains(named), "{named}: {body}");
    }
    // An arm that does not exist is refused too, never a 500.
    let mut p = good.clone();
    p["cancellation"] = json!({ "arms": ["magic"] });
    let (code, body) = create(&api, &p);
    assert!(code == 400 || code == 422, "{code}: {body}");
    assert!(body.to_string().contains("magic"), "{body}");
    let (_, studies) = api.get("/api/studies");
    assert_eq!(studies.as_array().unwrap().len(), 0, "nothing half-stored");
    assert_eq!(create(&api, &good).0, 200);
}

#[test]
fn a_pilot_runs_each_compensator_on_the_machine_with_and_without_the_subjects_own_cancellation() {
    let server = Server::start("cancel-pilot");
    let api = server.experimenter();
    let (code, study) = create(&api, &cancelling_params(&api));
    assert_eq!(code, 200, "{study}");
    let copy = pilot_copy(&api, study["id"].as_i64().unwrap(), 3);
    let (_, subjects) = api.get(&format!("/api/studies/{copy}/subjects"));
    let subjects = subjects.as_array().unwrap();
    assert_eq!(subjects.len(), 3);
    let mut cancelled_complete = Vec::new();
    let mut uncancelled_complete = Vec::new();
    let mut not_run = Vec::new();
    for s in subjects {
        let id = s["subject"]["id"].as_i64().unwrap();
        let trials = trial_rows(&api, id);
        let scored: Vec<&Value> = trials.iter().filter(|t| t["phase"] == "test").collect();
        let on: Vec<&Value> = scored
            .iter()
            .copied()
            .filter(|t| t["station"] == "on")
            .collect();
        let off: Vec<&Value> = scored
            .iter()
            .copied()
            .filter(|t| t["station"] == "off")
            .collect();
        // Every compensator once per arm on the machine, once uncancelled at the desk.
        let cells: BTreeSet<(String, String)> = on
            .iter()
            .map(|t| (t["controller"].to_string(), t["cancellation"].to_string()))
            .collect();
        assert_eq!(
            (on.len(), cells.len(), off.len()),
            (10, 10, 5),
            "{trials:?}"
        );
        assert!(off.iter().all(|t| t["cancellation"] == "off"));
        // The body the identification fitted is what the personal tests cancel with.
        let (_, view) = api.get(&format!("/api/subjects/{id}/identification"));
        let fit = &view["tests"][0]["fit"];
        for t in &on {
            match (t["cancellation"].as_str().unwrap(), t["status"].as_str()) {
                ("off", Some("complete")) => {
                    assert!(t["cancellation_json"].is_null(), "{t}");
                    uncancelled_complete.push(t["id"].as_i64().unwrap());
                }
                ("personal", Some("complete")) => {
                    let model: Value =
                        serde_json::from_str(t["cancellation_json"].as_str().unwrap()).unwrap();
                    assert_eq!(model["k_h"], fit["k_h"]["value"], "{model} {fit}");
                    assert_eq!(model["torso_f_hz"], fit["torso_f_hz"]["value"]);
                    assert_eq!(model["gain"], 1.0);
                    cancelled_complete.push(t["id"].as_i64().unwrap());
                }
                // A cell the check refused, or a body not identified: filed with why.
                ("personal", Some("incomplete")) => {
                    let why = t["status_reason"].as_str().unwrap();
                    assert!(
                        why.starts_with("not run: no personal cancellation")
                            && why.contains("was not identified ("),
                        "{t}"
                    );
                    not_run.push(why.to_string());
                }
                _ => {}
            }
        }
    }
    // Seeded: of these three subjects, one body is identified whole (each of its five
    // cells cancels) and two are not (a resonance the test could not pin down).
    assert_eq!(
        (cancelled_complete.len(), not_run.len()),
        (5, 10),
        "{cancelled_complete:?}, {not_run:?}"
    );
    // A cancelled test's record carries what was subtracted; an uncancelled one's is zero.
    let subtracted = |trial: i64| -> f64 {
        let (header, rows) =
            api.get_csv(&format!("/api/studies/{copy}/export/samples?trial={trial}"));
        let c = header.iter().position(|h| h == "cancellation_mm").unwrap();
        let values: Vec<f64> = rows.iter().map(|r| r[c].parse().unwrap()).collect();
        assert!(values.len() > 5000, "{trial}: a whole record");
        (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
    };
    assert!(subtracted(cancelled_complete[0]) > 0.05);
    assert_eq!(subtracted(uncancelled_complete[0]), 0.0);
    // The trials export names the arm of every test; the summary keeps the cells apart.
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/trials"));
    let col = |n: &str| header.iter().position(|h| h == n).unwrap();
    let arms: BTreeSet<&str> = rows
        .iter()
        .map(|r| r[col("cancellation")].as_str())
        .collect();
    assert!(
        arms.contains("off")
            && arms.contains("personal")
            && arms.is_subset(&BTreeSet::from(["", "off", "personal"])),
        "{arms:?}"
    );
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/summary"));
    let (c, a, v) = (
        header.iter().position(|h| h == "compensator").unwrap(),
        header.iter().position(|h| h == "cancellation").unwrap(),
        header.iter().position(|h| h == "variable").unwrap(),
    );
    let pid_on: Vec<&str> = rows
        .iter()
        .filter(|r| r[c] == "pid" && r[v] == "mse_tracking_mm2" && r[c + 1] == "on")
        .map(|r| r[a].as_str())
        .collect();
    assert_eq!(pid_on, ["off", "personal"], "{rows:?}");
    // The inferential table compares each compensator with itself cancelled.
    let (code, table) = api.get(&format!("/api/studies/{copy}/stats"));
    assert_eq!(code, 200, "{table}");
    let rows = table.as_array().unwrap();
    let cancellation: Vec<&Value> = rows
        .iter()
        .filter(|r| r["test"] == "wilcoxon_cancellation" && r["metric"] == "mse_tracking_mm2")
        .collect();
    assert!(!cancellation.is_empty(), "{table}");
    for r in &cancellation {
        assert_eq!(r["station"], "on");
        assert_eq!(r["b"], format!("{}+personal", r["a"].as_str().unwrap()));
        assert!(r["p_adjusted"].as_f64().unwrap() >= r["p_value"].as_f64().unwrap());
    }
    // One subject has both arms: no RM-ANOVA of the factor is invented from one (the
    // unit test of the table checks its rows with six).
    assert!(
        !rows
            .iter()
            .any(|r| r["test"] == "rm_anova" && r["a"] == "controller:cancellation:personal"),
        "{table}"
    );
    // Each subject's cells decided in the audit log, with the identification's filing.
    let (_, audit) = api.get_text("/api/audit/export");
    assert_eq!(audit.matches("cancellation.plan").count(), 3);
    // The power planner plans the factor's comparisons from the pilot's spread: with one
    // subject having both arms it says so (409) rather than plan from nothing; a request it
    // cannot answer is refused naming the field.
    let plan_at = |route: &str, extra: Value| {
        let mut body = json!({ "subjects": [12], "metric": "mse_tracking_mm2", "station": "on",
                               "draws": 200, "cancellation": "personal" });
        body.as_object_mut()
            .unwrap()
            .extend(extra.as_object().unwrap().clone());
        api.post(&format!("/api/studies/{copy}/{route}"), body)
    };
    let (code, e) = plan_at("plan", json!({}));
    assert_eq!(code, 409, "{e}");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .contains("cancelled with the personal model"),
        "{e}"
    );
    // (A plan with the population runs as the background job: refused before it starts.)
    for (route, extra, field) in [
        ("plan", json!({ "cancellation": "generic" }), "cancellation"),
        (
            "plan-job",
            json!({ "source": "population", "draws": 10 }),
            "cancellation",
        ),
        ("plan", json!({ "station": "off" }), "station"),
    ] {
        let (code, e) = plan_at(route, extra.clone());
        assert_eq!(code, 422, "{extra}: {e}");
        assert!(
            e["error"].as_str().unwrap().starts_with(field),
            "{extra}: {e}"
        );
    }
}

#[test]
fn an_identification_accepted_as_incomplete_takes_its_cancelling_tests_with_it() {
    let server = Server::start("cancel-accepted");
    let api = server.experimenter();
    let (code, study) = create(&api, &cancelling_params(&api));
    assert_eq!(code, 200, "{study}");
    let study = study["id"].as_i64().unwrap();
    let enrolled = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let trials = trial_rows(&api, subject);
    let ident = trials
        .iter()
        .find(|t| t["phase"] == "identification")
        .unwrap();
    // Before the identification is filed, no cancelling test has a model.
    assert!(
        trials
            .iter()
            .filter(|t| t["cancellation"] == "personal")
            .all(|t| t["cancellation_json"].is_null() && t["status"] == "scheduled")
    );
    api.ok(
        &format!("/api/trials/{}/incomplete", ident["id"]),
        json!({ "reason": "the subject could not hold still" }),
    );
    let trials = trial_rows(&api, subject);
    let personal: Vec<&Value> = trials
        .iter()
        .filter(|t| t["cancellation"] == "personal")
        .collect();
    assert_eq!(personal.len(), 5);
    for t in &personal {
        assert_eq!(t["status"], "incomplete", "{t}");
        let why = t["status_reason"].as_str().unwrap();
        assert!(
            why.starts_with("not run: no personal cancellation") && why.contains("not identified"),
            "{why}"
        );
    }
    // The uncancelled tests still run.
    assert_eq!(
        trials
            .iter()
            .filter(|t| t["phase"] == "test" && t["status"] == "scheduled")
            .count(),
        10
    );
    let (_, audit) = api.get_text("/api/audit/export");
    assert_eq!(audit.matches("cancellation.plan").count(), 1);
}

#[test]
fn a_cancelling_test_whose_guard_trips_goes_on_uncancelled_and_the_export_says_when() {
    let server = Server::start("cancel-guard");
    let api = server.experimenter();
    let mut params = cancelling_params(&api);
    // The smallest bound allowed: every cancelled test's output passes it within a second.
    params["cancellation"]["limit_mm"] = json!(0.1);
    let (code, study) = create(&api, &params);
    assert_eq!(code, 200, "{study}");
    let copy = pilot_copy(&api, study["id"].as_i64().unwrap(), 3);
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/trials"));
    let col = |n: &str| header.iter().position(|h| h == n).unwrap();
    let mut tripped = 0;
    for r in &rows {
        let at = &r[col("cancellation_off_at_s")];
        match (r[col("cancellation")].as_str(), r[col("status")].as_str()) {
            ("personal", "complete") => {
                // Turned off early, and the test ran to its end uncancelled.
                let at: f64 = at.parse().unwrap_or_else(|_| panic!("{r:?}"));
                assert!(at > 0.0 && at < 6.0, "{r:?}");
                assert!(r[col("mse_tracking_mm2")].parse::<f64>().is_ok(), "{r:?}");
                tripped += 1;
            }
            _ => assert!(at.is_empty(), "{r:?}"),
        }
    }
    assert_eq!(tripped, 5, "the identified subject's five cancelled tests");
    let (_, audit) = api.get_text("/api/audit/export");
    assert_eq!(audit.matches("cancellation_off_at_s").count(), 5);
}

#[test]
fn in_chromium_the_study_form_offers_cancellation_and_names_a_bad_wrong_model() {
    let server = Server::start("cancel-form");
    let base = server.base.clone();
    let api = server.experimenter();
    let downloads = TempDir::new("downloads");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.log_in_to_dashboard(&base);
    dash.type_into("#study-name", "Cancelling");
    dash.choose("#p-cancellation", "personal,generic,wrong");
    // A gain outside its range: refused by the server, the field marked, nothing stored.
    dash.type_into("#p-wrong-gain", "2.5");
    dash.click("#study-create");
    let said = dash.wait_until(
        "const s = document.querySelector('#study-status'); return !s.hidden && s.textContent.includes('cancellation.wrong.gain') && s.textContent;",
        json!([]),
    );
    assert!(said.as_str().unwrap().contains("[0.5, 2]"), "{said}");
    assert_eq!(
        dash.exec(
            "return document.querySelector('#p-wrong-gain').classList.contains('invalid');",
            json!([])
        ),
        true
    );
    assert_eq!(api.get("/api/studies").1, json!([]));
    dash.type_into("#p-wrong-gain", "1.3");
    dash.type_into("#p-wrong-lag", "30");
    dash.click("#study-create");
    let study = eventually(Duration::from_secs(20), || {
        api.get("/api/studies").1.as_array()?.first()?["id"].as_i64()
    });
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(
        st["params"]["cancellation"],
        json!({
            "arms": ["personal", "generic", "wrong"],
            "wrong": { "gain": 1.3, "phase_lag_deg": 30.0, "phase_ref_hz": 2.0 },
            "limit_mm": 100.0
        })
    );
    // The factor needs the identification test: the form added it.
    assert!(st["params"]["identification"].is_object(), "{st}");
    // The study shown again: the form says what it cancels with, and the advanced JSON
    // keeps only what the fields do not show.
    dash.goto(&format!("{base}/"));
    dash.find("#estop");
    dash.select_study(study);
    dash.wait_until(
        "return document.querySelector('#p-cancellation').value === 'personal,generic,wrong' && document.querySelector('#p-wrong-lag').value === '30';",
        json!([]),
    );
    let rest: Value = serde_json::from_str(
        dash.exec("return document.querySelector('#p-json').value;", json!([]))
            .as_str()
            .unwrap(),
    )
    .unwrap();
    let left = rest["cancellation"].as_object().unwrap();
    assert_eq!(left.len(), 1, "{rest}");
    assert_eq!(left["limit_mm"].as_f64(), Some(100.0));
}
