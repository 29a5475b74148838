//! Identification tests in a study, end to end through the real server (issue 22): bad
//! multisines refused naming the parameter, the test first in each subject's block on the
//! machine, a pilot's synthetic subjects measured and fitted, the exports and the subject's
//! Bode view carrying it, the stability of every design for the subject's own body, and the
//! station's instructions for the test.

use bdft_protocol::identification::BodyFit;
use bdft_tests::TempDir;
use bdft_tests::server::{Api, Server, assigned_station, pilot_copy, trial_rows, with_store};
use bdft_tests::webdriver::{Driver, artifacts_dir};
use serde_json::{Value, json};

/// The default study with short tests and the default identification test.
fn params_with_identification(api: &Api, practice_s: f64) -> Value {
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(6.0);
    params["practice_s"] = json!(practice_s);
    params["step_interval_s"] = json!(0.5);
    params["identification"] = json!({});
    params
}

fn create(api: &Api, params: &Value) -> (u16, Value) {
    api.create_study("identification", params)
}

fn csv(api: &Api, study: i64, kind: &str) -> (Vec<String>, Vec<Vec<String>>) {
    api.get_csv(&format!("/api/studies/{study}/export/{kind}"))
}

#[test]
fn a_bad_identification_test_is_refused_naming_what_is_wrong() {
    let server = Server::start("ident-refused");
    let api = server.experimenter();
    let good = params_with_identification(&api, 0.0);
    for (path, value, named) in [
        ("rms_mm", json!(50.0), "multisine.rms_mm"),
        ("f_max_hz", json!(0.4), "multisine.f_max_hz"),
        ("periods", json!(1), "multisine.periods"),
        ("seed", json!(7), "identification.excitation.seed"),
    ] {
        let mut p = good.clone();
        p["identification"]["excitation"][path] = value;
        let (code, body) = create(&api, &p);
        assert_eq!(code, 422, "{path}: {body}");
        assert!(body.to_string().contains(named), "{path}: {body}");
    }
    // The test must run one of the study's designs, whose loop the gate analyses.
    let mut p = good.clone();
    p["identification"]["controller"] = json!("lqr-cabacc");
    let (code, body) = create(&api, &p);
    assert_eq!(code, 422, "{body}");
    assert!(
        body.to_string().contains("identification.controller"),
        "{body}"
    );
    assert_eq!(create(&api, &good).0, 200);
}

#[test]
fn a_pilot_measures_each_synthetic_subjects_feedthrough_and_the_exports_and_views_carry_it() {
    let server = Server::start("ident-pilot");
    let api = server.experimenter();
    let (code, study) = create(&api, &params_with_identification(&api, 2.0));
    assert_eq!(code, 200, "{study}");
    let copy = pilot_copy(&api, study["id"].as_i64().unwrap(), 3);

    let (_, subjects) = api.get(&format!("/api/studies/{copy}/subjects"));
    let subjects = subjects.as_array().unwrap();
    assert_eq!(subjects.len(), 3);
    let mut truths_inside = 0;
    let (mut compared, mut whole_subjects) = (0, Vec::new());
    for s in subjects {
        let id = s["subject"]["id"].as_i64().unwrap();
        let (_, detail) = api.get(&format!("/api/subjects/{id}"));
        // One identification test, on the machine, first in the block there, complete.
        let trials = trial_rows(&api, id);
        let ident: Vec<&Value> = trials
            .iter()
            .filter(|t| t["phase"] == "identification")
            .collect();
        assert_eq!(ident.len(), 1, "{detail}");
        let t = ident[0];
        assert_eq!(t["station"], "on");
        assert_eq!(t["status"], "complete");
        assert_eq!(t["duration_s"], 70.0);
        for other in trials
            .iter()
            .filter(|u| u["block"] == t["block"] && u["id"] != t["id"])
        {
            assert!(other["queue_order"].as_i64() > t["queue_order"].as_i64());
        }
        // No survey is asked of it.
        let survey = detail["trials"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["trial"]["id"] == t["id"])
            .unwrap();
        assert!(survey["survey"].is_null());

        // The Bode view: every line measured, a fitted body, the population's band.
        let (code, view) = api.get(&format!("/api/subjects/{id}/identification"));
        assert_eq!(code, 200, "{view}");
        let test = &view["tests"][0];
        let points = test["points"].as_array().unwrap();
        assert_eq!(points.len(), 20, "the default multisine's lines");
        for p in points {
            let (lo, m, hi) = (
                p["magnitude_lo"].as_f64().unwrap(),
                p["magnitude"].as_f64().unwrap(),
                p["magnitude_hi"].as_f64().unwrap(),
            );
            assert!(lo <= m && m <= hi, "{p}");
            let c = p["coherence"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&c), "{p}");
        }
        let fit = &test["fit"];
        assert!(fit.is_object(), "{test}");
        // The fitted curve is drawn for a body identified whole, none other.
        let whole = BodyFit::PARAMETERS
            .iter()
            .all(|p| fit[*p]["not_identified"].is_null());
        let curve = if whole { 60 } else { 0 };
        assert_eq!(view["fitted"].as_array().unwrap().len(), curve, "{fit}");
        assert_eq!(view["population"].as_array().unwrap().len(), 60);
        // The body the synthetic subject drew is what the test measured (k_h and the
        // torso are not changed by the grip; the arm is, so it is not compared here).
        let drawn = &detail["subject"]["drawn"];
        for (key, truth) in [("k_h", "body_k_h"), ("torso_f_hz", "torso_f_hz")] {
            let truth = drawn[truth].as_f64().unwrap();
            let e = &fit[key];
            let (Some(lo), Some(hi)) = (e["lo"].as_f64(), e["hi"].as_f64()) else {
                assert!(e["not_identified"].is_string(), "{key}: {e}");
                continue;
            };
            compared += 1;
            assert!(
                truth > 0.7 * lo && truth < 1.3 * hi,
                "{key}: drawn {truth}, fitted {e}"
            );
            if (lo..=hi).contains(&truth) {
                truths_inside += 1;
            }
        }

        // Every design checked for this subject's own body, at the study's K_BF and another;
        // a body not identified whole is no one's: refused naming what was not identified.
        let (code, st) = api.get(&format!("/api/subjects/{id}/stability"));
        if !whole {
            assert_eq!(code, 409, "{st}");
            assert!(st.to_string().contains("not identified"), "{st}");
            continue;
        }
        whole_subjects.push(id);
        assert_eq!(code, 200, "{st}");
        assert_eq!(st["body"]["k_h"], fit["k_h"]["value"]);
        assert_eq!(st["report"]["verdicts"].as_array().unwrap().len(), 5);
        let (code, at) = api.get(&format!("/api/subjects/{id}/stability?k_bf=0.5"));
        assert_eq!((code, &at["report"]["k_bf"]), (200, &json!(0.5)), "{at}");
        let (code, bad) = api.get(&format!("/api/subjects/{id}/stability?k_bf=100"));
        assert_eq!(code, 422, "{bad}");
        assert!(bad.to_string().contains("k_bf"), "{bad}");
        let (code, bad) = api.get(&format!("/api/subjects/{id}/stability?k_bf=fast"));
        assert_eq!(code, 422, "{bad}");
        assert!(bad.to_string().contains("k_bf"), "{bad}");
    }
    // The workbench analyses a subject's own body when asked: another report than the
    // study's, and a subject of another study is refused naming the parameter.
    // Seeded: one of the three bodies is identified whole under the population's prior (the
    // others have a resonance the data weigh less in than the population).
    assert_eq!(whole_subjects.len(), 1, "{whole_subjects:?}");
    let first = whole_subjects[0];
    let (code, own) = api.get(&format!(
        "/api/studies/{copy}/workbench/frequency?subject={first}"
    ));
    assert_eq!(code, 200, "{own}");
    let (_, generic) = api.get(&format!("/api/studies/{copy}/workbench/frequency"));
    assert_ne!(own, generic);
    let original = study["id"].as_i64().unwrap();
    let (code, refused) = api.get(&format!(
        "/api/studies/{original}/workbench/robustness?design=pid&subject={first}"
    ));
    assert_eq!(code, 422, "{refused}");
    assert!(refused.to_string().contains("subject"), "{refused}");
    // 95 % intervals: most truths inside (a miss or two is the intervals' own 5 %, the
    // bound above catches a biased estimate).
    assert!(
        truths_inside + 2 >= compared && compared >= 4,
        "{truths_inside} of {compared} truths inside their intervals"
    );

    // The trials export: the identification test unscored, without a compensator of its own.
    let (h, rows) = csv(&api, copy, "trials");
    let col = |name: &str| h.iter().position(|c| c == name).unwrap();
    let ident: Vec<&Vec<String>> = rows
        .iter()
        .filter(|r| r[col("phase")] == "identification")
        .collect();
    assert_eq!(ident.len(), 3);
    for r in &ident {
        assert_eq!(r[col("controller")], "");
        assert_eq!(r[col("valid")], "0");
    }
    // The identification export: 20 lines per subject; the subjects export's identified
    // body is the API's.
    let (h, rows) = csv(&api, copy, "identification");
    assert_eq!(rows.len(), 60);
    assert!(h.contains(&"coherence".to_string()));
    let (h, rows) = csv(&api, copy, "subjects");
    let k_h = h.iter().position(|c| c == "identified.k_h").unwrap();
    let id = subjects[0]["subject"]["id"].as_i64().unwrap();
    let (_, view) = api.get(&format!("/api/subjects/{id}/identification"));
    let api_k_h = view["tests"][0]["fit"]["k_h"]["value"].as_f64().unwrap();
    let row = rows
        .iter()
        .find(|r| r[1] == subjects[0]["subject"]["code"].as_str().unwrap())
        .unwrap();
    let exported: f64 = row[k_h].parse().unwrap();
    assert!((exported - api_k_h).abs() < 1e-6, "{exported} vs {api_k_h}");
    // Each measurement is in the audit log.
    let (_, audit) = api.get_text("/api/audit/export");
    assert_eq!(audit.matches("identification.file").count(), 3);
}

#[test]
fn the_station_tells_the_subject_the_identification_task_and_shows_no_target() {
    let server = Server::start("ident-station");
    let api = server.experimenter();
    let (code, study) = create(&api, &params_with_identification(&api, 0.0));
    assert_eq!(code, 200, "{study}");
    let study = study["id"].as_i64().unwrap();
    // The first subject starts on the machine: with no practice, the identification test is
    // the first thing they do.
    let enrolled = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let (_, token) = assigned_station(&api, study, subject);
    let st = Api::with_bearer(&server.base, &token);
    st.ok("/api/station/consent", json!({ "decision": "agreed" }));
    let (_, view) = st.get("/api/station/state");
    assert_eq!(view["phase"], "ready", "{view}");
    let test = &view["test"];
    assert_eq!(test["phase"], "identification");
    assert_eq!(test["label"], "Identification");
    assert_eq!(test["duration_s"], 70.0);
    let text = test["instructions"].as_str().unwrap();
    assert!(
        text.contains("you do not steer") && text.contains("70 seconds"),
        "{text}"
    );
    // Blinded as every test: nothing names the design that moves the boom.
    assert!(!view.to_string().contains("\"pid"), "{view}");
}

/// A one-subject pilot of a study with 2 s tests and an identification test: (the dry-run
/// copy's id, its subject as the subjects list gives it).
fn identified_in_a_pilot(api: &Api) -> (i64, Value) {
    let (code, study) = create(api, &params_with_identification(api, 2.0));
    assert_eq!(code, 200, "{study}");
    let copy = pilot_copy(api, study["id"].as_i64().unwrap(), 1);
    let (_, subjects) = api.get(&format!("/api/studies/{copy}/subjects"));
    (copy, subjects[0]["subject"].clone())
}

#[test]
fn in_chromium_a_subjects_schedule_draws_the_identification_as_a_bode_plot() {
    let server = Server::start("ident-browser");
    let base = server.base.clone();
    let api = server.experimenter();
    let (copy, identified) = identified_in_a_pilot(&api);
    let subject = identified["id"].as_i64().unwrap();
    let (_, view) = api.get(&format!("/api/subjects/{subject}/identification"));

    let downloads = TempDir::new("ident-downloads");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.open_schedule(&base, copy, subject);
    // Both panels, a point per excited line with its bounds, the fitted curve and the band.
    let points = dash.wait_until(
        "const m = document.querySelectorAll('.bode-plot[data-panel=magnitude] circle'); \
         return document.querySelectorAll('.bode-plot').length === 2 && m.length ? m.length : null;",
        json!([]),
    );
    assert_eq!(points, json!(20));
    for panel in ["magnitude", "phase"] {
        assert!(dash.exists(&format!(".bode-plot[data-panel={panel}] polyline")));
        assert!(dash.exists(&format!(".bode-plot[data-panel={panel}] polygon")));
    }
    // The fitted parameters, as the API has them.
    let k_h = view["tests"][0]["fit"]["k_h"]["value"].as_f64().unwrap();
    let table = dash.text("table[data-fit=body]");
    assert!(table.contains(&format!("{k_h:.3}")[..4]), "{table}");
    dash.exec(
        "document.querySelector('.identification').scrollIntoView();",
        json!([]),
    );
    dash.screenshot(&artifacts_dir().join("14-identification-bode.png"));
}

/// The LQR weight a trial's stored design runs with.
fn weight_of(trial: &Value, weight: &str) -> f64 {
    let spec: Value = serde_json::from_str(trial["compensator_json"].as_str().unwrap()).unwrap();
    spec["lqr"][weight].as_f64().unwrap()
}

#[test]
fn a_personalized_study_runs_each_subjects_lqr_designs_tuned_to_their_own_body() {
    let server = Server::start("ident-personal");
    let api = server.experimenter();
    let mut params = params_with_identification(&api, 0.0);
    params["identification"]["personalized"] = json!(true);
    // A study with nothing to tune is refused, naming the parameter.
    let mut pid_only = params.clone();
    pid_only["controllers"] = json!(
        params["controllers"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| !c["kind"].as_str().unwrap().starts_with("lqr"))
            .cloned()
            .collect::<Vec<_>>()
    );
    let (code, body) = create(&api, &pid_only);
    assert_eq!(code, 422, "{body}");
    assert!(
        body.to_string().contains("identification.personalized"),
        "{body}"
    );
    let (code, study) = create(&api, &params);
    assert_eq!(code, 200, "{study}");
    let generic_alpha = params["controllers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["kind"] == "lqr")
        .unwrap()["lqr"]["alpha"]
        .as_f64()
        .unwrap();
    let copy = pilot_copy(&api, study["id"].as_i64().unwrap(), 4);

    let required = 1.5 * params["k_bf"].as_f64().unwrap();
    let (_, subjects) = api.get(&format!("/api/studies/{copy}/subjects"));
    let mut tuned = 0;
    for s in subjects.as_array().unwrap() {
        let id = s["subject"]["id"].as_i64().unwrap();
        let trials = trial_rows(&api, id);
        // The identification test runs before every scored test, wherever the subject
        // starts (the queue runs by block, then queue order).
        let order = |t: &Value| (t["block"].as_i64(), t["queue_order"].as_i64());
        let ident = trials
            .iter()
            .find(|t| t["phase"] == "identification")
            .unwrap();
        assert!(
            trials
                .iter()
                .filter(|t| t["phase"] == "test")
                .all(|t| order(t) > order(ident)),
            "{trials:?}"
        );
        let (_, view) = api.get(&format!("/api/subjects/{id}/identification"));
        let designs = view["tests"][0]["designs"].as_array().unwrap();
        // A body with a parameter the test did not identify is tuned to by no design: the
        // subject runs the study's (issue 42).
        let fit = &view["tests"][0]["fit"];
        if ["k_h", "torso_f_hz", "torso_zeta", "arm_f_hz", "arm_zeta"]
            .iter()
            .any(|p| fit[p]["not_identified"].is_string())
        {
            assert!(designs.is_empty(), "{view}");
            continue;
        }
        assert_eq!(designs.len(), 2, "lqr and lqr-cabvel: {view}");
        let (_, own) = api.get(&format!("/api/subjects/{id}/stability"));
        for d in designs {
            let kind = d["controller"].as_str().unwrap();
            let runs: Vec<&Value> = trials
                .iter()
                .filter(|t| t["controller"] == kind && t["phase"] == "test")
                .collect();
            assert_eq!(runs.len(), 2, "one per seat");
            let Some(value) = d["value"].as_f64() else {
                // No design keeps the margin: the study's runs, and the reason is given.
                assert!(d["reason"].as_str().is_some_and(|r| !r.is_empty()), "{d}");
                assert!(runs.iter().all(|t| t["personalized"] == false));
                continue;
            };
            tuned += 1;
            let weight = d["weight"].as_str().unwrap();
            for t in &runs {
                assert_eq!(t["personalized"], true, "{t}");
                assert_eq!(weight_of(t, weight), value);
                assert_eq!(t["status"], "complete", "{t}");
            }
            // The tuned loop keeps the gate's margin for the body it was tuned to.
            assert!(
                d["max_stable_kbf"]
                    .as_f64()
                    .is_none_or(|k| k >= required - 1e-9),
                "{d}"
            );
            // Tuned to the fitted body at its gain's upper bound, so wherever the study's
            // design falls short for the fitted body itself, the subject's is more
            // cautious: a smaller tracking weight, or a larger damping weight.
            let generic = own["report"]["verdicts"]
                .as_array()
                .unwrap()
                .iter()
                .find(|v| v["controller"] == kind)
                .unwrap();
            if generic["max_stable_kbf"]
                .as_f64()
                .is_some_and(|k| k < required)
            {
                match weight {
                    "alpha" => assert!(value < generic_alpha, "{d} vs {generic}"),
                    _ => assert!(value > d["generic"].as_f64().unwrap(), "{d} vs {generic}"),
                }
            }
        }
        // Every other design is the study's.
        assert!(
            trials
                .iter()
                .filter(|t| !t["controller"].as_str().unwrap().starts_with("lqr"))
                .all(|t| t["personalized"] == false)
        );
    }
    assert!(tuned >= 4, "{tuned} of 8 designs tuned");

    // The trials export says which design each test ran.
    let (h, rows) = csv(&api, copy, "trials");
    let col = |name: &str| h.iter().position(|c| c == name).unwrap();
    let personal: Vec<&Vec<String>> = rows
        .iter()
        .filter(|r| r[col("personalized")] == "1")
        .collect();
    assert_eq!(personal.len(), 2 * tuned);
    for r in &personal {
        assert!(r[col("controller")].starts_with("lqr"), "{r:?}");
        assert!(!r[col("design_alpha")].is_empty() && !r[col("design_beta")].is_empty());
    }
    assert!(
        rows.iter()
            .filter(|r| r[col("controller")] == "pid")
            .all(|r| r[col("personalized")] == "0" && r[col("design_alpha")].is_empty())
    );
    let (_, audit) = api.get_text("/api/audit/export");
    assert_eq!(audit.matches("design.personalize").count(), 4);
}

/// A fit as the old code stored one whose torso the data could not pin down: the singular
/// direction's interval [0, f64::MAX], a damping no body has, and the names without reasons.
fn store_unidentified_torso(server: &Server, subject: i64) {
    with_store(server, async |pool| {
        let (json,): (String,) =
            sqlx::query_as("SELECT fit_json FROM identifications WHERE subject_id = $1")
                .bind(subject)
                .fetch_one(pool)
                .await
                .unwrap();
        let mut fit: Value = serde_json::from_str(&json).unwrap();
        fit["torso_f_hz"] = json!({ "value": 4.36e-8, "lo": 0.0, "hi": f64::MAX });
        fit["torso_zeta"] = json!({ "value": 4_955_376.8, "lo": 0.9, "hi": 2.6e13 });
        fit["unidentified"] = json!(["torso_zeta"]);
        sqlx::query("UPDATE identifications SET fit_json = $1 WHERE subject_id = $2")
            .bind(fit.to_string())
            .bind(subject)
            .execute(pool)
            .await
            .unwrap();
    });
}

#[test]
fn an_unidentified_parameter_is_empty_in_the_exports_and_not_identified_on_the_dashboard() {
    let server = Server::start("ident-unidentified");
    let base = server.base.clone();
    let api = server.experimenter();
    let (copy, identified) = identified_in_a_pilot(&api);
    let subject = identified["id"].as_i64().unwrap();
    let code = identified["code"].as_str().unwrap().to_string();
    store_unidentified_torso(&server, subject);

    // The API: no number for either, and why (the unbounded interval named as such).
    let (_, view) = api.get(&format!("/api/subjects/{subject}/identification"));
    let fit = &view["tests"][0]["fit"];
    for key in ["torso_f_hz", "torso_zeta"] {
        let p = &fit[key];
        assert!(
            p["value"].is_null() && p["lo"].is_null() && p["hi"].is_null(),
            "{key}: {p}"
        );
        assert!(p["not_identified"].is_string(), "{key}: {p}");
    }
    assert!(
        fit["torso_f_hz"]["not_identified"]
            .as_str()
            .unwrap()
            .contains("unbounded"),
        "{fit}"
    );
    assert!(fit["k_h"]["value"].is_f64() && fit["k_h"]["not_identified"].is_null());
    // A body with a parameter not identified is no one's: the Bode plot draws no fitted
    // curve, and the stability of the designs for it is refused, saying which and why —
    // never analysed (nor printed) with the absurd values stored.
    assert_eq!(view["fitted"], json!([]), "{view}");
    let (status, st) = api.get(&format!("/api/subjects/{subject}/stability"));
    assert_eq!(status, 409, "{st}");
    let why = st.to_string();
    assert!(
        why.contains("torso_") && why.contains("not identified"),
        "{st}"
    );
    assert!(!why.contains("4.36e-8") && !why.contains("e308"), "{st}");

    // The subjects export: every number a finite number, the unidentified ones empty, and
    // the status saying why.
    let (h, rows) = csv(&api, copy, "subjects");
    let row = rows.iter().find(|r| r[1] == code).unwrap();
    let cell = |name: &str| &row[h.iter().position(|c| c == name).unwrap()];
    for (name, value) in h.iter().zip(row) {
        if name.starts_with("identified.") && !name.ends_with("_status") && !value.is_empty() {
            let x: f64 = value
                .parse()
                .unwrap_or_else(|_| panic!("{name} = {value:?} is no number"));
            assert!(x.is_finite() && x.abs() < 1e300, "{name} = {value}");
        }
    }
    for key in ["torso_f_hz", "torso_zeta"] {
        for suffix in ["", "_lo", "_hi"] {
            assert_eq!(
                cell(&format!("identified.{key}{suffix}")),
                "",
                "{key}{suffix}"
            );
        }
        let status = cell(&format!("identified.{key}_status"));
        assert!(status.starts_with("not identified: "), "{key}: {status}");
    }
    assert!(cell("identified.torso_f_hz_status").contains("unbounded"));
    assert_eq!(cell("identified.k_h_status"), "identified");
    assert!(!cell("identified.k_h").is_empty());
    // The codebook documents the status columns.
    let (_, codebook) = api.get_text(&format!("/api/studies/{copy}/export/codebook"));
    assert!(
        codebook.contains("identified.torso_f_hz_status"),
        "{codebook}"
    );

    // The dashboard's subject view says so instead of a number.
    let downloads = TempDir::new("ident-unidentified-downloads");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.open_schedule(&base, copy, subject);
    // Each parameter's row: the unidentified ones say so and why, with no value or interval.
    let rows = dash.wait_until(
        "const t = document.querySelector('table[data-fit=body]'); \
         return t ? Object.fromEntries([...t.tBodies[0].rows].map((r) => [r.cells[0].textContent, r.textContent])) : null;",
        json!([]),
    );
    for name in ["torso frequency", "torso damping"] {
        let row = rows[name].as_str().unwrap();
        assert!(row.contains("not identified ("), "{name}: {row}");
        assert!(!row.contains('[') && !row.contains("e308"), "{name}: {row}");
    }
    assert!(
        rows["torso frequency"]
            .as_str()
            .unwrap()
            .contains("unbounded")
    );
    let k_h = rows["k_h"].as_str().unwrap();
    assert!(
        !k_h.contains("not identified") && k_h.contains('['),
        "{k_h}"
    );
}
