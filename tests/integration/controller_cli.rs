//! `bdft-controller analyze` and `simulate` as other tools call them.

use bdft_tests::{TempDir, controller};
use serde_json::Value;

fn json_of(args: &[&str]) -> Value {
    let out = controller(args);
    assert!(
        out.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON document")
}

fn stderr_of_failure(args: &[&str]) -> String {
    let out = controller(args);
    assert!(!out.status.success(), "{args:?} should have failed");
    assert!(out.stdout.is_empty(), "a failure prints nothing on stdout");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn analyze_reports_every_compensator_with_the_documented_fields() {
    let v = json_of(&["analyze", "--kbf", "0.6", "--json"]);
    assert_eq!(v["kbf"], 0.6);
    let comps = v["compensators"].as_array().unwrap();
    let names: Vec<&str> = comps.iter().map(|c| c["name"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "pid",
            "pid-notch",
            "pid-shaper",
            "lqr",
            "lqr-cabvel",
            "lqr-cabacc",
            // Analysed frozen at their design's mode (r = 1), as their fixed counterparts.
            "pid-notch-adaptive",
            "pid-shaper-adaptive",
            "lqr-cabvel-scheduled"
        ]
    );
    for c in comps {
        assert!(c["stable"].is_boolean());
        assert!(c["max_stable_kbf"].is_number() || c["max_stable_kbf"].is_null());
        for p in c["poles"].as_array().unwrap() {
            assert_eq!(p.as_array().unwrap().len(), 2);
        }
        // Stability at 0.6 and the margin must agree.
        if let Some(m) = c["max_stable_kbf"].as_f64() {
            assert_eq!(c["stable"].as_bool().unwrap(), m > 0.6, "{c}");
        }
    }
    // The verdict the system model predicts: plain PID loses stability through the
    // feedthrough, every compensated design keeps it.
    assert_eq!(comps[0]["stable"], false);
    assert!(comps[1..].iter().all(|c| c["stable"] == true));
    // An unstable loop has a pole in the right half plane, a stable one has none.
    let rhp = |c: &Value| {
        c["poles"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| p[0].as_f64().unwrap() > 0.0)
    };
    assert!(rhp(&comps[0]));
    assert!(!rhp(&comps[3]));
}

#[test]
fn analyze_at_a_small_kbf_finds_plain_pid_stable() {
    // The reference margin of plain PID is 0.347 (continuous loop, python-control).
    let v = json_of(&["analyze", "--kbf", "0.2", "--json"]);
    assert_eq!(v["compensators"][0]["stable"], true);
}

#[test]
fn simulate_writes_the_full_record_and_is_reproducible_across_processes() {
    let dir = TempDir::new("sim");
    let csv = dir.path().join("samples.csv");
    let args = [
        "simulate",
        "--compensator",
        "lqr-cabvel",
        "--signal",
        "steps",
        "--duration",
        "6",
        "--station",
        "on",
        "--kbf",
        "0.78",
        "--seed",
        "17",
        "--json",
    ];
    let mut with_out: Vec<&str> = args.to_vec();
    let csv_str = csv.to_str().unwrap();
    with_out.extend(["--out", csv_str]);
    let a = json_of(&with_out);
    let b = json_of(&args);
    assert_eq!(a, b, "same seed, same result");
    assert_eq!(a["compensator"], "lqr-cabvel");
    assert_eq!(a["signal"], "steps");
    assert_eq!(a["duration_s"], 6.0);
    assert!(a["mse_tracking_mm2"].as_f64().unwrap() > 0.0);
    assert!(a["ms_cab_accel"].as_f64().unwrap() > 0.0);

    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header[0], "t_s");
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 6000, "1 kHz for 6 s");
    // The metrics are the means over the record: recompute them from the CSV.
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (t, y, a_c) = (col("target_mm"), col("cyl_pos_mm"), col("cab_accel_mm_s2"));
    let mse = rows.iter().map(|r| (r[t] - r[y]).powi(2)).sum::<f64>() / rows.len() as f64;
    let msa = rows.iter().map(|r| r[a_c].powi(2)).sum::<f64>() / rows.len() as f64;
    // The record is written at each channel's resolution (0.1 µm, 0.001 mm/s²): its means
    // agree to far better than 1e-4.
    let rel = |x: f64, y: f64| ((x - y) / y).abs();
    assert!(rel(mse, a["mse_tracking_mm2"].as_f64().unwrap()) < 1e-4);
    assert!(rel(msa, a["ms_cab_accel"].as_f64().unwrap()) < 1e-4);
    // Valve commands are always saturated.
    let v = col("valve_cmd");
    assert!(rows.iter().all(|r| r[v].abs() <= 10.0));
    // A different seed gives a different target.
    let c = json_of(&[
        "simulate",
        "--compensator",
        "lqr-cabvel",
        "--signal",
        "steps",
        "--duration",
        "6",
        "--seed",
        "18",
        "--json",
    ]);
    assert_ne!(c["mse_tracking_mm2"], a["mse_tracking_mm2"]);
}

#[test]
fn bench_signals_run_without_operator() {
    for signal in ["swept-sine", "trapezoid"] {
        let v = json_of(&[
            "simulate",
            "--compensator",
            "pid-notch",
            "--signal",
            signal,
            "--duration",
            "5",
            "--json",
        ]);
        assert_eq!(v["station"], "off");
        assert!(v["mse_tracking_mm2"].as_f64().unwrap().is_finite());
    }
}

#[test]
fn bad_arguments_get_clear_errors() {
    let err = stderr_of_failure(&["simulate", "--compensator", "pdi", "--signal", "steps"]);
    assert!(
        err.contains("pid-notch") && err.contains("lqr-cabvel"),
        "lists the valid names: {err}"
    );
    let err = stderr_of_failure(&["analyze", "--kbf", "NaN"]);
    assert!(err.contains("finite"), "{err}");
    let err = stderr_of_failure(&["analyze", "--kbf", "25"]);
    assert!(err.contains("[0, 20]"), "{err}");
    let err = stderr_of_failure(&[
        "simulate",
        "--compensator",
        "pid",
        "--signal",
        "steps",
        "--duration=-3",
    ]);
    assert!(err.contains("(0, 3600]"), "{err}");
    let err = stderr_of_failure(&["simulate", "--compensator", "pid", "--signal", "chirp"]);
    assert!(err.contains("swept-sine"), "{err}");
    let err = stderr_of_failure(&[
        "simulate",
        "--compensator",
        "pid",
        "--signal",
        "trapezoid",
        "--station",
        "on",
    ]);
    assert!(err.contains("station"), "{err}");
    let err = stderr_of_failure(&[
        "simulate",
        "--compensator",
        "pid",
        "--signal",
        "steps",
        "--operator",
        "human",
    ]);
    // The synthetic operator is the only one `simulate` has: no flag pretends otherwise.
    assert!(err.contains("unexpected argument '--operator'"), "{err}");
}

#[test]
fn a_failed_record_write_leaves_no_file() {
    let dir = TempDir::new("nofile");
    let csv = dir.path().join("missing-dir").join("x.csv");
    let err = stderr_of_failure(&[
        "simulate",
        "--compensator",
        "pid",
        "--signal",
        "steps",
        "--duration",
        "2",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(err.contains("creating"), "{err}");
    assert!(!csv.exists());
}

#[test]
fn parameters_round_trip_through_a_file() {
    let dir = TempDir::new("params");
    let out = controller(&["defaults"]);
    assert!(out.status.success());
    let mut params: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(params["plant"]["k_vc"], 22.0);
    assert_eq!(
        params["compensators"].as_array().unwrap().len(),
        bdft_protocol::params::CompensatorKind::ALL.len()
    );
    // Without a body response there is no feedthrough: plain PID is stable at any K_BF.
    params["body"]["k_h"] = 0.0.into();
    let file = dir.path().join("params.json");
    std::fs::write(&file, serde_json::to_vec(&params).unwrap()).unwrap();
    let v = json_of(&["analyze", "--json", "--params", file.to_str().unwrap()]);
    assert_eq!(v["compensators"][0]["stable"], true);
    assert!(v["compensators"][0]["max_stable_kbf"].is_null());

    // A misspelt key and an out-of-range value are named in the error.
    std::fs::write(&file, r#"{"plant": {"kvc": 3}}"#).unwrap();
    let err = stderr_of_failure(&["analyze", "--params", file.to_str().unwrap()]);
    assert!(err.contains("kvc"), "{err}");
    std::fs::write(&file, r#"{"plant": {"v_max": -1}}"#).unwrap();
    let err = stderr_of_failure(&[
        "simulate",
        "--compensator",
        "pid",
        "--signal",
        "steps",
        "--params",
        file.to_str().unwrap(),
    ]);
    assert!(
        err.contains("plant.v_max") && err.contains("[0.001, 1000]"),
        "{err}"
    );
}

#[test]
fn the_interlock_stops_the_bench_pid_on_the_machine_and_spares_stable_loops() {
    // The Ziegler–Nichols PID closed through the feedthrough at the study's K_BF 0.78 is a
    // 4 Hz limit cycle (the analysis: stable only up to 0.35): stopped within seconds, with
    // the RMS it measured above the limit.
    let v = json_of(&[
        "simulate",
        "--compensator",
        "pid",
        "--signal",
        "steps",
        "--station",
        "on",
        "--kbf",
        "0.78",
        "--json",
    ]);
    assert_eq!(v["outcome"], "cab-vibration", "{v}");
    let t = v["stopped_at_s"].as_f64().unwrap();
    assert!((1.0..20.0).contains(&t), "{v}");
    assert!(v["stop_rms_mm_s2"].as_f64().unwrap() > 6000.0, "{v}");
    // The same PID far inside its stable range, and the notch (stable to 1.04) at 0.78, run
    // to the end. (At 0.3, just inside 0.35, the loop is so lightly damped that it trips.)
    for (compensator, kbf) in [("pid", "0.1"), ("pid-notch", "0.78")] {
        let v = json_of(&[
            "simulate",
            "--compensator",
            compensator,
            "--signal",
            "steps",
            "--station",
            "on",
            "--kbf",
            kbf,
            "--duration",
            "20",
            "--json",
        ]);
        assert_eq!(v["outcome"], "complete", "{compensator} at {kbf}: {v}");
        assert!(v.get("stopped_at_s").is_none());
    }
    // A lower limit is the experimenter's to set, and it is checked.
    let err = stderr_of_failure(&[
        "simulate",
        "--compensator",
        "pid",
        "--signal",
        "steps",
        "--max-cab-rms",
        "0",
    ]);
    assert!(err.contains("max_cab_rms_mm_s2"), "{err}");
}

#[test]
fn analyze_shows_the_design_model_beside_the_implemented_loop() {
    let placed = [-175.0, -176.0, -180.0, -190.0, -191.0, -195.0, -196.0];
    let near = |poles: &Value, p: f64| {
        poles
            .as_array()
            .unwrap()
            .iter()
            .map(|q| (q[0].as_f64().unwrap() - p).hypot(q[1].as_f64().unwrap()) / p.abs())
            .fold(f64::INFINITY, f64::min)
    };
    let v = json_of(&["analyze", "--model", "design", "--json"]);
    assert_eq!(v["model"], "design");
    let lqr = &v["compensators"][3];
    assert_eq!(lqr["name"], "lqr");
    for p in placed {
        assert!(near(&lqr["poles"], p) < 1e-6, "placed {p}: {lqr}");
    }
    let cmp = &v["comparison"][3];
    assert_eq!(cmp["design"], *lqr);
    // The implemented loop moves the observer poles, and each move names its cause.
    assert!(
        placed
            .iter()
            .any(|&p| near(&cmp["implemented"]["poles"], p) > 0.01)
    );
    let diffs = cmp["differences"].as_array().unwrap();
    assert!(!diffs.is_empty());
    assert!(
        diffs
            .iter()
            .all(|d| d["cause"].as_str().unwrap().len() > 10)
    );
    // The PID family has one view.
    assert!(
        v["comparison"][0]["differences"]
            .as_array()
            .unwrap()
            .is_empty()
    );
    // The default is the implemented loop, and the text output shows both.
    let v = json_of(&["analyze", "--json"]);
    assert_eq!(v["model"], "implemented");
    assert_eq!(v["compensators"][3], v["comparison"][3]["implemented"]);
    let text = controller(&["analyze", "--model", "design"]);
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("design model") && text.contains("rate filter"),
        "{text}"
    );
    let err = stderr_of_failure(&["analyze", "--model", "textbook"]);
    assert!(err.contains("design, implemented"), "{err}");
}

#[test]
fn robustness_maps_the_margin_and_counts_the_passing_draws() {
    let v = json_of(&[
        "robustness",
        "lqr",
        "pid-notch",
        "--grid",
        "3",
        "--draws",
        "20",
        "--json",
    ]);
    let reports = v.as_array().unwrap();
    assert_eq!(reports.len(), 2);
    let lqr = &reports[0];
    assert_eq!(lqr["design"], "lqr");
    assert_eq!(lqr["kh_scales"].as_array().unwrap().len(), 3);
    let map = lqr["max_stable_kbf"].as_array().unwrap();
    assert_eq!(map.len(), 3);
    assert!(map.iter().all(|row| row.as_array().unwrap().len() == 3));
    // The nominal cell is analyze's margin.
    let a = json_of(&["analyze", "--json"]);
    let want = a["compensators"][3]["max_stable_kbf"].as_f64().unwrap();
    let got = map[1][1].as_f64().unwrap();
    assert!((got - want).abs() < 2e-5, "{got} vs {want}");
    // More K_H, less K_BF.
    assert!(map[2][1].as_f64().unwrap() < got && map[0][1].as_f64().unwrap() > got);
    let rate = lqr["pass_rate"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&rate));
    assert!(reports[1]["pass_rate"].is_number());
    let err = stderr_of_failure(&["robustness", "lqr", "--kh-range", "20,-20"]);
    assert!(err.contains("LO must not exceed HI"), "{err}");
    let err = stderr_of_failure(&["robustness", "lqr:fast"]);
    assert!(err.contains("lqr:kalman"), "{err}");
}
