//! The workbench's analysis routes and page: frequency responses, Nyquist verdicts, pole
//! tables and robustness maps of a study's designs — the numbers the same as the
//! controller's CLI prints for the same parameters, bad input refused with the field named,
//! and the dashboard drawing them in Chromium.

use bdft_tests::server::{ADMIN_PASSWORD, Api, Server, short_study};
use bdft_tests::webdriver::{Driver, artifacts_dir};
use bdft_tests::{TempDir, controller_json};
use serde_json::{Value, json};

/// The study's rig, body and designs as a `--params` file of the controller's CLI.
fn params_file(dir: &TempDir, study: &Value) -> String {
    let p = &study["params"];
    let doc = json!({
        "plant": p["plant"], "body": p["body"], "compensators": p["controllers"],
    });
    let path = dir.path().join("params.json");
    std::fs::write(&path, doc.to_string()).unwrap();
    path.to_str().unwrap().to_string()
}

fn close(a: &Value, b: &Value, what: &str) {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!(
                (x - y).abs() <= 1e-9 * x.abs().max(1.0),
                "{what}: {x} vs {y}"
            );
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{what}: lengths");
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                close(p, q, &format!("{what}[{i}]"));
            }
        }
        _ => assert_eq!(a, b, "{what}"),
    }
}

fn error_of(api: &Api, path: &str) -> String {
    let (code, body) = api.get(path);
    assert_eq!(code, 422, "{path}: {body}");
    body.to_string()
}

#[test]
fn a_studys_frequency_and_robustness_reports_match_the_cli_and_refuse_bad_input() {
    let server = Server::start("workbench-analysis");
    let api = server.experimenter();
    let id = short_study(&api, 2.0, 1.0);
    let (_, study) = api.get(&format!("/api/studies/{id}"));
    let dir = TempDir::new("workbench-analysis");
    let file = params_file(&dir, &study);

    let (code, r) = api.get(&format!("/api/studies/{id}/workbench/frequency?kbf=0.78"));
    assert_eq!(code, 200, "{r}");
    let names: Vec<String> = study["params"]["controllers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["kind"].as_str().unwrap().to_string())
        .collect();
    let mut args = vec!["frequency", "--params", &file, "--kbf", "0.78", "--json"];
    for n in &names {
        args.extend(["--compensator", n.as_str()]);
    }
    let cli = controller_json(&args);
    close(&r["freqs_hz"], &cli["freqs_hz"], "grid");
    close(&r["parts"], &cli["parts"], "parts");
    let comps = r["compensators"].as_array().unwrap();
    assert_eq!(comps.len(), names.len());
    for (c, k) in comps.iter().zip(cli["compensators"].as_array().unwrap()) {
        let name = c["name"].as_str().unwrap();
        for key in [
            "closed_loop_on",
            "closed_loop_off",
            "compensator",
            "nyquist",
        ] {
            close(&c[key], &k[key], &format!("{name}.{key}"));
        }
        assert_eq!(c["poles"], k["poles"], "{name}: pole tables");
        // The verdict is Z = P − N, and the pole table's implemented view says the same.
        let n = &c["nyquist"];
        let z = n["open_loop_unstable"].as_i64().unwrap() - n["encirclements"].as_i64().unwrap();
        assert_eq!(n["closed_loop_unstable"], z, "{name}");
        assert_eq!(n["stable"], c["poles"]["implemented"]["stable"], "{name}");
    }

    // Robustness of one design, as the CLI computes it for the same parameters.
    let q = "design=pid-notch&grid=6&draws=40&kh_lo=-40&kh_hi=30&freq_lo=-10&freq_hi=15";
    let (code, rob) = api.get(&format!("/api/studies/{id}/workbench/robustness?{q}"));
    assert_eq!(code, 200, "{rob}");
    let kbf = study["params"]["k_bf"].to_string();
    let cli = controller_json(&[
        "robustness",
        "pid-notch",
        "--params",
        &file,
        "--grid",
        "6",
        "--draws",
        "40",
        "--kh-range",
        "-40,30",
        "--freq-range",
        "-10,15",
        "--kbf",
        &kbf,
        "--json",
    ]);
    close(&rob, &cli[0], "robustness");
    assert_eq!(rob["kh_scales"][0], 0.6);
    assert!(rob["pass_rate"].as_f64().is_some());

    // Bad input: 422 naming the field and what is allowed.
    let base = format!("/api/studies/{id}/workbench");
    let e = error_of(
        &api,
        &format!("{base}/robustness?design=pid&kh_lo=10&kh_hi=-10"),
    );
    assert!(e.contains("kh_range"), "{e}");
    let e = error_of(&api, &format!("{base}/robustness?design=pid&freq_lo=-95"));
    assert!(e.contains("freq_range") && e.contains("-90"), "{e}");
    let e = error_of(&api, &format!("{base}/robustness?design=pid&grid=500"));
    assert!(e.contains("grid") && e.contains("50"), "{e}");
    let e = error_of(&api, &format!("{base}/robustness?design=pid&draws=100000"));
    assert!(e.contains("draws") && e.contains("2000"), "{e}");
    let e = error_of(&api, &format!("{base}/robustness?design=pidd"));
    assert!(e.contains("design") && e.contains("pid-notch"), "{e}");
    let e = error_of(&api, &format!("{base}/robustness?design=pid&kh_lo=abc"));
    assert!(e.contains("kh_lo"), "{e}");
    let e = error_of(&api, &format!("{base}/frequency?kbf=50"));
    assert!(e.contains("kbf") && e.contains("20"), "{e}");
    let e = error_of(&api, &format!("{base}/frequency?kbf=x"));
    assert!(e.contains("kbf"), "{e}");
    let (code, _) = api.get("/api/studies/999/workbench/frequency");
    assert_eq!(code, 404);

    // Read-only: an analyst may use them.
    let admin = server.experimenter();
    let (_, analyst) = server.account(&admin, "ana", "analyst");
    let (code, again) = analyst.get(&format!("{base}/frequency?kbf=0.78"));
    assert_eq!(code, 200);
    assert_eq!(again, r);
    let (code, _) = analyst.get(&format!("{base}/robustness?design=lqr&grid=2&draws=5"));
    assert_eq!(code, 200);
    // In the OpenAPI document.
    let (_, doc) = api.get("/api/openapi.json");
    for p in ["frequency", "robustness"] {
        assert!(
            doc["paths"][format!("/api/studies/{{id}}/workbench/{p}")]["get"].is_object(),
            "{p}"
        );
    }
}

#[test]
fn the_workbench_draws_bode_nyquist_and_the_robustness_map_with_their_verdicts() {
    let server = Server::start("workbench-browser");
    let api = server.experimenter();
    let id = short_study(&api, 2.0, 1.0);
    let downloads = TempDir::new("wb-downloads");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.goto(&format!("{}/", server.base));
    dash.type_into("#login-username", "admin");
    dash.type_into("#login-password", ADMIN_PASSWORD);
    dash.click("#login-submit");
    dash.find("#estop");
    dash.wait_until(
        "return document.querySelectorAll('#wb-robust-design option').length > 0",
        json!([]),
    );
    dash.exec(
        "document.querySelector('#sec-workbench').scrollIntoView()",
        json!([]),
    );
    dash.click("#wb-frequency");
    let (_, report) = api.get(&format!("/api/studies/{id}/workbench/frequency"));
    let comps = report["compensators"].as_array().unwrap();
    // Every plot drawn: parts (3, and the LQR's inner loop), loops (2), compensators and
    // Nyquist curves (one each).
    let inner = comps.iter().any(|c| c["inner_loop"].is_object());
    let plots = 5 + usize::from(inner) + 2 * comps.len();
    let drawn = dash.wait_until(
        "const n = document.querySelectorAll('#wb-analysis canvas[data-drawn]').length; \
         return n >= arguments[0] ? n : null;",
        json!([plots]),
    );
    assert_eq!(drawn, json!(plots));
    // The verdicts are the server's, and the curves are not blank.
    for c in report["compensators"].as_array().unwrap() {
        let name = c["name"].as_str().unwrap();
        let row = dash.text(&format!("#wb-verdicts tr[data-design='{name}']"));
        let want = if c["nyquist"]["stable"] == true {
            "stable"
        } else {
            "unstable"
        };
        assert!(
            row.contains(want) && (want == "unstable" || !row.contains("unstable")),
            "{name}: {row}"
        );
    }
    let inked = "const c = document.querySelector(arguments[0]); const d = c.getContext('2d') \
        .getImageData(0, 0, c.width, c.height).data; let n = 0; \
        for (let i = 0; i < d.length; i += 4) if (d[i] < 200 && d[i + 2] > 120) n++; return n;";
    let blue = dash.exec(inked, json!(["#wb-nyquist canvas"]));
    assert!(
        blue.as_u64().unwrap() > 100,
        "the first Nyquist curve is drawn: {blue}"
    );
    assert!(dash.exists("#wb-poles details[data-design='lqr']"));

    // The robustness map of one design at a small grid.
    dash.exec(
        "const s = document.querySelector('#wb-robust-design'); s.value = 'lqr'; \
         document.querySelector('#wb-grid').value = '8'; document.querySelector('#wb-draws').value = '60';",
        json!([]),
    );
    dash.click("#wb-robust-form button[type=submit]");
    let rate = dash.wait_until(
        "const p = document.querySelector('#wb-pass-rate'); \
         const c = document.querySelector('#wb-robust-result canvas[data-drawn]'); \
         return p && c ? p.textContent : null;",
        json!([]),
    );
    let (_, rob) = api.get(&format!(
        "/api/studies/{id}/workbench/robustness?design=lqr&grid=8&draws=60"
    ));
    let pct = format!("{:.1} %", 100.0 * rob["pass_rate"].as_f64().unwrap());
    assert!(rate.as_str().unwrap().contains(&pct), "{rate} vs {pct}");
    let colored = "const c = document.querySelector('#wb-robust-result canvas'); const d = c \
        .getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0; \
        for (let i = 0; i < d.length; i += 4) if (d[i + 1] > d[i] + 20) n++; return n;";
    let green = dash.exec(colored, json!([]));
    assert!(
        green.as_u64().unwrap() > 1000,
        "the map has stable cells: {green}"
    );
    // A bad range is refused with the field named on the page.
    dash.exec(
        "document.querySelector('#wb-kh-lo').value = '80';",
        json!([]),
    );
    dash.click("#wb-robust-form button[type=submit]");
    dash.wait_until(
        "return (document.querySelector('#wb-robust-status').textContent || '').includes('kh_range');",
        json!([]),
    );
    dash.screenshot(&artifacts_dir().join("workbench-analysis.png"));
}
