//! Machine conditions (issue 41) through the real server and its controller: a study fixed
//! on a condition, its stability gate, its pilot's tests and export; a bench run on a
//! condition checked against the `bdft-controller simulate --condition` process; the
//! workbench's conditions table against `bdft-controller conditions`.

use std::time::Duration;

use bdft_tests::server::{Api, Server, eventually, run_pilot};
use bdft_tests::webdriver::Driver;
use bdft_tests::{TempDir, controller_json};
use serde_json::{Value, json};

fn study_on(api: &Api, condition: &str) -> (u16, Value) {
    let (_, mut params) = api.get("/api/defaults");
    params["condition"] = json!(condition);
    params["trial_s"] = json!(6.0);
    params["practice_s"] = json!(3.0);
    api.create_study(&format!("on {condition}"), &params)
}

#[test]
fn a_study_on_tires_is_gated_run_and_exported_under_its_condition() {
    let server = Server::start("conditions-study");
    let api = server.experimenter();
    // Refused with the condition named, nothing created.
    for (bad, says) in [
        ("stilts+tires", "one ground"),
        ("loaded:2", "validity"),
        ("mud", "unknown part"),
    ] {
        let (status, body) = study_on(&api, bad);
        assert_eq!(status, 422, "{bad}: {body}");
        let msg = body["error"].as_str().unwrap_or_default();
        assert!(
            msg.contains("condition") && msg.contains(says),
            "{bad}: {msg}"
        );
    }
    let (_, studies) = api.get("/api/studies");
    assert_eq!(studies.as_array().map_or(0, Vec::len), 0, "{studies}");

    let (status, created) = study_on(&api, "tires");
    assert_eq!(status, 200, "{created}");
    let study = created["id"].as_i64().unwrap();
    let (_, stored) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(stored["params"]["condition"], "tires", "{stored}");

    // The gate judges the designs made for the thesis's rig on the rig on tires: what the
    // workbench's table says of each design there (the gate's own path on stilts is the
    // sampled loop's; the table's is the design judged on another rig — they agree on
    // stilts, so the gate is not merely the table again).
    let (_, gate) = api.get(&format!("/api/studies/{study}/stability"));
    let (_, table) = api.get(&format!(
        "/api/studies/{study}/workbench/conditions?conditions=stilts,tires"
    ));
    let row = |design: &str, condition: &str| -> Value {
        table["rows"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["design"] == design && r["condition"] == condition)
            .cloned()
            .unwrap_or_else(|| panic!("{design} on {condition}: {table}"))
    };
    let (_, home) = study_on(&api, "stilts");
    let (_, home_gate) = api.get(&format!(
        "/api/studies/{}/stability",
        home["id"].as_i64().unwrap()
    ));
    let close = |a: &Value, b: &Value| match (a.as_f64(), b.as_f64()) {
        (Some(a), Some(b)) => (a - b).abs() < 1e-3,
        _ => a == b,
    };
    let mut moved = 0;
    for (on_tires, on_stilts) in gate["verdicts"]
        .as_array()
        .unwrap()
        .iter()
        .zip(home_gate["verdicts"].as_array().unwrap())
    {
        let design = on_tires["controller"].as_str().unwrap();
        let tires = row(design, "tires");
        let stilts = row(design, "stilts");
        assert!(
            close(&on_tires["max_stable_kbf"], &tires["max_stable_kbf"]),
            "{design}: gate {on_tires} vs table {tires}"
        );
        assert!(
            close(&on_stilts["max_stable_kbf"], &stilts["max_stable_kbf"]),
            "{design}: gate {on_stilts} vs table {stilts}"
        );
        assert_eq!(on_tires["stable_on"], tires["stable"], "{design}");
        if !close(&on_tires["max_stable_kbf"], &on_stilts["max_stable_kbf"]) {
            moved += 1;
        }
        assert!((tires["f1_hz"].as_f64().unwrap() - 3.0).abs() < 1e-9);
    }
    assert!(moved >= 3, "the condition moved few margins: {gate}");
    // The workbench's frequency view is of the machine on tires: its Nyquist margins are
    // the gate's there.
    let (_, freq) = api.get(&format!("/api/studies/{study}/workbench/frequency"));
    assert_eq!(freq["condition"], "tires", "{}", freq["condition"]);
    for v in gate["verdicts"].as_array().unwrap() {
        let design = v["controller"].as_str().unwrap();
        let c = freq["compensators"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["name"] == design)
            .unwrap_or_else(|| panic!("{design} in the frequency view"));
        assert!(
            close(&c["nyquist"]["max_stable_kbf"], &v["max_stable_kbf"]),
            "{design}: Nyquist {} against the gate's {}",
            c["nyquist"]["max_stable_kbf"],
            v["max_stable_kbf"]
        );
    }

    // On tires some design made for the stilts is no longer stable with the body: the
    // pilot is refused until that is acknowledged, as for any unstable design.
    let refused = run_pilot(&api, study, 1);
    assert!(
        refused["error"]
            .as_str()
            .unwrap_or_default()
            .contains("unstable"),
        "{refused}"
    );
    // The pilot's dry-run copy is the study that needs the acknowledgement.
    let copy = refused["study_id"].as_i64().unwrap();
    api.ok(
        &format!("/api/studies/{copy}/acknowledge-instability"),
        json!({ "reason": "the designs made for the stilts, run on tires in simulation" }),
    );
    // A pilot runs every test on tires, and the export says so.
    let status = run_pilot(&api, study, 1);
    assert_eq!(
        status["report"]["study_id"], copy,
        "the pilot did not run: {status}"
    );
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/trials"));
    let col = header.iter().position(|h| h == "condition").unwrap();
    assert!(!rows.is_empty());
    assert!(rows.iter().all(|r| r[col] == "tires"), "{rows:?}");
    let (_, codebook) = api.get_text(&format!("/api/studies/{copy}/export/codebook"));
    assert!(codebook.contains("the machine's condition"), "{codebook}");
}

#[test]
fn a_bench_run_on_a_condition_is_the_simulate_command_on_it() {
    let server = Server::start("conditions-bench");
    let api = server.experimenter();
    let run = api.ok(
        "/api/bench",
        json!({
            "compensators": [{"design": "pid"}, {"design": "pid-notch"}],
            "signal": {"kind": "swept-sine"},
            "duration_s": 10,
            "condition": "tires+loaded"
        }),
    )["run_id"]
        .as_i64()
        .unwrap();
    let v = eventually(Duration::from_secs(300), || {
        let (_, v) = api.get(&format!("/api/bench/runs/{run}"));
        (v["run"]["status"] != "running").then_some(v)
    });
    assert_eq!(v["run"]["status"], "done", "{v}");
    assert_eq!(v["run"]["condition"], "tires+loaded", "{v}");
    for r in v["results"].as_array().unwrap() {
        let design = r["label"].as_str().unwrap();
        let sim = controller_json(&[
            "simulate",
            "--compensator",
            design,
            "--signal",
            "swept-sine",
            "--duration",
            "10",
            "--condition",
            "tires+loaded",
            "--json",
        ]);
        let (got, want) = (
            r["ms_cab_accel"].as_f64().unwrap(),
            sim["ms_cab_accel"].as_f64().unwrap(),
        );
        assert!((got / want - 1.0).abs() < 1e-9, "{design}: {got} vs {want}");
    }
    // A condition the rig cannot take is refused naming it; nothing runs.
    let (status, body) = api.post(
        "/api/bench",
        json!({"compensators": [{"design": "pid"}], "signal": {"kind": "trapezoid"},
               "condition": "tires+outriggers"}),
    );
    assert_eq!(status, 422, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("one ground"),
        "{body}"
    );
    // The table the workbench answers is the CLI's.
    let (_, defaults) = api.get("/api/defaults");
    let study = api.create_study("home", &defaults).1["id"]
        .as_i64()
        .unwrap();
    let (_, table) = api.get(&format!(
        "/api/studies/{study}/workbench/conditions?conditions=outriggers,stick"
    ));
    let want = controller_json(&[
        "conditions",
        "pid-notch",
        "pid-shaper",
        "--conditions",
        "outriggers,stick",
        "--json",
    ]);
    for w in want["rows"].as_array().unwrap() {
        let got = table["rows"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["design"] == w["design"] && r["condition"] == w["condition"])
            .unwrap_or_else(|| panic!("{w} missing from {table}"));
        // The study's designs are tuned for people (slow PID), the CLI's the bench's: the
        // rig is the same, so the first mode agrees; the reductions need not.
        assert_eq!(got["f1_hz"], w["f1_hz"]);
    }
    let (status, body) = api.get(&format!(
        "/api/studies/{study}/workbench/conditions?conditions=stilts%2Bstilts"
    ));
    assert_eq!(status, 422, "{body}");
    assert!(body["error"].as_str().unwrap().contains("twice"), "{body}");
}

/// The dashboard offers the conditions: the study form shows and keeps a study's, and the
/// workbench draws the table the server answers, an unstable row marked.
#[test]
fn in_chromium_the_study_form_and_the_workbench_offer_the_conditions() {
    let server = Server::start("conditions-dashboard");
    let api = server.experimenter();
    let (status, created) = study_on(&api, "tires+loaded");
    assert_eq!(status, 200, "{created}");
    let study = created["id"].as_i64().unwrap();
    let downloads = TempDir::new("conditions-dashboard");
    let driver = Driver::start();
    let dash = driver.dashboard_on(downloads.path(), &server.base, study);
    let shown = dash.wait_until(
        "const v = document.querySelector('#p-condition').value; return v || null;",
        json!([]),
    );
    assert_eq!(shown, "tires+loaded");
    dash.type_into("#wb-conditions", "stilts,tires+loaded");
    dash.click("#wb-conditions-form button[type=submit]");
    let rows = dash.wait_until(
        "const t = document.querySelector('#wb-conditions-table'); \
         return t ? [...t.tBodies[0].rows].map((r) => [r.className, ...[...r.cells].map((c) => c.textContent)]) : null;",
        json!([]),
    );
    let (_, table) = api.get(&format!(
        "/api/studies/{study}/workbench/conditions?conditions=stilts,tires%2Bloaded"
    ));
    let want = table["rows"].as_array().unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), want.len(), "{rows:?}");
    assert_eq!(rows.len(), 10, "five designs on two conditions: {rows:?}");
    for (got, w) in rows.iter().zip(want) {
        assert_eq!(got[2], w["condition"], "{got:?}");
        let stable = w["stable"].as_bool().unwrap();
        assert_eq!(got[0] == "bad", !stable, "{got:?} {w}");
        assert_eq!(got[7], if stable { "yes" } else { "NO" });
        if let Some(m) = w["max_stable_kbf"].as_f64() {
            assert_eq!(got[6], format!("{m:.3}"), "{got:?}");
        }
    }
    assert!(
        rows.iter().any(|r| r[0] == "bad"),
        "on tires with a load some design is unstable: {rows:?}"
    );
}

/// An adaptive design's account of a test — its estimate of the cab mode, its retunes and
/// its fallbacks to the fixed design — is filed with the test's result: in the trials export
/// and in the audit log's `trial.finish`; a fixed design's test has none.
#[test]
fn an_adaptive_designs_estimate_and_fallbacks_are_filed_with_its_test() {
    let server = Server::start("conditions-adaptation");
    let api = server.experimenter();
    let (_, mut params) = api.get("/api/defaults");
    let controllers = params["controllers"].as_array().unwrap().clone();
    let spec = |kind: &str| {
        controllers
            .iter()
            .find(|c| c["kind"] == kind)
            .cloned()
            .unwrap_or_else(|| panic!("{kind} in the defaults"))
    };
    let mut adaptive = spec("pid-shaper");
    adaptive["kind"] = json!("pid-shaper-adaptive");
    adaptive["adapt"] = json!({});
    // An adaptive notch that never trusts its estimate (the strictest confidence allowed):
    // every decision falls back to the fixed design.
    let mut doubting = spec("pid-notch");
    doubting["kind"] = json!("pid-notch-adaptive");
    doubting["adapt"] = json!({ "max_rel_std": 1e-4 });
    params["controllers"] = json!([spec("pid"), adaptive, doubting]);
    // The modes 20 % below the design: the rule moves f₁ from 4.0 Hz to 3.2 Hz.
    params["condition"] = json!("modes:0.8");
    params["trial_s"] = json!(20.0);
    params["practice_s"] = json!(3.0);
    let (status, created) = api.create_study("adaptive on modes 0.8", &params);
    assert_eq!(status, 200, "{created}");
    let study = created["id"].as_i64().unwrap();
    let mut run = run_pilot(&api, study, 1);
    if let Some(copy) = run["study_id"]
        .as_i64()
        .filter(|_| run["error"].is_string())
    {
        // The PID made for the stilts may be unstable with the body on this rig: the
        // acknowledgement any such study needs.
        api.ok(
            &format!("/api/studies/{copy}/acknowledge-instability"),
            json!({ "reason": "fixed designs on a rig with its modes 20 % low, in simulation" }),
        );
        run = run_pilot(&api, study, 1);
    }
    let copy = run["report"]["study_id"]
        .as_i64()
        .unwrap_or_else(|| panic!("the pilot did not run: {run}"));
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/trials"));
    let col = |c: &str| {
        header
            .iter()
            .position(|h| h == c)
            .unwrap_or_else(|| panic!("{c}"))
    };
    let num = |r: &Vec<String>, c: &str| r[col(c)].parse::<f64>().ok();
    let complete = |r: &&Vec<String>| r[col("status")] == "complete" && r[col("phase")] == "test";
    let adaptive: Vec<&Vec<String>> = rows
        .iter()
        .filter(complete)
        .filter(|r| r[col("compensator")] == "pid-shaper-adaptive")
        .collect();
    let fixed: Vec<&Vec<String>> = rows
        .iter()
        .filter(|r| r[col("compensator")] == "pid")
        .collect();
    assert!(!adaptive.is_empty() && !fixed.is_empty(), "{rows:?}");
    for r in &fixed {
        for c in [
            "adapt_f_hz",
            "adapt_ratio",
            "adapt_retunes",
            "adapt_fallbacks",
        ] {
            assert_eq!(r[col(c)], "", "a fixed design's {c}: {r:?}");
        }
    }
    let mut trials = Vec::new();
    for r in &adaptive {
        // Converged on the rig's first mode, and the design running is the one frozen
        // nearest it (the shaper's grid is 1 %).
        let f = num(r, "adapt_f_hz").unwrap_or_else(|| panic!("no estimate: {r:?}"));
        assert!((f - 3.2).abs() < 0.1, "estimated {f} Hz against 3.2: {r:?}");
        let ratio = num(r, "adapt_ratio").unwrap();
        assert!((ratio - 0.8).abs() <= 0.03, "ratio {ratio}: {r:?}");
        assert!(num(r, "adapt_retunes").unwrap() >= 1.0, "{r:?}");
        let since = num(r, "adapt_confident_since_s").unwrap();
        assert!(since > 0.0 && since < 20.0, "{r:?}");
        assert_eq!(r[col("adapt_confident")], "1", "{r:?}");
        // Each decision (once a second) before the estimate was trusted kept the fixed
        // design, and is counted.
        let fallbacks = num(r, "adapt_fallbacks").unwrap();
        assert!(fallbacks >= since.floor(), "{r:?}");
        trials.push((r[col("trial_id")].clone(), fallbacks));
    }
    let doubting: Vec<&Vec<String>> = rows
        .iter()
        .filter(complete)
        .filter(|r| r[col("compensator")] == "pid-notch-adaptive")
        .collect();
    assert!(!doubting.is_empty(), "{rows:?}");
    for r in doubting {
        // Twenty decisions in 20 s, each a fallback; the fixed design ran throughout.
        let fallbacks = num(r, "adapt_fallbacks").unwrap();
        assert!((19.0..=20.0).contains(&fallbacks), "{r:?}");
        assert_eq!(num(r, "adapt_ratio"), Some(1.0), "{r:?}");
        assert_eq!(num(r, "adapt_retunes"), Some(0.0), "{r:?}");
        assert_eq!(r[col("adapt_confident_since_s")], "", "{r:?}");
        assert_eq!(r[col("adapt_confident")], "0", "{r:?}");
        trials.push((r[col("trial_id")].clone(), fallbacks));
    }
    // The audit log's account of each test's end carries the same.
    let (_, audit) = api.get("/api/audit?limit=10000");
    for (trial, fallbacks) in trials {
        let finish = audit
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["action"] == "trial.finish" && a["target"] == format!("trial:{trial}"))
            .unwrap_or_else(|| panic!("no trial.finish for {trial}: {audit}"));
        let details = &finish["detail"];
        assert_eq!(
            details["adaptation"]["fallbacks"].as_f64(),
            Some(fallbacks),
            "{finish}"
        );
    }
}

/// A study that makes the condition a factor: refused with the field named when the levels
/// are not a factor; its gate judges every design on every level (as the studies fixed on
/// each judge it); the subjects take the levels in turn by enrolment, two each, every test
/// of a subject under theirs; the summary has a group per level.
#[test]
fn a_study_compares_conditions_between_its_subjects() {
    let server = Server::start("conditions-factor");
    let api = server.experimenter();
    let (_, defaults) = api.get("/api/defaults");
    let with = |condition: &str, conditions: Value| {
        let mut p = defaults.clone();
        p["condition"] = json!(condition);
        p["conditions"] = conditions;
        p["trial_s"] = json!(6.0);
        p["practice_s"] = json!(3.0);
        p
    };
    for (condition, conditions, says) in [
        ("stilts", json!(["tires"]), "2 to 6"),
        ("stilts", json!(["tires", "tires"]), "listed twice"),
        (
            "tires",
            json!(["stilts", "outriggers"]),
            "one of condition and conditions",
        ),
        ("stilts", json!(["stilts", "loaded:2"]), "loaded:2"),
    ] {
        let (status, body) = api.create_study("bad factor", &with(condition, conditions.clone()));
        assert_eq!(status, 422, "{conditions}: {body}");
        let msg = body["error"].as_str().unwrap_or_default();
        assert!(
            msg.contains("conditions") && msg.contains(says),
            "{conditions}: {msg}"
        );
    }
    let (status, created) = api.create_study(
        "stilts against tires",
        &with("stilts", json!(["stilts", "tires"])),
    );
    assert_eq!(status, 200, "{created}");
    let study = created["id"].as_i64().unwrap();
    assert_eq!(
        api.get(&format!("/api/studies/{study}")).1["params"]["conditions"],
        json!(["stilts", "tires"])
    );

    // The protocol package tells the board the factor and how subjects meet its levels.
    let (status, _, html) = api.get_page(&format!("/api/studies/{study}/protocol.html"));
    assert_eq!(status, 200);
    assert!(
        html.contains("Between subjects, the machine's condition: “stilts”, “tires”")
            && html.contains("two subjects each"),
        "{html}"
    );

    // Each design is as stable as on the least stable level: what the studies fixed on each
    // level say of it.
    let gate_of = |condition: &str| {
        let (_, s) = api.create_study(condition, &with(condition, json!([])));
        api.get(&format!(
            "/api/studies/{}/stability",
            s["id"].as_i64().unwrap()
        ))
        .1
    };
    let (stilts, tires) = (gate_of("stilts"), gate_of("tires"));
    let (_, gate) = api.get(&format!("/api/studies/{study}/stability"));
    let kbf = |v: &Value| v["max_stable_kbf"].as_f64().unwrap_or(f64::INFINITY);
    for (i, v) in gate["verdicts"].as_array().unwrap().iter().enumerate() {
        let (a, b) = (&stilts["verdicts"][i], &tires["verdicts"][i]);
        assert!(
            (kbf(v) - kbf(a).min(kbf(b))).abs() < 1e-9,
            "{v} against {a} and {b}"
        );
        let least = if kbf(b) < kbf(a) { "tires" } else { "stilts" };
        assert_eq!(v["condition"], least, "{v}");
        assert_eq!(
            v["stable_on"].as_bool(),
            Some(a["stable_on"] == true && b["stable_on"] == true),
            "{v}"
        );
    }
    assert!(
        gate["verdicts"]
            .as_array()
            .unwrap()
            .iter()
            .any(|v| v["condition"] == "tires"),
        "{gate}"
    );

    // Some design is unstable on tires: acknowledged, as any such study.
    let refused = run_pilot(&api, study, 4);
    let copy = refused["study_id"]
        .as_i64()
        .unwrap_or_else(|| panic!("{refused}"));
    api.ok(
        &format!("/api/studies/{copy}/acknowledge-instability"),
        json!({ "reason": "the stilts' designs on tires, in simulation" }),
    );
    let status = run_pilot(&api, study, 4);
    assert_eq!(status["report"]["study_id"], copy, "{status}");
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/trials"));
    let col = |c: &str| header.iter().position(|h| h == c).unwrap();
    for (subject, condition) in [
        ("S01", "stilts"),
        ("S02", "stilts"),
        ("S03", "tires"),
        ("S04", "tires"),
    ] {
        let theirs: Vec<&Vec<String>> = rows
            .iter()
            .filter(|r| r[col("subject_code")] == subject)
            .collect();
        assert!(!theirs.is_empty(), "{subject}: {rows:?}");
        assert!(
            theirs.iter().all(|r| r[col("condition")] == condition),
            "{subject} not all on {condition}: {theirs:?}"
        );
    }
    // The statistics compare the levels between subjects: per seat and metric, the
    // Kruskal–Wallis test of two subjects per level (n 4, 1 degree of freedom).
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/stats"));
    let col = |c: &str| header.iter().position(|h| h == c).unwrap();
    let kw: Vec<&Vec<String>> = rows
        .iter()
        .filter(|r| r[col("test")] == "kruskal_condition")
        .collect();
    assert!(!kw.is_empty(), "{rows:?}");
    for r in &kw {
        assert_eq!(r[col("a")], "stilts,tires", "{r:?}");
        assert!(r[col("n")].parse::<u32>().unwrap() <= 4, "{r:?}");
        let h: f64 = r[col("statistic")].parse().unwrap();
        let p: f64 = r[col("p_value")].parse().unwrap();
        // Two groups of two: H ≤ 2.4 (ranks 1,2 against 3,4), and p = P(χ²₁ ≥ H).
        assert!((0.0..=2.4 + 1e-9).contains(&h) && p > 0.1, "{r:?}");
    }
    // The summary: a group per level, each of its own subjects.
    let (header, rows) = api.get_csv(&format!("/api/studies/{copy}/export/summary"));
    let col = |c: &str| header.iter().position(|h| h == c).unwrap();
    for condition in ["stilts", "tires"] {
        let of: Vec<&Vec<String>> = rows
            .iter()
            .filter(|r| r[col("condition")] == condition)
            .collect();
        assert!(!of.is_empty(), "no {condition} group: {rows:?}");
        assert!(
            of.iter().all(|r| r[col("n")].parse::<u32>().unwrap() <= 2),
            "{condition}: {of:?}"
        );
    }
}
