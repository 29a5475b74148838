//! Accounts and roles through the real server: an analyst changes nothing (every
//! state-changing route of the OpenAPI document's experimenter group is tried, so a new route
//! is covered without editing this test) but reads everything and may press the E-stop; only
//! an admin manages accounts; the last active admin stays; disabling ends an account's
//! sessions; every audit row names the account that acted, or says what else did; and in
//! Chromium the dashboard asks before withdrawing a subject or disabling an account, and
//! shows an analyst no control they may not use.

use std::time::Duration;

use bdft_tests::TempDir;
use bdft_tests::server::{ADMIN_PASSWORD, Api, Server, eventually, short_study};
use bdft_tests::webdriver::{Driver, Session};
use serde_json::{Value, json};

/// (method, path) of every operation the document says needs the experimenter's session.
fn experimenter_operations(api: &Api) -> Vec<(String, String)> {
    let (code, doc) = api.get("/api/openapi.json");
    assert_eq!(code, 200);
    let mut out = Vec::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            let session = op["security"]
                .as_array()
                .is_some_and(|s| s.iter().any(|r| r.get("session").is_some()));
            if session {
                out.push((method.to_uppercase(), path.clone()));
            }
        }
    }
    assert!(out.len() > 20, "the experimenter group: {out:?}");
    out
}

/// One request of `api`'s session on a connection of its own. Refused requests are answered
/// before their body is read, and a long one can outlast the server's idle limit for the
/// pooled connection of the next: a fresh connection per request keeps this sweep of every
/// route about the answers, not about connection reuse.
fn call_alone(api: &Api, method: &str, path: &str) -> (u16, Value) {
    let agent = ureq::AgentBuilder::new()
        .max_idle_connections(0)
        .timeout(Duration::from_secs(120))
        .build();
    let req = agent
        .request(method, &format!("{}{path}", api.base))
        .set("cookie", &api.cookie_header())
        .set("x-csrf-token", api.csrf.as_deref().unwrap_or(""));
    let res = if method == "GET" {
        req.call()
    } else {
        req.send_json(json!({}))
    };
    let resp = match res {
        Ok(r) | Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("{method} {path}: {e}"),
    };
    let code = resp.status();
    let text = resp.into_string().unwrap_or_default();
    (
        code,
        serde_json::from_str(&text).unwrap_or(Value::String(text)),
    )
}

/// `path` with its parameters filled in: ids with `id`, and a valid export kind.
fn concrete(path: &str, id: i64) -> String {
    path.replace("{id}", &id.to_string())
        .replace("{kind}", "trials")
        .replace("{file}", "mse_tracking_mm2.svg")
}

#[test]
fn an_analyst_changes_nothing_but_reads_everything_and_may_press_the_estop() {
    let server = Server::start("accounts-analyst");
    let admin = server.experimenter();
    let study = short_study(&admin, 2.0, 1.0);
    admin.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let (_, analyst) = server.account(&admin, "ana", "analyst");
    assert_eq!(analyst.get("/api/me").1["role"], "analyst");

    // The E-stop reaches a connected controller.
    eventually(Duration::from_secs(30), || {
        (admin.get("/api/controller").1["connected"] == true).then_some(())
    });
    let ops = experimenter_operations(&admin);
    let mut refused = 0;
    for (method, path) in &ops {
        if path == "/api/logout" {
            continue;
        }
        let (code, body) = call_alone(&analyst, method, &concrete(path, study));
        let admin_only = path.starts_with("/api/accounts") || path.starts_with("/api/backups");
        match method.as_str() {
            _ if admin_only => assert_eq!(code, 403, "{method} {path}: {body}"),
            "GET" => assert!(
                ![401, 403].contains(&code),
                "an analyst reads {path}: {code} {body}"
            ),
            _ if path == "/api/estop" => assert_eq!(code, 200, "E-stop by an analyst: {body}"),
            // The planner changes nothing; an empty body is the analyst's mistake, not a refusal.
            _ if path.ends_with("/plan") || path.ends_with("/plan-job") => {
                assert_eq!(code, 422, "planning by an analyst: {body}")
            }
            _ => {
                assert_eq!(code, 403, "{method} {path}: {body}");
                assert!(
                    body["error"].as_str().unwrap().contains("analyst"),
                    "the refusal names the role: {body}"
                );
                refused += 1;
            }
        }
    }
    assert!(refused >= 15, "state-changing routes tried: {refused}");
    // Nothing changed: the study is as it was, and resetting the E-stop is the admin's.
    assert_eq!(
        admin
            .get(&format!("/api/studies/{study}/subjects"))
            .1
            .as_array()
            .unwrap()
            .len(),
        1
    );
    for path in [
        "/api/studies",
        "/api/audit",
        &format!("/api/studies/{study}/summary"),
    ] {
        let (code, body) = analyst.get(path);
        assert_eq!(code, 200, "{path}: {body}");
    }
    for kind in ["trials", "samples", "summary"] {
        let (code, csv) = analyst.get_text(&format!("/api/studies/{study}/export/{kind}"));
        assert_eq!(code, 200, "{kind}: {csv}");
    }
    admin.ok("/api/estop/reset", json!({}));

    // An experimenter runs studies but does not manage accounts or backups.
    let (_, experimenter) = server.account(&admin, "exp", "experimenter");
    let admins_only = |p: &str| p.starts_with("/api/accounts") || p.starts_with("/api/backups");
    for (method, path) in ops.iter().filter(|(_, p)| admins_only(p)) {
        let (code, body) = call_alone(&experimenter, method, &concrete(path, 1));
        assert_eq!(code, 403, "{method} {path}: {body}");
        assert!(body["error"].as_str().unwrap().contains("admin"), "{body}");
    }
    let (code, body) = experimenter.post(&format!("/api/studies/{study}/subjects"), json!({}));
    assert_eq!(code, 200, "{body}");
}

fn account<'a>(list: &'a Value, username: &str) -> &'a Value {
    list.as_array()
        .unwrap()
        .iter()
        .find(|a| a["username"] == username)
        .unwrap_or_else(|| panic!("{username} in {list}"))
}

#[test]
fn accounts_are_checked_the_last_admin_stays_and_disabling_ends_sessions() {
    let server = Server::start("accounts-admin");
    let admin = server.experimenter();
    let me = admin.get("/api/me").1;
    assert_eq!(me["role"], "admin", "--admin-password makes an admin: {me}");
    let admin_id = me["id"].as_i64().unwrap();

    // The rules of a new account, each named.
    for (body, field) in [
        (
            json!({ "username": "a b", "password": ADMIN_PASSWORD, "role": "analyst" }),
            "username",
        ),
        (
            json!({ "username": "x".repeat(41), "password": ADMIN_PASSWORD, "role": "analyst" }),
            "username",
        ),
        (
            json!({ "username": "carol", "password": "short", "role": "analyst" }),
            "password",
        ),
        (
            json!({ "username": "carol", "password": ADMIN_PASSWORD, "role": "boss" }),
            "role",
        ),
    ] {
        let (code, err) = admin.post("/api/accounts", body);
        assert_eq!(code, 422, "{err}");
        assert!(err["error"].as_str().unwrap().contains(field), "{err}");
    }
    let (code, err) = admin.post(
        &format!("/api/accounts/{admin_id}/role"),
        json!({ "role": "boss" }),
    );
    assert_eq!(code, 422, "{err}");
    assert!(
        err["error"]
            .as_str()
            .unwrap()
            .contains("admin, experimenter, analyst"),
        "{err}"
    );

    // The only admin can neither be demoted nor disabled.
    for (path, body) in [
        (
            format!("/api/accounts/{admin_id}/role"),
            json!({ "role": "experimenter" }),
        ),
        (format!("/api/accounts/{admin_id}/disable"), json!({})),
    ] {
        let (code, err) = admin.post(&path, body);
        assert_eq!(code, 409, "{path}: {err}");
        assert!(
            err["error"].as_str().unwrap().contains("last active admin"),
            "{err}"
        );
    }

    // Disabling ends the account's session at once, and it cannot log in again.
    let (alice_id, alice) = server.account(&admin, "alice", "experimenter");
    let (code, err) = admin.post(
        "/api/accounts",
        json!({ "username": "alice", "password": ADMIN_PASSWORD, "role": "analyst" }),
    );
    assert_eq!(code, 409, "{err}");
    assert_eq!(alice.get("/api/me").0, 200);
    let disabled = admin.ok(&format!("/api/accounts/{alice_id}/disable"), json!({}));
    assert!(disabled["disabled_at"].is_string(), "{disabled}");
    assert_eq!(alice.get("/api/me").0, 401);
    assert_eq!(alice.post("/api/studies", json!({})).0, 401);
    let (code, err) = Api::anonymous(&server.base).post(
        "/api/login",
        json!({ "username": "alice", "password": ADMIN_PASSWORD }),
    );
    assert_eq!(code, 403, "{err}");
    assert!(err["error"].as_str().unwrap().contains("disabled"), "{err}");
    admin.ok(&format!("/api/accounts/{alice_id}/enable"), json!({}));
    let alice = server.login("alice", ADMIN_PASSWORD);

    // With a second admin, the first may be demoted; then the second is the last one.
    let (bob_id, bob) = server.account(&admin, "bob", "admin");
    let demoted = bob.ok(
        &format!("/api/accounts/{admin_id}/role"),
        json!({ "role": "analyst" }),
    );
    assert_eq!(demoted["role"], "analyst");
    assert_eq!(
        admin.get("/api/accounts").0,
        403,
        "the role applies at once"
    );
    let (code, _) = bob.post(&format!("/api/accounts/{bob_id}/disable"), json!({}));
    assert_eq!(code, 409);
    let list = bob.get("/api/accounts").1;
    assert_eq!(account(&list, "admin")["role"], "analyst");
    assert_eq!(account(&list, "bob")["role"], "admin");
    assert!(account(&list, "alice")["disabled_at"].is_null());
    assert!(account(&list, "alice").get("password_hash").is_none());
    assert_eq!(alice.get("/api/accounts").0, 403);

    // Every change is audited with the admin who made it.
    let audit = bob.get("/api/audit?limit=1000").1;
    let rows = audit.as_array().unwrap();
    let by = |action: &str| -> Vec<(String, Value)> {
        rows.iter()
            .filter(|r| r["action"] == action)
            .map(|r| {
                (
                    r["actor"].as_str().unwrap().to_string(),
                    r["actor_id"].clone(),
                )
            })
            .collect()
    };
    assert_eq!(
        by("experimenter.disable"),
        [("admin".into(), json!(admin_id))]
    );
    assert_eq!(
        by("experimenter.enable"),
        [("admin".into(), json!(admin_id))]
    );
    assert_eq!(by("experimenter.role"), [("bob".into(), json!(bob_id))]);
    assert_eq!(
        by("experimenter.create").len(),
        3,
        "the startup's admin, alice and bob"
    );
}

#[test]
fn every_audit_row_names_the_acting_account_or_says_what_acted() {
    let server = Server::start("accounts-audit");
    let admin = server.experimenter();
    let (alice_id, alice) = server.account(&admin, "alice", "experimenter");
    let study = short_study(&alice, 1.0, 0.5);
    let (code, _) = Api::anonymous(&server.base).post(
        "/api/login",
        json!({ "username": "alice", "password": "wrong password" }),
    );
    assert_eq!(code, 403);
    alice.ok(
        &format!("/api/studies/{study}/pilot"),
        json!({ "subjects": 1 }),
    );
    let status = eventually(Duration::from_secs(300), || {
        let (_, p) = alice.get("/api/pilot");
        (p["running"] == false && (p["report"].is_object() || p["error"].is_string())).then_some(p)
    });
    assert!(status["report"].is_object(), "{status}");

    let audit = alice.get("/api/audit?limit=10000").1;
    let rows = audit.as_array().unwrap();
    let row = |action: &str| {
        rows.iter()
            .find(|r| r["action"] == action)
            .unwrap_or_else(|| panic!("{action} in the audit log"))
    };
    assert_eq!(row("study.create")["actor"], "alice");
    assert_eq!(row("study.create")["actor_id"], alice_id);
    assert_eq!(row("pilot.start")["actor"], "alice");
    assert_eq!(row("trial.finish")["actor"], "pilot (by alice)");
    assert_eq!(row("login.failed")["actor"], "anonymous:login");
    assert_eq!(row("experimenter.create")["actor"], "admin");
    assert!(
        rows.iter()
            .any(|r| r["actor"] == "system:startup" && r["action"] == "experimenter.create"),
        "--admin-password's account is made by the startup"
    );
    // No row is by a bare word: each names an account (with its id) or says what it is.
    for r in rows {
        let actor = r["actor"].as_str().unwrap();
        assert!(
            r["actor_id"].is_i64() || actor.contains(':') || actor.contains(' '),
            "{r}"
        );
    }
}

/// A dashboard in Chromium, logged in as `username` (password [`ADMIN_PASSWORD`]).
fn dashboard(driver: &Driver, downloads: &TempDir, base: &str, username: &str) -> Session {
    let dash = driver.session(downloads.path());
    dash.goto(&format!("{base}/"));
    dash.type_into("#login-username", username);
    dash.type_into("#login-password", ADMIN_PASSWORD);
    dash.click("#login-submit");
    dash.find("#estop");
    dash
}

/// Whether the element `css` is displayed.
fn shown(dash: &Session, css: &str) -> bool {
    dash.exec(
        "const n = document.querySelector(arguments[0]); return !!n && n.offsetParent !== null;",
        json!([css]),
    ) == true
}

#[test]
fn in_chromium_the_dashboard_asks_before_withdrawing_or_disabling_and_follows_the_role() {
    let server = Server::start("accounts-browser");
    let admin = server.experimenter();
    let study = short_study(&admin, 60.0, 60.0);
    let enrolled = admin.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let code = enrolled["subject"]["code"].as_str().unwrap();
    server.account(&admin, "ana", "analyst");
    let downloads = TempDir::new("accounts-browser-downloads");
    let driver = Driver::start();

    let dash = dashboard(&driver, &downloads, &server.base, "admin");
    assert!(shown(&dash, "#sec-accounts"), "an admin sees the accounts");
    dash.find("#accounts tr[data-account-id]");
    // Withdrawing asks first, naming the subject; Cancel changes nothing.
    let withdrawn =
        || admin.get(&format!("/api/subjects/{subject}")).1["subject"]["withdrawn_at"].is_i64();
    let row = format!("#subjects tr[data-subject-id='{subject}']");
    dash.find(&row);
    dash.click(&row);
    dash.find("#schedule tbody tr");
    dash.type_into(
        &format!("input[data-withdraw-reason='{subject}']"),
        "felt unwell",
    );
    let button = format!("button[data-action='withdraw'][data-subject-id='{subject}']");
    dash.click(&button);
    dash.find("#confirm-dialog");
    assert!(
        dash.text("#confirm-title").contains(code),
        "{}",
        dash.text("#confirm-title")
    );
    dash.click("#confirm-cancel");
    dash.wait_until(
        "return document.querySelector('#confirm-dialog').open ? null : true",
        json!([]),
    );
    assert!(!withdrawn(), "Cancel does not withdraw");
    dash.click(&button);
    dash.find("#confirm-dialog");
    dash.click("#confirm-ok");
    eventually(Duration::from_secs(20), || withdrawn().then_some(()));
    // The withdrawn subject's schedule, with its data, leaves the screen.
    dash.wait_until(
        "return document.querySelector('#schedule tbody') ? null : document.querySelector('#schedule').textContent",
        json!([]),
    );
    // Disabling an account asks too.
    let disable = "#accounts button[data-action='disable'][data-account-id='2']";
    dash.click(disable);
    dash.find("#confirm-dialog");
    assert!(dash.text("#confirm-title").contains("ana"));
    dash.click("#confirm-ok");
    dash.find("#accounts button[data-action='enable'][data-account-id='2']");
    admin.ok("/api/accounts/2/enable", json!({}));

    // An analyst sees no control it may not use, but the E-stop.
    let ana = dashboard(&driver, &downloads, &server.base, "ana");
    ana.find(&row);
    for css in [
        "#enrol",
        "#pair-form",
        "#study-create",
        "#estop-reset",
        "#sec-accounts",
        button.as_str(),
    ] {
        assert!(!shown(&ana, css), "an analyst sees {css}");
    }
    assert!(shown(&ana, "#estop"));
    assert!(ana.text("#whoami").contains("analyst"));
}
