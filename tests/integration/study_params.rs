//! Study parameters that can run, and texts from parameters: what the server refuses at
//! creation (with the field and the reason), what the station is told, and how the station
//! page shows it in Chromium.

use std::time::Duration;

use bdft_tests::TempDir;
use bdft_tests::server::{Api, Server, assigned_station, eventually};
use bdft_tests::webdriver::Driver;
use serde_json::{Value, json};

/// POSTs a study with `params`; returns (status, error message).
fn create(api: &Api, params: &Value) -> (u16, String) {
    let (code, body) = api.post(
        "/api/studies",
        json!({ "name": "checked", "params": params }),
    );
    (code, body["error"].as_str().unwrap_or_default().to_string())
}

fn defaults(api: &Api) -> Value {
    api.get("/api/defaults").1
}

#[test]
fn a_study_that_cannot_run_is_refused_at_creation_and_edit_naming_the_field() {
    let server = Server::start("params-runnable");
    let api = server.experimenter();

    // A target std of 32 mm within ±40 mm passes the range check but no target fits.
    let mut p = defaults(&api);
    p["target_range_mm"] = json!(40.0);
    p["target_std_mm"] = json!(32.0);
    let (code, err) = create(&api, &p);
    assert_eq!(code, 422, "{err}");
    assert!(err.starts_with("target_std_mm: "), "{err}");

    // An LQR design with no Riccati solution.
    let mut p = defaults(&api);
    let lqr = p["controllers"]
        .as_array_mut()
        .unwrap()
        .iter_mut()
        .find(|c| c["kind"] == "lqr")
        .unwrap();
    lqr["lqr"]["alpha"] = json!(0.001);
    let (code, err) = create(&api, &p);
    assert_eq!(code, 422, "{err}");
    assert!(
        err.starts_with("controllers: the lqr design cannot be built: the Riccati equation has no stabilizing solution"),
        "{err}"
    );

    // A test too short for two steps is the test duration's fault.
    let mut p = defaults(&api);
    p["trial_s"] = json!(3.0);
    let (code, err) = create(&api, &p);
    assert_eq!(code, 422, "{err}");
    assert!(err.starts_with("trial_s: "), "{err}");

    // An unknown placeholder, named with the allowed ones.
    let mut p = defaults(&api);
    p["consent"]["text"] = json!("You do {tests} tests in {hours} hours.");
    let (code, err) = create(&api, &p);
    assert_eq!(code, 422, "{err}");
    assert!(
        err.starts_with("consent.text: unknown placeholder {hours}"),
        "{err}"
    );
    assert!(
        err.contains("{trial_s}") && err.contains("{minutes}"),
        "{err}"
    );

    // The same checks on an edit: nothing is saved.
    let st = api.ok(
        "/api/studies",
        json!({ "name": "ok", "params": defaults(&api) }),
    );
    let id = st["id"].as_i64().unwrap();
    let mut p = defaults(&api);
    p["target_range_mm"] = json!(40.0);
    p["target_std_mm"] = json!(32.0);
    let (code, body) = api.call(
        "PUT",
        &format!("/api/studies/{id}"),
        Some(json!({ "name": "ok", "params": p, "version": st["version"] })),
    );
    assert_eq!(code, 422, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .starts_with("target_std_mm: ")
    );
    let (_, now) = api.get(&format!("/api/studies/{id}"));
    assert_eq!(now["version"], st["version"]);
}

/// A study of 3 compensators × 2 seats with German texts, its tests `trial_s` long; a
/// subject enrolled and assigned to a station serving both seats. Returns (subject, station
/// token).
fn german_study(api: &Api, trial_s: f64, practice_s: f64) -> (i64, String) {
    let mut p = defaults(api);
    p["trial_s"] = json!(trial_s);
    p["practice_s"] = json!(practice_s);
    p["step_interval_s"] = json!(0.5);
    p["controllers"].as_array_mut().unwrap().truncate(3);
    p["texts"]["language"] = json!("de");
    p["texts"]["ready"] = json!("Gleich geht es los: {tests} Tests zu je {trial_s} s.");
    let study = api.ok("/api/studies", json!({ "name": "texts", "params": p }))["id"]
        .as_i64()
        .unwrap();
    let subject = api.ok(&format!("/api/studies/{study}/subjects"), json!({}))["subject"]["id"]
        .as_i64()
        .unwrap();
    let (_, token) = assigned_station(api, study, subject);
    (subject, token)
}

#[test]
fn the_station_gets_its_texts_filled_in_from_the_parameters() {
    let server = Server::start("params-texts");
    let api = server.experimenter();
    let (subject, token) = german_study(&api, 90.0, 120.0);
    let station = Api::with_bearer(&api.base, &token);
    let (_, state) = station.get("/api/station/state");
    assert_eq!(state["phase"], "consent", "{state}");
    let consent = state["consent"]["text"].as_str().unwrap();
    assert!(
        consent.contains("Then 6 tests of 90 seconds each: 3 while seated on the machine"),
        "the consent form follows the study: {consent}"
    );
    assert!(!consent.contains('{'), "{consent}");
    assert_eq!(state["texts"]["language"], "de");
    assert_eq!(
        state["texts"]["ready"],
        "Gleich geht es los: 6 Tests zu je 90 s."
    );
    assert_eq!(state["texts"]["before_test"], "The test lasts 90 seconds.");

    // The practice runs the study's own design of its practice compensator.
    let (_, studies) = api.get("/api/studies");
    let params = &studies.as_array().unwrap().last().unwrap()["params"];
    let own = params["controllers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["kind"] == params["practice_controller"])
        .unwrap()
        .clone();
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let practice = &s["trials"][0]["trial"];
    assert_eq!(practice["phase"], "practice");
    let ran: Value = serde_json::from_str(practice["compensator_json"].as_str().unwrap()).unwrap();
    assert_eq!(ran, own);
}

/// Starts the subject's `index`-th trial and waits for it to end (the page feeds it).
fn run_at_page(api: &Api, subject: i64, index: usize) {
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    let trial = s["trials"][index]["trial"]["id"].as_i64().unwrap();
    // The page must be showing the test (and feeding it) before it starts.
    eventually(Duration::from_secs(60), || {
        let (code, body) = api.post(&format!("/api/trials/{trial}/start"), json!({}));
        (code == 200).then_some(()).or_else(|| {
            assert!(code == 409 || code == 503, "start {trial}: {code} {body}");
            None
        })
    });
    eventually(Duration::from_secs(60), || {
        let (_, s) = api.get(&format!("/api/subjects/{subject}"));
        (s["trials"][index]["trial"]["status"] == "complete").then_some(())
    });
}

#[test]
fn the_station_page_shows_the_texts_confirms_a_decline_fits_and_counts_the_comment() {
    let server = Server::start("params-station-page");
    let api = server.experimenter();
    let (subject, token) = german_study(&api, 1.0, 0.5);
    let downloads = TempDir::new("params-station-downloads");
    let driver = Driver::start();
    let page = driver.session(downloads.path());
    page.cmd(
        "POST",
        "/window/rect",
        json!({ "width": 1280, "height": 800 }),
    )
    .expect("window size");
    page.open_paired_station(&api.base, &token);
    page.wait_phase("consent");
    assert_eq!(
        page.exec("return document.documentElement.lang", json!([])),
        "de"
    );
    assert!(page.text("#consent-text").contains("6 tests of 1 seconds"));
    // Declining asks once more; going back leaves the decision open.
    page.click("#consent-decline");
    page.find("#decline-confirm");
    assert!(
        page.visible("#consent-agree").is_none(),
        "the choice gives way to the question"
    );
    page.click("#decline-back");
    page.find("#consent-agree");
    page.click("#consent-agree");
    page.wait_phase("ready");
    // At 1280 × 800 the practice's Ready screen (the longest) fits: "the experimenter will
    // start it" is seen without scrolling.
    page.wait_until(
        "return document.getElementById('ready-note').textContent",
        json!([]),
    );
    let note = page.text("#ready-note");
    assert!(note.contains("6 Tests zu je 1 s"), "{note}");
    let fits = page.exec(
        "const r = document.getElementById('ready-note').getBoundingClientRect(); \
         return [r.bottom, window.innerHeight, window.innerWidth];",
        json!([]),
    );
    let (bottom, height) = (fits[0].as_f64().unwrap(), fits[1].as_f64().unwrap());
    assert!(
        bottom > 0.0 && bottom <= height,
        "the ready note ends at {bottom} of {height}: {fits}"
    );

    // The practice and the first test; then the survey's comment box counts.
    run_at_page(&api, subject, 0);
    run_at_page(&api, subject, 1);
    page.wait_phase("survey");
    assert_eq!(
        page.exec(
            "return document.getElementById('comment').maxLength",
            json!([])
        ),
        json!(2000)
    );
    assert_eq!(page.text("#comment-count"), "0 / 2000");
    page.type_into("#comment", "héllo");
    page.wait_until(
        "return document.getElementById('comment-count').textContent === '5 / 2000'",
        json!([]),
    );
}

#[test]
fn an_unpaired_station_never_polls_its_state() {
    // Waiting to be paired, the page waits on POST /api/station/pairing: it never asks for
    // its state, so it never gets a 401 every second.
    let server = Server::start("params-unpaired");
    let downloads = TempDir::new("params-unpaired-downloads");
    let driver = Driver::start();
    let page = driver.session(downloads.path());
    page.goto(&format!("{}/station", server.base));
    page.wait_phase("unpaired");
    page.wait_until(
        "return performance.getEntriesByType('resource').some((e) => e.name.includes('/api/station/pairing'))",
        json!([]),
    );
    // Polling would have asked three times by now.
    page.wait_until("return performance.now() > 3500", json!([]));
    let polled = page.exec(
        "return performance.getEntriesByType('resource').filter((e) => e.name.includes('/api/station/state')).length",
        json!([]),
    );
    assert_eq!(polled, json!(0), "an unpaired station asked for its state");
}
