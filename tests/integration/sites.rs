//! One server, two labs (`serve --site lab-a --site lab-b`, each with a controller of its
//! own): stations are paired to a site, a subject's stations are at one site, a trial runs
//! on its subject's site's machine and records it; a lost controller files only its own
//! site's trials; an E-stop stops one site or every site (a name no site has stops every
//! site), latched per site; a site's reset is refused while every site's latch holds.

use std::time::Duration;

use bdft_tests::exports::parse_csv;
use bdft_tests::server::{
    ADMIN_PASSWORD, Api, Server, dry_run, eventually, next_trial, short_study, trial_ended,
    trial_row,
};
use bdft_tests::webdriver::{Driver, artifacts_dir};
use serde_json::{Value, json};

/// Each site's entry of GET /api/controller, by name.
fn site(api: &Api, name: &str) -> Value {
    let (_, c) = api.get("/api/controller");
    c["sites"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["site"] == name)
        .unwrap_or_else(|| panic!("no site {name} in {c}"))
        .clone()
}

/// Waits until both sites' controllers are connected and unlatched.
fn sites_ready(api: &Api) {
    eventually(Duration::from_secs(60), || {
        let (_, c) = api.get("/api/controller");
        let sites = c["sites"].as_array()?;
        sites
            .iter()
            .all(|s| s["connected"] == true && s["estop_latched"] == false)
            .then_some(())
    });
}

/// Pairs a new station at `site` (none: the request names no site).
fn pair_at(api: &Api, study: i64, name: &str, role: &str, site: Option<&str>) -> (u16, Value) {
    let reg = Api::anonymous(&api.base).ok("/api/station/register", json!({}));
    let mut body = json!({ "pairing_code": reg["pairing_code"], "name": name, "role": role });
    if let Some(site) = site {
        body["site"] = json!(site);
    }
    let (code, mut answer) = api.post(&format!("/api/studies/{study}/stations"), body);
    answer["token"] = reg["token"].clone();
    (code, answer)
}

/// A synthetic subject of `study` at a new station on the machine at `site`, consented:
/// (subject id, its first test's id).
fn subject_at(api: &Api, study: i64, site: &str) -> (i64, i64) {
    let enrolled = api.ok(
        &format!("/api/studies/{study}/subjects"),
        json!({ "synthetic": true }),
    );
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let (code, station) = pair_at(api, study, &format!("at-{site}"), "on", Some(site));
    assert_eq!(code, 200, "{station}");
    assert_eq!(station["site"], site);
    api.ok(
        &format!("/api/stations/{}/assign", station["id"]),
        json!({ "subject_id": subject }),
    );
    Api::with_bearer(&api.base, station["token"].as_str().unwrap())
        .ok("/api/station/consent", json!({ "decision": "agreed" }));
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    (subject, s["trials"][0]["trial"]["id"].as_i64().unwrap())
}

fn start(api: &Api, trial: i64) -> (u16, Value) {
    api.post(&format!("/api/trials/{trial}/start"), json!({}))
}

/// A server with the admin account and two sites, lab-a and lab-b, each with its own
/// simulated controller.
fn two_sites(tag: &str) -> Server {
    let args = [
        "--admin-password",
        ADMIN_PASSWORD,
        "--site",
        "lab-a",
        "--site",
        "lab-b",
    ];
    Server::start_with(tag, &args)
}

#[test]
fn two_sites_run_their_own_trials_lose_and_stop_them_apart() {
    let server = two_sites("sites");
    let api = server.experimenter();
    sites_ready(&api);
    let (_, status) = api.get("/api/controller");
    let names: Vec<&str> = status["sites"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["site"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["lab-a", "lab-b"]);
    let pid = |name: &str| site(&api, name)["pid"].as_u64().unwrap();
    assert_ne!(pid("lab-a"), pid("lab-b"), "a controller process of each");

    // Long tests: they still run when the faults come.
    let study = dry_run(&api, short_study(&api, 60.0, 60.0));
    let (code, e) = pair_at(&api, study, "nowhere", "both", Some("lab-c"));
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().contains("lab-a, lab-b"), "{e}");
    let (a, a_first) = subject_at(&api, study, "lab-a");
    let (b, b_first) = subject_at(&api, study, "lab-b");
    // A station paired without a site is at the first one.
    let (_, plain) = pair_at(&api, study, "plain", "off", None);
    assert_eq!(plain["site"], "lab-a");
    // A subject's stations are at one site: a's desk station cannot be at lab-b.
    let (_, desk_b) = pair_at(&api, study, "desk-b", "off", Some("lab-b"));
    let (code, e) = api.post(
        &format!("/api/stations/{}/assign", desk_b["id"]),
        json!({ "subject_id": a }),
    );
    assert_eq!(code, 409, "{e}");
    assert!(
        e["error"].as_str().unwrap().contains("at site \"lab-a\""),
        "{e}"
    );

    // Each test runs on its subject's site and records it.
    let (code, t) = start(&api, a_first);
    assert_eq!((code, &t["site"]), (200, &json!("lab-a")), "{t}");
    let (code, t) = start(&api, b_first);
    assert_eq!((code, &t["site"]), (200, &json!("lab-b")), "{t}");

    // lab-a's controller dies: its test is filed incomplete, lab-b's runs on.
    let killed = pid("lab-a");
    let status = std::process::Command::new("kill")
        .args(["-KILL", &killed.to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let a_row = trial_ended(&api, a, a_first);
    assert_eq!(a_row["status"], "incomplete", "{a_row}");
    assert!(
        a_row["status_reason"]
            .as_str()
            .unwrap()
            .contains("controller lost"),
        "{a_row}"
    );
    assert_eq!(trial_row(&api, b, b_first)["status"], "running");
    eventually(Duration::from_secs(30), || {
        let s = site(&api, "lab-a");
        // Connected, and its latch (a controller starts latched) cleared by the server's.
        (s["connected"] == true && s["pid"].as_u64() != Some(killed) && s["estop_latched"] == false)
            .then_some(())
    });
    assert_eq!(trial_row(&api, b, b_first)["status"], "running");

    // lab-b's E-stop stops lab-b's test alone and latches lab-b alone.
    let stopped = api.ok("/api/estop?site=lab-b", json!({}));
    assert_eq!(stopped["sites"], json!(["lab-b"]), "{stopped}");
    let b_row = trial_ended(&api, b, b_first);
    assert_eq!(b_row["status"], "aborted", "{b_row}");
    assert!(
        b_row["status_reason"]
            .as_str()
            .unwrap()
            .starts_with("e-stop"),
        "{b_row}"
    );
    assert_eq!(site(&api, "lab-b")["estop_latched"], true);
    assert_eq!(site(&api, "lab-a")["estop_latched"], false);
    let b_again = next_trial(&api, b);
    let (code, e) = start(&api, b_again);
    assert_eq!(code, 409, "{e}");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .contains("E-stop of site \"lab-b\" is latched"),
        "{e}"
    );
    // lab-a runs on meanwhile.
    let a_again = next_trial(&api, a);
    let (code, t) = eventually(Duration::from_secs(30), || {
        let (code, t) = start(&api, a_again);
        (code != 503).then_some((code, t))
    });
    assert_eq!((code, &t["site"]), (200, &json!("lab-a")), "{t}");
    api.ok("/api/estop/reset?site=lab-b", json!({}));
    // The controller's latch clears when its status answers the reset.
    eventually(Duration::from_secs(10), || {
        (site(&api, "lab-b")["estop_latched"] == false).then_some(())
    });
    assert_eq!(trial_row(&api, a, a_again)["status"], "running");

    // A name no site has stops every site: a stop is never refused for a typo.
    let stopped = api.ok("/api/estop?site=lab-z", json!({}));
    assert_eq!(stopped["sites"], json!(["lab-a", "lab-b"]), "{stopped}");
    // Nor for a query that does not parse.
    let stopped = api.ok("/api/estop?sight=lab-a", json!({}));
    assert_eq!(stopped["sites"], json!(["lab-a", "lab-b"]), "{stopped}");
    assert_eq!(trial_ended(&api, a, a_again)["status"], "aborted");
    // Every site's latch holds until it is reset for every site.
    let (code, e) = api.post("/api/estop/reset?site=lab-a", json!({}));
    assert_eq!(code, 409, "{e}");
    assert!(e["error"].as_str().unwrap().contains("every site"), "{e}");
    let (code, e) = api.post("/api/estop/reset?site=lab-z", json!({}));
    assert_eq!(code, 422, "{e}");
    api.ok("/api/estop/reset", json!({}));
    sites_ready(&api);

    // The trials export says where each test ran (none for a test never started).
    let (code, csv) = api.get_text(&format!("/api/studies/{study}/export/trials"));
    assert_eq!(code, 200, "{csv}");
    let rows = parse_csv(&csv);
    let col = |name: &str| rows[0].iter().position(|c| c == name).unwrap();
    let site_of = |id: i64| {
        rows[1..]
            .iter()
            .find(|r| r[col("trial_id")] == id.to_string())
            .map(|r| r[col("site")].clone())
            .unwrap()
    };
    assert_eq!(
        [a_first, b_first, a_again, b_again].map(site_of),
        ["lab-a", "lab-b", "lab-a", ""]
    );

    // The audit log names what was stopped.
    let (_, log) = api.get("/api/audit?limit=200");
    let targets: Vec<&Value> = log
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "estop")
        .map(|e| &e["target"])
        .collect();
    assert_eq!(
        targets,
        [
            &json!("controller"),
            &json!("controller"),
            &json!("site:lab-b")
        ]
    );
}

#[test]
fn site_arguments_that_cannot_work_are_refused_at_start() {
    let dir = bdft_tests::TempDir::new("sites-refused");
    let db = dir.path().join("bdft-lab.db");
    for (args, says) in [
        (vec!["--site", "lab-a", "--site", "lab-a"], "given twice"),
        (vec!["--site", "Lab A"], "a-z, 0-9 and '-'"),
        (
            vec!["--site", "lab-a=127.0.0.1:7000"],
            "NAME=ADDRESS,KEY_FILE",
        ),
        (
            vec!["--site", "lab-a=127.0.0.1:7000,/nonexistent/key"],
            "--site lab-a: its key file",
        ),
        (
            vec!["--site", "lab-a", "--controller", "127.0.0.1:7000"],
            "--controller",
        ),
    ] {
        let out = bdft_tests::server_cmd(["serve", "--listen", "127.0.0.1:0", "--db"])
            .arg(&db)
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} started");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

/// The dashboard of a server with two sites: each site's link and latch with its own stop
/// and reset beside the button that stops them all, the pairing form asking for the site,
/// and the Accounts section ticking the sites an account may drive.
#[test]
fn in_chromium_the_dashboard_stops_and_resets_one_site() {
    let server = two_sites("sites-dashboard");
    let api = server.experimenter();
    sites_ready(&api);
    let downloads = bdft_tests::TempDir::new("sites-dashboard-downloads");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.log_in_to_dashboard(&server.base);
    let row = |site: &str| format!("#estop-sites li[data-site=\"{site}\"]");
    dash.wait_until(
        "const l = document.getElementById('estop-sites'); return !l.hidden && l.children.length === 2;",
        json!([]),
    );
    let sites: Value = dash.exec(
        "return [...document.getElementById('pair-site').options].map((o) => o.value);",
        json!([]),
    );
    assert_eq!(sites, json!(["lab-a", "lab-b"]));
    assert!(
        dash.exec(
            "return !document.getElementById('pair-site-label').hidden;",
            json!([])
        ) == true
    );

    dash.click(&format!("{} .estop-site", row("lab-b")));
    eventually(Duration::from_secs(10), || {
        (site(&api, "lab-b")["estop_latched"] == true).then_some(())
    });
    assert_eq!(site(&api, "lab-a")["estop_latched"], false);
    dash.wait_until(
        "return document.querySelector(arguments[0]).classList.contains('alarm');",
        json!([row("lab-b")]),
    );
    assert!(dash.text(&row("lab-b")).contains("LATCHED"));
    dash.wait_until(
        "return document.getElementById('estop-latch').textContent.includes('LATCHED at lab-b:');",
        json!([]),
    );
    assert!(!dash.text(&row("lab-a")).contains("LATCHED"));
    dash.screenshot(&artifacts_dir().join("sites-dashboard-lab-b-stopped.png"));

    dash.click(&format!("{} button:not(.estop-site)", row("lab-b")));
    eventually(Duration::from_secs(10), || {
        (site(&api, "lab-b")["estop_latched"] == false).then_some(())
    });
    dash.wait_until(
        "return !document.querySelector(arguments[0]).classList.contains('alarm');",
        json!([row("lab-b")]),
    );

    // The Accounts section ticks the sites an account may drive: at creation, and later.
    dash.wait_until(
        "return !document.getElementById('account-sites').hidden && document.querySelectorAll('#account-sites input').length === 2;",
        json!([]),
    );
    dash.type_into("#account-username", "carol");
    dash.type_into("#account-password", ADMIN_PASSWORD);
    dash.click("#account-sites input[value='lab-b']");
    dash.click("#account-create");
    let carol = eventually(Duration::from_secs(10), || {
        let (_, list) = api.get("/api/accounts");
        list.as_array()?
            .iter()
            .find(|a| a["username"] == "carol")
            .cloned()
    });
    assert_eq!(carol["sites"], json!(["lab-b"]), "{carol}");
    let id = carol["id"].as_i64().unwrap();
    let boxes = format!("#accounts td[data-sites-of='{id}']");
    dash.wait_until(
        "return document.querySelector(arguments[0] + \" input[value='lab-b']\")?.checked ? true : null;",
        json!([boxes]),
    );
    dash.screenshot(&artifacts_dir().join("sites-dashboard-accounts.png"));
    dash.click(&format!("{boxes} input[value='lab-a']"));
    dash.click(&format!("{boxes} button[data-action='sites']"));
    eventually(Duration::from_secs(10), || {
        let (_, list) = api.get("/api/accounts");
        let sites = list.as_array()?.iter().find(|a| a["id"] == id)?["sites"].clone();
        (sites == json!(["lab-a", "lab-b"])).then_some(())
    });
    // None ticked: every site.
    dash.wait_until(
        "return document.querySelector(arguments[0] + \" input[value='lab-a']\")?.checked ? true : null;",
        json!([boxes]),
    );
    dash.click(&format!("{boxes} input[value='lab-a']"));
    dash.click(&format!("{boxes} input[value='lab-b']"));
    dash.click(&format!("{boxes} button[data-action='sites']"));
    eventually(Duration::from_secs(10), || {
        let (_, list) = api.get("/api/accounts");
        let sites = list.as_array()?.iter().find(|a| a["id"] == id)?["sites"].clone();
        sites.is_null().then_some(())
    });
}

/// The error of a refusal (its status must be `code`).
fn refusal(answer: (u16, Value), code: u16) -> String {
    let (got, body) = answer;
    assert_eq!(got, code, "{body}");
    body["error"]
        .as_str()
        .unwrap_or_else(|| panic!("not the JSON error: {body}"))
        .to_string()
}

/// Per-site roles: an account limited to lab-a starts, aborts and resets lab-a's machine
/// only, and runs the bench on lab-a's real machine only; it still presses any site's
/// E-stop. An admin sets the sites (checked against the server's), each change audited; an
/// account with no sites drives every site's machine, as every account did before.
#[test]
fn an_account_limited_to_a_site_drives_only_its_machine_but_stops_any() {
    let server = two_sites("sites-roles");
    let admin = server.experimenter();
    sites_ready(&admin);

    // The sites are checked against the server's: a 422 naming them.
    for sites in [json!(["lab-c"]), json!([]), json!(["lab-a", "Lab A"])] {
        let e = refusal(
            admin.post(
                "/api/accounts",
                json!({ "username": "eve", "password": ADMIN_PASSWORD, "role": "experimenter", "sites": sites }),
            ),
            422,
        );
        assert!(e.contains("lab-a, lab-b"), "{sites}: {e}");
    }
    let made = admin.ok(
        "/api/accounts",
        json!({ "username": "bob", "password": ADMIN_PASSWORD, "role": "experimenter", "sites": ["lab-a"] }),
    );
    assert_eq!(made["sites"], json!(["lab-a"]), "{made}");
    let bob_id = made["id"].as_i64().unwrap();
    let bob = server.login("bob", ADMIN_PASSWORD);
    assert_eq!(bob.get("/api/me").1["sites"], json!(["lab-a"]));
    // Accounts made without sites drive every site (none listed).
    let (_, me) = admin.get("/api/me");
    assert_eq!(me["sites"], Value::Null, "{me}");

    let study = dry_run(&admin, short_study(&admin, 60.0, 60.0));
    let (a, a_first) = subject_at(&admin, study, "lab-a");
    let (b, b_first) = subject_at(&admin, study, "lab-b");

    // Starting a test at lab-b is refused, naming bob's sites; at lab-a it runs.
    let e = refusal(start(&bob, b_first), 403);
    assert!(e.contains("\"lab-a\"") && e.contains("\"lab-b\""), "{e}");
    assert_eq!(trial_row(&admin, b, b_first)["status"], "scheduled");
    let (code, t) = start(&bob, a_first);
    assert_eq!((code, &t["site"]), (200, &json!("lab-a")), "{t}");
    let (code, t) = start(&admin, b_first);
    assert_eq!((code, &t["site"]), (200, &json!("lab-b")), "{t}");

    // Aborting lab-b's test is refused; lab-a's is aborted.
    let abort = |api: &Api, id: i64| {
        api.post(
            &format!("/api/trials/{id}/abort"),
            json!({ "reason": "checking per-site roles" }),
        )
    };
    let e = refusal(abort(&bob, b_first), 403);
    assert!(e.contains("\"lab-b\""), "{e}");
    assert_eq!(trial_row(&admin, b, b_first)["status"], "running");
    assert_eq!(abort(&bob, a_first).0, 200);
    assert_eq!(trial_ended(&admin, a, a_first)["status"], "aborted");

    // Bob presses lab-b's E-stop: never refused. Resetting it is.
    let stopped = bob.ok("/api/estop?site=lab-b", json!({}));
    assert_eq!(stopped["sites"], json!(["lab-b"]), "{stopped}");
    assert_eq!(trial_ended(&admin, b, b_first)["status"], "aborted");
    let e = refusal(bob.post("/api/estop/reset?site=lab-b", json!({})), 403);
    assert!(e.contains("\"lab-b\""), "{e}");
    // A reset of every site is one of lab-b too.
    let e = refusal(bob.post("/api/estop/reset", json!({})), 403);
    assert!(e.contains("every site"), "{e}");
    assert_eq!(site(&admin, "lab-b")["estop_latched"], true);
    // A site no server serves is still the 422 it was, not a refusal of bob.
    assert_eq!(bob.post("/api/estop/reset?site=lab-z", json!({})).0, 422);
    admin.ok("/api/estop/reset?site=lab-b", json!({}));
    // The E-stop of every site, by bob; only an account of every site resets it.
    let stopped = bob.ok("/api/estop", json!({}));
    assert_eq!(stopped["sites"], json!(["lab-a", "lab-b"]), "{stopped}");
    assert_eq!(bob.post("/api/estop/reset", json!({})).0, 403);
    admin.ok("/api/estop/reset", json!({}));
    sites_ready(&admin);
    // Bob's own site's E-stop he stops and resets.
    bob.ok("/api/estop?site=lab-a", json!({}));
    bob.ok("/api/estop/reset?site=lab-a", json!({}));
    sites_ready(&admin);

    // The bench on lab-b's real machine is refused; lab-a's is only refused by its
    // (simulating) controller; a simulated run uses no site's machine and runs.
    let (_, mut params) = admin.get("/api/defaults");
    params["rig"] = json!("real");
    let real = admin.ok("/api/studies", json!({ "name": "real", "params": params }))["id"]
        .as_i64()
        .unwrap();
    let bench = |site: &str, study: Option<i64>| {
        bob.post(
            "/api/bench",
            json!({ "study_id": study, "site": site, "duration_s": 1.0,
                    "compensators": [{ "design": "pid" }], "signal": { "kind": "trapezoid" } }),
        )
    };
    let e = refusal(bench("lab-b", Some(real)), 403);
    assert!(e.contains("\"lab-b\""), "{e}");
    let e = refusal(bench("lab-a", Some(real)), 409);
    assert!(e.contains("rig"), "{e}");
    let (code, run) = bench("lab-b", None);
    assert_eq!(code, 200, "{run}");

    // The admin lifts the limit: bob drives lab-b's machine. Then limits him again.
    let e = refusal(
        admin.post(
            &format!("/api/accounts/{bob_id}/sites"),
            json!({ "sites": ["lab-q"] }),
        ),
        422,
    );
    assert!(e.contains("lab-a, lab-b"), "{e}");
    let changed = admin.ok(
        &format!("/api/accounts/{bob_id}/sites"),
        json!({ "sites": null }),
    );
    assert_eq!(changed["sites"], Value::Null, "{changed}");
    let b_again = next_trial(&admin, b);
    let (code, t) = start(&bob, b_again);
    assert_eq!((code, &t["site"]), (200, &json!("lab-b")), "{t}");
    let changed = admin.ok(
        &format!("/api/accounts/{bob_id}/sites"),
        json!({ "sites": ["lab-b", "lab-a"] }),
    );
    assert_eq!(changed["sites"], json!(["lab-a", "lab-b"]), "{changed}");
    let (_, list) = admin.get("/api/accounts");
    let listed = list
        .as_array()
        .unwrap()
        .iter()
        .find(|x| x["username"] == "bob")
        .unwrap();
    assert_eq!(listed["sites"], json!(["lab-a", "lab-b"]), "{list}");
    // Only an admin sets them.
    assert_eq!(
        bob.post(
            &format!("/api/accounts/{bob_id}/sites"),
            json!({ "sites": null })
        )
        .0,
        403
    );

    // Each setting is in the audit log, with what it was before.
    let (_, log) = admin.get("/api/audit?limit=500");
    let rows: Vec<&Value> = log
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| {
            r["target"] == format!("experimenter:{bob_id}")
                && ["experimenter.create", "experimenter.sites"]
                    .contains(&r["action"].as_str().unwrap())
        })
        .collect();
    let details: Vec<&Value> = rows.iter().map(|r| &r["detail"]).collect();
    assert_eq!(details.len(), 3, "{details:?}");
    let sites_of = |d: &Value| (d["from"].clone(), d["to"].clone());
    assert!(
        details.iter().any(|d| d["sites"] == json!(["lab-a"])),
        "the creation records the sites: {details:?}"
    );
    assert!(
        details
            .iter()
            .any(|d| sites_of(d) == (json!(["lab-a"]), Value::Null)),
        "{details:?}"
    );
    assert!(
        details
            .iter()
            .any(|d| sites_of(d) == (Value::Null, json!(["lab-a", "lab-b"]))),
        "{details:?}"
    );
}
