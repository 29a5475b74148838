//! The workbench's bench runs and versioned controller configurations, through the real
//! server (and its controller), checked against the `bdft-controller simulate` CLI process.

use std::time::Duration;

use bdft_tests::controller_link::Proc;
use bdft_tests::server::{ADMIN_PASSWORD, Api, Server, dry_run, eventually};
use bdft_tests::webdriver::{Driver, artifacts_dir};
use bdft_tests::{TempDir, controller_json};
use serde_json::{Value, json};

/// Starts a bench run and waits for it to end; returns the stored run.
fn bench(api: &Api, body: Value) -> Value {
    let run = api.ok("/api/bench", body)["run_id"].as_i64().unwrap();
    eventually(Duration::from_secs(300), || {
        let (_, v) = api.get(&format!("/api/bench/runs/{run}"));
        (v["run"]["status"] != "running").then_some(v)
    })
}

/// A study of the published parameters on the real rig.
fn real_rig_study(api: &Api) -> i64 {
    let (_, mut params) = api.get("/api/defaults");
    params["rig"] = json!("real");
    api.ok(
        "/api/studies",
        json!({ "name": "machine", "params": params }),
    )["id"]
        .as_i64()
        .unwrap()
}

/// `bdft-controller simulate … --json` as another tool calls it.
fn simulate(compensator: &str, signal: &str, duration: &str) -> Value {
    controller_json(&[
        "simulate",
        "--compensator",
        compensator,
        "--signal",
        signal,
        "--duration",
        duration,
        "--seed",
        "1",
        "--json",
    ])
}

#[test]
fn a_simulated_bench_run_stores_the_metrics_simulate_computes_and_reductions_against_twins() {
    let server = Server::start("wb-bench");
    let api = server.experimenter();
    let designs = ["pid", "pid-notch", "lqr", "lqr-cabvel"];
    let v = bench(
        &api,
        json!({
            "compensators": designs.iter().map(|d| json!({ "design": d })).collect::<Vec<_>>(),
            "signal": { "kind": "swept-sine" },
            "duration_s": 4.0,
        }),
    );
    assert_eq!(v["run"]["status"], "done", "{}", v["run"]);
    let results = v["results"].as_array().unwrap();
    assert_eq!(results.len(), 4);
    for (r, d) in results.iter().zip(designs) {
        let cli = simulate(d, "swept-sine", "4");
        assert_eq!(r["label"], d);
        assert_eq!(r["ticks"], cli["ticks"], "{d}");
        assert_eq!(r["mse_tracking_mm2"], cli["mse_tracking_mm2"], "{d}");
        assert_eq!(r["ms_cab_accel"], cli["ms_cab_accel"], "{d}");
        assert_eq!(r["outcome"], "complete");
    }
    // Reductions from the stored metrics: 100·(1 − mine/twin's), twin by kind.
    let m = |i: usize, k: &str| results[i][k].as_f64().unwrap();
    for (i, twin) in [(1, 0), (3, 2)] {
        assert_eq!(results[i]["twin"], designs[twin]);
        for (metric, red) in [
            ("mse_tracking_mm2", "tracking_reduction_pct"),
            ("ms_cab_accel", "cab_accel_reduction_pct"),
        ] {
            let want = 100.0 * (1.0 - m(i, metric) / m(twin, metric));
            let got = results[i][red].as_f64().unwrap();
            assert!(
                (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                "{red}: {got} vs {want}"
            );
        }
    }
    for i in [0, 2] {
        assert!(results[i]["twin"].is_null() && results[i]["tracking_reduction_pct"].is_null());
    }
    // The decimated trace: every 10th tick of 4 s, the reference the swept sine's.
    let trace = &v["traces"][1];
    assert_eq!(trace["dt_s"], 0.01);
    assert_eq!(trace["target_mm"].as_array().unwrap().len(), 400);
    assert!(
        trace["target_mm"]
            .as_array()
            .unwrap()
            .iter()
            .all(|x| x.as_f64().unwrap().abs() <= 5.0 + 1e-6)
    );

    // Exported as CSV with the same figures, and audited.
    let run = v["run"]["id"].as_i64().unwrap();
    let (code, text) = api.get_text(&format!("/api/bench/runs/{run}/export"));
    assert_eq!(code, 200);
    let mut lines = text.lines();
    assert!(
        lines
            .next()
            .unwrap()
            .starts_with("run_id,position,label,controller")
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 4 * 400);
    let notch = rows
        .iter()
        .find(|l| l.split(',').nth(2) == Some("pid-notch"))
        .unwrap();
    assert_eq!(
        notch.split(',').nth(6).unwrap().parse::<f64>().unwrap(),
        m(1, "mse_tracking_mm2")
    );
    let (_, audit) = api.get("/api/audit?limit=200");
    let actions: Vec<&str> = audit["entries"]
        .as_array()
        .or(audit.as_array())
        .unwrap()
        .iter()
        .filter_map(|e| e["action"].as_str())
        .collect();
    for a in ["bench.start", "bench.result", "bench.finish"] {
        assert!(actions.contains(&a), "audit has {a}: {actions:?}");
    }
}

#[test]
fn an_uploaded_reference_runs_and_bad_uploads_name_the_line() {
    let server = Server::start("wb-csv");
    let api = server.experimenter();
    let post = |csv: &str| {
        api.post(
            "/api/bench",
            json!({ "compensators": [{ "design": "pid" }],
                    "signal": { "kind": "csv", "sample_rate_hz": 100.0, "csv": csv } }),
        )
    };
    for (csv, line, problem) in [
        ("mm\n0\n1\nfoo\n", "line 4", "not a number"),
        ("0\n1,2\n", "line 2", "one column"),
        ("0\n5000\n", "line 2", "outside"),
        ("mm\n", "signal.csv", "at least 2"),
    ] {
        let (code, body) = post(csv);
        assert_eq!(code, 422, "{csv:?}: {body}");
        let msg = body["error"].as_str().unwrap();
        assert!(
            msg.contains(line) && msg.contains(problem),
            "{csv:?}: {msg}"
        );
    }
    // Larger than the largest upload: refused from its announced length, before it is read,
    // not a 500.
    assert_eq!(api.status_of_announced_post("/api/bench", 4_800_000), 413);
    // A good one: a 2 s ramp to 10 mm and back; its reference is the upload, interpolated.
    let csv: String = (0..=200)
        .map(|i| format!("{}\n", 10.0 - (f64::from(i) - 100.0).abs() / 10.0))
        .collect();
    let v = bench(
        &api,
        json!({ "compensators": [{ "design": "pid" }],
                "signal": { "kind": "csv", "sample_rate_hz": 100.0, "csv": csv } }),
    );
    assert_eq!(v["run"]["status"], "done", "{}", v["run"]);
    assert_eq!(v["run"]["duration_s"], 2.0);
    // Simulated here: no site's machine ran it.
    assert!(v["run"]["site"].is_null(), "{}", v["run"]);
    let target = v["traces"][0]["target_mm"].as_array().unwrap();
    // Within one tick (10 mm/s × 1 ms) of the upload's peak and of its half-way point.
    assert!(
        (target[100].as_f64().unwrap() - 10.0).abs() <= 0.011,
        "{}",
        target[100]
    );
    assert!(
        (target[50].as_f64().unwrap() - 5.0).abs() <= 0.011,
        "{}",
        target[50]
    );
}

#[test]
fn bench_requests_are_validated_and_a_real_rig_without_a_rig_is_refused() {
    let server = Server::start("wb-refuse");
    let api = server.experimenter();
    let (code, body) = api.post(
        "/api/bench",
        json!({ "compensators": [{ "design": "pid-wobble" }], "signal": { "kind": "trapezoid" } }),
    );
    assert_eq!(code, 422);
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("compensators[0].design"),
        "{body}"
    );
    let (code, body) = api.post(
        "/api/bench",
        json!({ "compensators": [{ "design": "pid" }], "signal": { "kind": "trapezoid" }, "duration_s": 1e6 }),
    );
    assert_eq!(code, 422);
    assert!(
        body["error"].as_str().unwrap().contains("duration_s"),
        "{body}"
    );
    let (code, _) = api.post(
        "/api/bench",
        json!({ "compensators": [], "signal": { "kind": "trapezoid" } }),
    );
    assert_eq!(code, 422);

    // A study on the real rig, with the server's own simulating controller: refused, named.
    let study = real_rig_study(&api);
    let (code, body) = api.post(
        "/api/bench",
        json!({ "study_id": study, "compensators": [{ "design": "pid" }], "signal": { "kind": "trapezoid" } }),
    );
    assert!(code == 409 || code == 503, "{code} {body}");
    assert!(
        body["error"].as_str().unwrap().contains("rig")
            || body["error"].as_str().unwrap().contains("controller"),
        "{body}"
    );
    assert_eq!(
        api.get("/api/bench/runs").1,
        json!([]),
        "nothing was stored"
    );
}

#[test]
fn a_bench_run_on_the_real_rig_runs_in_real_time_stops_at_the_estop_and_a_silent_rig_faults_cleanly()
 {
    let mut rig = Proc::rig_sim();
    let rig_arg = format!("--controller-arg={}", rig.addr);
    let server = Server::start_with(
        "wb-real",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--controller-arg=--rig",
            "--controller-arg=udp",
            "--controller-arg=--rig-addr",
            &rig_arg,
            // A loaded test machine can hold the rig simulator's reply back past the
            // default 50 ms; the silent rig below still faults, after a second.
            "--controller-arg=--rig-timeout-ms",
            "--controller-arg=1000",
        ],
    );
    let api = server.experimenter();
    eventually(Duration::from_secs(30), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["rig"] == "udp").then_some(())
    });
    let study = real_rig_study(&api);
    let run = |api: &Api, duration_s: f64| {
        bench(
            api,
            json!({ "study_id": study, "compensators": [{ "design": "pid" }],
                    "signal": { "kind": "trapezoid" }, "duration_s": duration_s }),
        )
    };
    // Through the controller link as a trial on the rig: every tick of the second, in real
    // time, its result back to the bench (no study trial is made of it).
    let v = run(&api, 1.0);
    assert_eq!(v["run"]["rig"], "real");
    // On the machine of the server's one site, and recorded so.
    assert_eq!(v["run"]["site"], "main", "{}", v["run"]);
    assert_eq!(v["run"]["status"], "done", "{}", v["run"]);
    assert_eq!(
        v["results"][0]["outcome"], "complete",
        "{}",
        v["results"][0]
    );
    assert_eq!(v["results"][0]["ticks"], 1000);
    assert_eq!(v["traces"][0]["target_mm"].as_array().unwrap().len(), 100);
    // The E-stop stops a run on the machine: its trial faults at once (or, pressed before the
    // trial reached the controller, nothing more starts), long before its 60 s.
    let started = api.ok(
        "/api/bench",
        json!({ "study_id": study, "compensators": [{ "design": "pid" }, { "design": "pid-notch" }],
                "signal": { "kind": "trapezoid" }, "duration_s": 60.0 }),
    )["run_id"]
        .as_i64()
        .unwrap();
    eventually(Duration::from_secs(30), || {
        (api.get("/api/bench").1["running"] == true).then_some(())
    });
    let (code, body) = api.post("/api/estop", json!({}));
    assert_eq!(code, 200, "{body}");
    let v = eventually(Duration::from_secs(30), || {
        let (_, v) = api.get(&format!("/api/bench/runs/{started}"));
        (v["run"]["status"] != "running").then_some(v)
    });
    assert_eq!(v["run"]["status"], "failed", "{v}");
    for r in v["results"].as_array().unwrap() {
        assert!(r["outcome"].as_str().unwrap().starts_with("faulted"), "{r}");
        assert!(r["ticks"].as_u64().unwrap() < 60_000, "{r}");
    }
    api.ok("/api/estop/reset", json!({}));

    // The rig goes silent: the run's trial (longer than the rig timeout) faults on the
    // controller and the run says so.
    rig.kill();
    let v = run(&api, 3.0);
    assert_ne!(v["run"]["status"], "running");
    let outcome = v["results"][0]["outcome"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(
        outcome.starts_with("faulted") || v["run"]["status"] == "failed",
        "{}",
        v
    );
}

#[test]
fn configuration_versions_are_immutable_picked_by_a_study_and_recorded_on_its_trials() {
    let server = Server::start("wb-configs");
    let api = server.experimenter();
    let (_, defaults) = api.get("/api/defaults");
    let notch = defaults["controllers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["kind"] == "pid-notch")
        .unwrap()
        .clone();
    let v1 = api.ok(
        "/api/configs",
        json!({ "name": "notch tuned", "spec": notch }),
    );
    assert_eq!(v1["version"], 1);
    let mut edited = notch.clone();
    edited["pid"]["kp"] = json!(edited["pid"]["kp"].as_f64().unwrap() * 0.9);
    let v2 = api.ok(
        "/api/configs",
        json!({ "name": "notch tuned", "spec": edited }),
    );
    assert_eq!(v2["version"], 2);
    assert_eq!(
        api.get(&format!("/api/configs/{}", v1["id"])).1["spec"],
        notch
    );
    // The existing validation, naming the field.
    let mut bad = notch.clone();
    bad["pid"]["kp"] = json!(-1.0);
    let (code, body) = api.post("/api/configs", json!({ "name": "bad", "spec": bad }));
    assert_eq!(code, 422);
    assert!(body["error"].as_str().unwrap().contains("kp"), "{body}");
    assert_eq!(api.get("/api/configs").1.as_array().unwrap().len(), 2);

    // A study picks version 2: its design of that kind is the version's.
    let study = api.ok(
        "/api/studies",
        json!({ "name": "with configs", "params": defaults, "seed": 3 }),
    )["id"]
        .as_i64()
        .unwrap();
    let (code, picked) = api.call(
        "PUT",
        &format!("/api/studies/{study}/configs"),
        Some(json!({ "config_ids": [v2["id"]] })),
    );
    assert_eq!(code, 200, "{picked}");
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert!(
        st["params"]["controllers"]
            .as_array()
            .unwrap()
            .contains(&edited)
    );

    // Its trials record the version they run (only the notch's), exported in the trials CSV;
    // so do those of its dry-run copy (a pilot's).
    let copy = dry_run(&api, study);
    api.ok(
        &format!("/api/studies/{copy}/subjects"),
        json!({ "synthetic": true }),
    );
    api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    for s in [study, copy] {
        let (code, csv) = api.get_text(&format!("/api/studies/{s}/export/trials"));
        assert_eq!(code, 200);
        let mut lines = csv.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let (ci, vi) = (
            header.iter().position(|h| *h == "controller").unwrap(),
            header.iter().position(|h| *h == "config_version").unwrap(),
        );
        let mut notch_rows = 0;
        for l in lines {
            let cells: Vec<&str> = l.split(',').collect();
            if cells[ci] == "pid-notch" {
                notch_rows += 1;
                assert_eq!(cells[vi], "notch tuned v2");
            } else {
                assert_eq!(cells[vi], "", "{l}");
            }
        }
        assert!(notch_rows > 0);
    }

    // Locked now: the versions cannot switch.
    let (code, body) = api.call(
        "PUT",
        &format!("/api/studies/{study}/configs"),
        Some(json!({ "config_ids": [v1["id"]] })),
    );
    assert_eq!(code, 409, "{body}");
    // A bench run of a version names it.
    let v = bench(
        &api,
        json!({ "compensators": [{ "config_id": v2["id"] }, { "design": "pid" }],
                "signal": { "kind": "trapezoid" }, "duration_s": 2.0 }),
    );
    assert_eq!(v["results"][0]["label"], "notch tuned v2");
    assert_eq!(v["results"][0]["config_id"], v2["id"]);
    assert_eq!(v["results"][0]["twin"], "pid");
}

#[test]
fn a_bench_run_from_the_dashboard_shows_its_plots_and_table() {
    let server = Server::start("wb-browser");
    let downloads = TempDir::new("wb-downloads");
    let driver = Driver::start();
    let s = driver.session(downloads.path());
    s.goto(&format!("{}/", server.base));
    s.type_into("#login-username", "admin");
    s.type_into("#login-password", ADMIN_PASSWORD);
    s.click("#login-submit");
    s.find("#wb-bench");
    // A configuration version made on the page from the published notch design.
    s.wait_until(
        "return [...document.querySelectorAll('#config-base option')].some(o => o.textContent.startsWith('pid-notch'));",
        json!([]),
    );
    s.exec(
        "const e = document.querySelector('#config-base'); e.value = [...e.options].find(o => o.textContent.startsWith('pid-notch')).value;",
        json!([]),
    );
    s.click("#config-load");
    s.type_into("#config-name", "pid-notch page");
    s.click("#config-save");
    s.wait_until(
        "return document.querySelectorAll('#config-table tr[data-config-id]').length === 1 && document.querySelectorAll('#bench-configs input').length === 1;",
        json!([]),
    );
    assert!(
        s.text("#config-table").contains("pid-notch page"),
        "{}",
        s.text("#config-table")
    );
    s.click("#bench-configs input");
    for d in ["pid", "pid-notch"] {
        s.click(&format!("#bench-designs input[value='{d}']"));
    }
    s.exec(
        "const e = document.querySelector('#bench-signal'); e.value = 'trapezoid'; e.dispatchEvent(new Event('change', { bubbles: true }));",
        json!([]),
    );
    s.exec(
        "document.querySelector('#bench-duration').value = '3';",
        json!([]),
    );
    s.click("#bench-run");
    s.wait_until(
        "return document.querySelectorAll('#bench-table tbody tr').length === 3;",
        json!([]),
    );
    let table = s.text("#bench-table");
    assert!(
        table.contains("pid-notch") && table.contains("pid-notch page v1") && table.contains("%"),
        "{table}"
    );
    // Two overlaid plots, each with a line per compensator (and the reference in tracking).
    let lines = s.exec(
        "return [...document.querySelectorAll('#bench-plots svg')].map(g => g.querySelectorAll('polyline').length);",
        json!([]),
    );
    assert_eq!(lines, json!([4, 3]));
    s.exec(
        "document.querySelector('#bench-table').scrollIntoView();",
        json!([]),
    );
    s.screenshot(&artifacts_dir().join("wb-bench.png"));
}
