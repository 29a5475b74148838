//! The subject's own page through the real server and controller: the token of the link the
//! experimenter got at enrolment reads the subject's progress, blinded (no compensator name,
//! no metric), and withdraws them, stopping a running test at once; and in Chromium the page
//! shows the progress, takes the token out of the address, and withdraws only after the
//! confirmation.

use std::time::Duration;

use bdft_tests::TempDir;
use bdft_tests::server::{Api, Server, assigned_station, eventually, short_study};
use bdft_tests::webdriver::Driver;
use serde_json::{Value, json};

/// Every word that could name a compensator: the wire names and the dashboard's names.
const COMPENSATOR_WORDS: &[&str] = &["pid", "lqr", "notch", "shaper", "cabvel", "cabacc"];

/// A person enrolled in a new study: (subject id, code, page token).
fn enrolled_person(api: &Api, study: i64) -> (i64, String, String) {
    let e = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    (
        e["subject"]["id"].as_i64().unwrap(),
        e["subject"]["code"].as_str().unwrap().to_string(),
        e["subject_token"].as_str().unwrap().to_string(),
    )
}

fn assert_blinded(text: &str) {
    let lower = text.to_lowercase();
    for w in COMPENSATOR_WORDS {
        assert!(!lower.contains(w), "{w:?} on the subject's page: {text}");
    }
    for w in ["mse", "accel", "metric"] {
        assert!(
            !lower.contains(w),
            "a metric ({w}) on the subject's page: {text}"
        );
    }
}

fn trial_row(api: &Api, subject: i64) -> Value {
    api.get(&format!("/api/subjects/{subject}")).1["trials"][0]["trial"].clone()
}

#[test]
fn the_subject_reads_blinded_progress_and_withdraws_which_stops_their_running_test() {
    let server = Server::start("subject-page-api");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let (subject, code, token) = enrolled_person(&api, study);
    let page = Api::with_bearer(&server.base, &token);

    assert_eq!(Api::anonymous(&server.base).get("/api/subject").0, 401);
    assert_eq!(
        Api::with_bearer(&server.base, "0123abcd")
            .get("/api/subject")
            .0,
        401
    );
    assert_eq!(
        Api::anonymous(&server.base).get_text("/subject").0,
        200,
        "the page exists"
    );
    let (status, own) = page.get("/api/subject");
    assert_eq!(status, 200, "{own}");
    assert_eq!(own["code"], code.as_str());
    assert_eq!(
        (own["tests_complete"].as_u64(), own["tests_total"].as_u64()),
        (Some(0), Some(10))
    );
    assert!(
        own["consent"].is_null() && own["withdrawn"] == false,
        "{own}"
    );
    assert_blinded(&own.to_string());

    // A running test of theirs, at a station.
    let (_, station_token) = assigned_station(&api, study, subject);
    Api::with_bearer(&server.base, &station_token)
        .ok("/api/station/consent", json!({ "decision": "agreed" }));
    eventually(Duration::from_secs(30), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["estop_latched"] == false).then_some(())
    });
    let practice = trial_row(&api, subject)["id"].as_i64().unwrap();
    api.ok(&format!("/api/trials/{practice}/start"), json!({}));
    assert_eq!(trial_row(&api, subject)["status"], "running");
    assert_eq!(page.get("/api/subject").1["consent"], "agreed");

    // Bad bodies are named; nothing is withdrawn by them.
    for body in [
        json!({ "reason": 5 }),
        json!({ "reason": "x".repeat(501) }),
        json!({ "why": "x" }),
    ] {
        let (status, err) = page.post("/api/subject/withdraw", body);
        assert_eq!(status, 422, "{err}");
    }
    assert_eq!(trial_row(&api, subject)["status"], "running");

    // Withdrawn: the test stops at once, filed aborted, and the page says so.
    let (status, after) = page.post("/api/subject/withdraw", json!({}));
    assert_eq!(status, 200, "{after}");
    assert_eq!(after["withdrawn"], true);
    let stopped = eventually(Duration::from_secs(20), || {
        let t = trial_row(&api, subject);
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(stopped["status"], "aborted", "{stopped}");
    assert!(
        stopped["status_reason"]
            .as_str()
            .unwrap()
            .contains("withdrew"),
        "{stopped}"
    );
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    assert!(
        detail["subject"]["withdraw_reason"]
            .as_str()
            .unwrap()
            .contains("no reason given")
    );
    let audit = api.get("/api/audit").1;
    let row = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["action"] == "subject.withdraw")
        .expect("the withdrawal is audited")
        .clone();
    assert_eq!(row["actor"], format!("subject:{code}"), "{row}");
    assert_eq!(row["detail"]["running_trial"], practice, "{row}");
    // Once only, whoever tries again.
    assert_eq!(page.post("/api/subject/withdraw", json!({})).0, 409);
    let (status, _) = api.post(
        &format!("/api/subjects/{subject}/withdraw"),
        json!({ "reason": "again" }),
    );
    assert_eq!(status, 409);
}

#[test]
fn in_chromium_the_page_shows_progress_without_names_and_withdraws_after_confirming() {
    let server = Server::start("subject-page-browser");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let (subject, code, token) = enrolled_person(&api, study);
    let downloads = TempDir::new("subject-page-downloads");
    let driver = Driver::start();
    let page = driver.session(downloads.path());

    page.goto(&format!("{}/subject?token={token}", server.base));
    page.find("#done");
    assert_eq!(page.text("#done"), "0 of 10 tests done");
    assert!(page.text("#code").contains(&code));
    let address = page.exec("return location.href", json!([]));
    assert!(
        !address.as_str().unwrap().contains(&token),
        "the token left the address: {address}"
    );
    assert_blinded(&page.body_text());
    assert!(
        page.body_text().contains("Controller 1"),
        "{}",
        page.body_text()
    );

    let withdrawn =
        || api.get(&format!("/api/subjects/{subject}")).1["subject"]["withdrawn_at"].is_i64();
    // The first click only asks; "No" leaves everything as it was.
    page.click("#withdraw");
    page.find("#withdraw-confirm");
    assert!(!withdrawn(), "one click does not withdraw");
    page.click("#withdraw-no");
    page.wait_until(
        "return document.querySelector('#withdraw-confirm').hidden || null",
        json!([]),
    );
    assert!(!withdrawn());
    // Confirmed, with a reason.
    page.click("#withdraw");
    page.type_into("#withdraw-reason", "too tired today");
    page.click("#withdraw-yes");
    page.find("#withdrawn");
    assert!(
        page.text("#withdrawn")
            .contains("left out of every analysis")
    );
    assert!(withdrawn());
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    assert_eq!(detail["subject"]["withdraw_reason"], "too tired today");
    // A reload of the page (without the token in the address) still knows the subject.
    page.exec("location.reload()", json!([]));
    page.find("#withdrawn");
}
