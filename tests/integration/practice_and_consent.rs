//! A lab's first day, the protocol's side: a practice that must be passed before anything
//! scored runs, and a consent form that says what the locked protocol does and is hashed
//! with it — through the API, the station page and the dashboard in Chromium.

use std::time::Duration;

use bdft_tests::TempDir;
use bdft_tests::server::{
    Api, Server, eventually, person_at_a_station, run_trial, short_study, trial_rows,
};
use bdft_tests::webdriver::Driver;
use serde_json::{Value, json};

/// The latest attempt of the subject's practice.
fn practice(api: &Api, subject: i64) -> Value {
    trial_rows(api, subject)
        .into_iter()
        .filter(|t| t["phase"] == "practice")
        .max_by_key(|t| t["attempt"].as_i64())
        .expect("a practice")
}

#[test]
fn a_practice_never_completed_holds_the_schedule_until_the_experimenter_decides() {
    let server = Server::start("practice-hold");
    let api = server.experimenter();
    let study = short_study(&api, 2.0, 1.0);
    let (subject, station, token) = person_at_a_station(&server, &api, study);
    let station_api = Api::with_bearer(&server.base, &token);

    // Nobody feeds the station: every attempt of the practice stops without counting (its
    // input goes stale, or its display never reports), and the server repeats it by itself
    // until it has failed three times.
    for attempt in 1..=3 {
        let p = practice(&api, subject);
        assert_eq!(p["attempt"], attempt, "{p}");
        let ended = run_trial(&api, subject, p["id"].as_i64().unwrap());
        assert!(
            ["aborted", "incomplete", "invalid"].contains(&ended["status"].as_str().unwrap()),
            "{ended}"
        );
    }
    let failed = practice(&api, subject);
    assert_eq!(failed["attempt"], 3);

    // Held: the station waits, the first scored test is refused with the reason, and the
    // subject's schedule names the practice.
    let (_, state) = station_api.get("/api/station/state");
    assert_eq!(state["phase"], "held", "{state}");
    assert_eq!(state["failed"]["phase"], "practice", "{state}");
    assert_eq!(state["failed"]["attempts"], 3, "{state}");
    let first_test = trial_rows(&api, subject)
        .into_iter()
        .find(|t| t["slot"] == 1)
        .unwrap();
    let (code, body) = api.post(
        &format!("/api/trials/{}/start", first_test["id"]),
        json!({}),
    );
    assert_eq!(code, 409, "{body}");
    assert!(body["error"].as_str().unwrap().contains("held"), "{body}");
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    assert_eq!(detail["next_trial_id"], Value::Null, "{detail}");
    assert_eq!(detail["held"]["trial_id"], failed["id"], "{detail}");

    // What the experimenter and the subject see, in Chromium.
    let downloads = TempDir::new("practice-hold-downloads");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.log_in_to_dashboard(&server.base);
    let hint = eventually(Duration::from_secs(30), || {
        let t = dash.exec(
            "const p = [...document.querySelectorAll('.mon-hint')].map((e) => e.textContent).join(' | '); return p;",
            json!([]),
        );
        let t = t.as_str().unwrap_or_default().to_string();
        t.contains("practice failed").then_some(t)
    });
    assert!(
        hint.contains("3 times") && hint.contains("holds every scored test"),
        "{hint}"
    );
    dash.click(&format!("tr[data-subject-id='{subject}']"));
    let held_line = dash.text(&format!("[data-held='{}']", failed["id"]));
    assert!(held_line.contains("no scored test runs"), "{held_line}");
    let seat = driver.session(downloads.path());
    seat.open_paired_station(&server.base, &token);
    seat.wait_phase("held");

    // The experimenter accepts the practice as incomplete, with a reason: the first scored
    // test is next, on the station too.
    api.ok(
        &format!("/api/trials/{}/incomplete", failed["id"]),
        json!({ "reason": "practised with the experimenter by hand" }),
    );
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    assert_eq!(detail["held"], Value::Null, "{detail}");
    assert_eq!(detail["next_trial_id"], first_test["id"], "{detail}");
    seat.wait_phase("ready");
    let (_, view) = api.get(&format!("/api/stations/{station}/state"));
    assert_eq!(view["phase"], "ready", "{view}");
    assert_eq!(view["test"]["number"], 1, "{view}");
}

/// The subject's study with an identification test (its default multisine: 1 transient and
/// 6 recorded periods of 10 s, from 0.5 to 8 Hz), 20 s tests and a 10 s practice.
fn study_with_identification(api: &Api) -> i64 {
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(20.0);
    params["practice_s"] = json!(10.0);
    params["identification"] = json!({});
    api.ok(
        "/api/studies",
        json!({ "name": "with identification", "params": params, "seed": 3 }),
    )["id"]
        .as_i64()
        .unwrap()
}

#[test]
fn the_consent_form_says_what_the_locked_protocol_does_and_is_hashed_with_it() {
    let server = Server::start("consent-protocol");
    let api = server.experimenter();
    let study = study_with_identification(&api);
    let enrolled = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let (_, token) = bdft_tests::server::assigned_station(&api, study, subject);

    let downloads = TempDir::new("consent-downloads");
    let driver = Driver::start();
    let page = driver.session(downloads.path());
    page.open_paired_station(&server.base, &token);
    page.wait_phase("consent");
    let shown = page.text("#consent-text");
    // Every kind of test with its count and length, the shaking, the exposure budget.
    for part in [
        "practice run of 10 seconds",
        "10 tests of 20 seconds",
        "5 while seated on the machine",
        "one more test, of 70 seconds",
        "shakes the seat",
        "between 0.5 and 8 Hz",
        "A(8) 0.5 m/s²",
        "VDV 9.1 m/s^1.75",
        "about 5 minutes",
    ] {
        assert!(
            shown.contains(part),
            "{part:?} missing from the form: {shown}"
        );
    }

    // The lock kept the text and its hash; the decision records that hash; the package
    // prints it, and the subjects export carries it.
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    let text = st["consent_text"].as_str().expect("the locked text");
    let sha = st["consent_sha256"].as_str().expect("its hash");
    assert_eq!(sha, sha256_hex(text.as_bytes()));
    // The page shows the text with its paragraphs (the same words, whatever the spacing).
    let words = |s: &str| s.split_whitespace().collect::<Vec<_>>().join(" ");
    assert_eq!(words(&shown), words(text));
    page.click("#consent-agree");
    page.wait_phase("ready");
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    assert_eq!(detail["subject"]["consent_sha256"], sha, "{detail}");
    let (_, package) = api.get_text(&format!("/api/studies/{study}/protocol.html"));
    assert!(package.contains(sha), "the package prints the form's hash");
    let (_, csv) = api.get_text(&format!("/api/studies/{study}/export/subjects"));
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = header.iter().position(|c| *c == "consent_sha256").unwrap();
    let row: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(row[col], sha);

    // A form edited to leave the tests out still tells them: the description is appended.
    let (_, mut params) = api.get("/api/defaults");
    params["consent"]["text"] = json!("Please take part.");
    params["identification"] = json!({});
    let other = api.ok(
        "/api/studies",
        json!({ "name": "terse form", "params": params }),
    )["id"]
        .as_i64()
        .unwrap();
    let (_, html) = api.get_text(&format!("/api/studies/{other}/protocol.html"));
    assert!(
        html.contains("Please take part.") && html.contains("shakes the seat"),
        "the package's form: {html}"
    );
}

/// SHA-256 by the coreutils' `sha256sum`: an implementation other than the server's.
fn sha256_hex(bytes: &[u8]) -> String {
    use std::io::Write;
    let mut child = std::process::Command::new("sha256sum")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("sha256sum");
    child.stdin.take().unwrap().write_all(bytes).unwrap();
    let out = child.wait_with_output().unwrap();
    String::from_utf8(out.stdout).unwrap()[..64].to_string()
}
