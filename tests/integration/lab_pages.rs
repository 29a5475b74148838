//! The pages a lab meets on its first day (issue 39), in Chromium through the real server:
//! a pilot's dry run listed, marked and its results shown (never pooled with the study's
//! people); an erased subject shown as erased, with nothing to do and not offered to a
//! station; the schedule fitting its box; the live monitor's note with no station paired;
//! no two elements of the dashboard sharing an id; a station's stop notice in one sentence;
//! and a second tab of a station's browser refused.

use std::time::Duration;

use bdft_tests::TempDir;
use bdft_tests::server::{
    Api, Server, eventually, person_at_a_station, run_trial, short_study, trial_rows, with_store,
};
use bdft_tests::webdriver::Driver;
use serde_json::{Value, json};

#[test]
fn a_pilots_dry_run_is_listed_marked_and_its_results_shown_apart_from_the_studys() {
    let server = Server::start("lab-dry-run");
    let api = server.experimenter();
    let study = short_study(&api, 2.0, 1.0);
    let downloads = TempDir::new("lab-dry-run");
    let driver = Driver::start();
    let dash = driver.dashboard_on(downloads.path(), &server.base, study);

    // The pilot from the dashboard: when it ends, the study list has its dry run, marked.
    dash.type_into("#pilot-subjects", "2");
    dash.click("#pilot-start");
    let status = eventually(Duration::from_secs(300), || {
        let (_, s) = api.get("/api/pilot");
        (s["running"] == false && s["report"].is_object()).then_some(s)
    });
    let copy = status["report"]["study_id"].as_i64().unwrap();
    let (_, listed) = api.get(&format!("/api/studies/{copy}"));
    assert_eq!(listed["dry_run"]["of_study"], study, "{listed}");
    assert!(api.get(&format!("/api/studies/{study}")).1["dry_run"].is_null());
    let option = dash.wait_until(
        "const o = document.querySelector(`#study-select option[value='${arguments[0]}']`); return o ? o.textContent : null;",
        json!([copy.to_string()]),
    );
    let option = option.as_str().unwrap();
    assert!(
        option.contains("Pilot of end-to-end") && option.contains(&format!("dry run #{copy}")),
        "{option}"
    );
    let row = dash.text(&format!("#studies tr[data-study-id='{copy}']"));
    assert!(row.contains("dry run"), "{row}");
    assert!(dash.exists(&format!("[data-dry-run-badge='{copy}']")));
    // The study itself is not marked.
    assert!(!dash.exists(&format!("[data-dry-run-badge='{study}']")));

    // Selected, its results show: averages with n, the box plots drawn.
    dash.choose("#study-select", &copy.to_string());
    dash.wait_until(
        "return document.querySelectorAll('#averages td[data-variable]').length > 0;",
        json!([]),
    );
    dash.wait_until(
        "return [...document.querySelectorAll('#plots img')].some((i) => i.complete && i.naturalWidth > 0);",
        json!([]),
    );

    // Never pooled: the study's own results have none of the dry run's subjects.
    let (_, own) = api.get(&format!("/api/studies/{study}/summary"));
    assert_eq!(own.as_array().map(Vec::len), Some(0), "{own}");
    let (_, pilot) = api.get(&format!("/api/studies/{copy}/summary"));
    assert!(!pilot.as_array().unwrap().is_empty(), "{pilot}");
    let (_, subjects) = api.get(&format!("/api/studies/{study}/subjects"));
    assert_eq!(subjects.as_array().map(Vec::len), Some(0), "{subjects}");
}

#[test]
fn an_erased_subject_shows_erased_with_nothing_to_do_and_is_not_offered_to_a_station() {
    let server = Server::start("lab-erased");
    let api = server.experimenter();
    let study = short_study(&api, 2.0, 1.0);
    let enrol = |_| {
        api.ok(&format!("/api/studies/{study}/subjects"), json!({}))["subject"]["id"]
            .as_i64()
            .unwrap()
    };
    let (kept, erased) = (enrol(0), enrol(1));
    api.ok(
        &format!("/api/subjects/{erased}/erase"),
        json!({ "reason": "the subject asked for erasure" }),
    );
    // A station to assign to.
    bdft_tests::server::pair_station(&api, study, "both");

    let downloads = TempDir::new("lab-erased");
    let driver = Driver::start();
    let dash = driver.dashboard_on(downloads.path(), &server.base, study);
    let row = format!("#subjects tr[data-subject-id='{erased}']");
    dash.find(&row);
    let text = dash.text(&row);
    assert!(text.contains("erased"), "{text}");
    assert!(!text.contains("pending"), "{text}");
    assert!(!dash.exists(&format!("{row} button[data-action='withdraw']")));
    assert!(!dash.exists(&format!("{row} input")));
    // The subject still taking part keeps the withdrawal.
    assert!(dash.exists(&format!(
        "#subjects tr[data-subject-id='{kept}'] button[data-action='withdraw']:not([disabled])"
    )));
    // The station's list offers the one taking part, not the erased one.
    let offered = dash.wait_until(
        "const s = document.querySelector('select[data-assign-station]'); \
         return s ? [...s.options].map((o) => o.value).filter((v) => v) : null;",
        json!([]),
    );
    assert_eq!(offered, json!([kept.to_string()]));
}

#[test]
fn a_subjects_schedule_with_a_long_timing_line_fits_its_box_at_1400_px() {
    let server = Server::start("lab-schedule");
    let api = server.experimenter();
    let study = short_study(&api, 2.0, 1.0);
    let (subject, _, _) = person_at_a_station(&server, &api, study);
    let first = trial_rows(&api, subject)[0]["id"].as_i64().unwrap();
    let done = run_trial(&api, subject, first);
    assert_ne!(done["status"], "running", "{done}");
    // What a station in Chromium reports of its display (the page's own report, long).
    let timing = json!({ "frames": 123_456, "longest_gap_ms": 1234.5, "hidden_ms": 0.0,
        "input_hz": 59.94, "rtt_ms": { "p50": 12.25, "p95": 48.75, "max": 1234.5 } });
    with_store(&server, async |pool| {
        sqlx::query("UPDATE trials SET client_timing_json = $1 WHERE id = $2")
            .bind(timing.to_string())
            .bind(first)
            .execute(pool)
            .await
            .unwrap();
    });

    let downloads = TempDir::new("lab-schedule");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.cmd(
        "POST",
        "/window/rect",
        json!({ "width": 1400, "height": 900 }),
    )
    .unwrap();
    dash.log_in_to_dashboard(&server.base);
    dash.find("#estop");
    dash.select_study(study);
    let row = format!("#subjects tr[data-subject-id='{subject}']");
    dash.find(&row);
    dash.click(&row);
    let widths = dash.wait_until(
        "const t = document.querySelector('.schedule-table'); \
         if (!t || !t.querySelector('.validity') || !t.querySelector('.validity').textContent.includes('round trip')) return null; \
         const box = t.closest('.table-wrap'); return [t.scrollWidth, box.clientWidth];",
        json!([]),
    );
    let (table, frame) = (widths[0].as_i64().unwrap(), widths[1].as_i64().unwrap());
    assert!(
        table <= frame,
        "the schedule is {table} px wide in a {frame} px box"
    );
}

#[test]
fn the_dashboard_has_no_two_elements_with_one_id_and_its_monitor_says_no_station_is_paired() {
    let server = Server::start("lab-dashboard");
    let api = server.experimenter();
    let downloads = TempDir::new("lab-dashboard");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.log_in_to_dashboard(&server.base);
    dash.find("#estop");
    // Before any study, the monitor asks for one.
    dash.wait_until(
        "const p = document.querySelector('#monitors .monitor-empty'); return p && p.textContent.includes('Select or create a study first');",
        json!([]),
    );
    let study = short_study(&api, 2.0, 1.0);
    dash.goto(&format!("{}/", server.base));
    dash.find("#estop");
    dash.select_study(study);
    // A study selected with no station paired: the monitor says so.
    let note = dash.wait_until(
        "const p = document.querySelector('#monitors .monitor-empty'); \
         return p && p.textContent.includes('No station paired with this study yet') ? p.textContent : null;",
        json!([]),
    );
    assert!(!note.as_str().unwrap().contains("Select or create"));
    // Every id once, in the page as its scripts built it (with the study's views filled).
    dash.wait_until(
        "return document.querySelectorAll('#studies tr[data-study-id]').length > 0;",
        json!([]),
    );
    let duplicates = dash.exec(
        "const seen = new Map(); for (const e of document.querySelectorAll('[id]')) seen.set(e.id, (seen.get(e.id) || 0) + 1); \
         return [...seen].filter(([, n]) => n > 1).map(([id]) => id);",
        json!([]),
    );
    assert_eq!(duplicates, json!([]), "ids used more than once");
}

#[test]
fn a_station_says_in_one_sentence_that_the_experimenter_stopped_a_test_and_when_it_comes_back() {
    let server = Server::start("lab-stop-notice");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let (subject, _, token) = person_at_a_station(&server, &api, study);
    let downloads = TempDir::new("lab-stop-notice");
    let driver = Driver::start();
    let s = driver.session(downloads.path());
    s.open_paired_station(&server.base, &token);
    s.wait_phase("ready");
    let station = Api::with_bearer(&server.base, &token);
    let first = station.get("/api/station/state").1["test"].clone();
    let trial = first["trial_id"].as_i64().unwrap();
    api.ok(&format!("/api/trials/{trial}/start"), json!({}));
    eventually(Duration::from_secs(60), || {
        (trial_rows(&api, subject)
            .iter()
            .find(|t| t["id"] == trial)?["status"]
            == "running")
            .then_some(())
    });
    api.ok(
        &format!("/api/trials/{trial}/abort"),
        json!({ "reason": "the subject sneezed" }),
    );
    // Whether the repeat is the station's next test, as the server queued it.
    let next: Value = eventually(Duration::from_secs(60), || {
        let v = station.get("/api/station/state").1;
        (v["phase"] == "ready" && v["test"]["trial_id"] != trial).then_some(v)
    });
    let rows = trial_rows(&api, subject);
    let slot_of = |id: &Value| rows.iter().find(|t| &t["id"] == id).unwrap()["slot"].clone();
    let repeat_next = slot_of(&next["test"]["trial_id"]) == slot_of(&json!(trial));
    let then = if repeat_next {
        "It will be repeated next."
    } else {
        "It will be repeated later."
    };
    let want = format!(
        "{} was stopped by the experimenter. {then}",
        first["label"].as_str().unwrap()
    );
    let shown = s.wait_until(
        "const n = document.getElementById('stopped-notice'); return !n.hidden && n.textContent ? n.textContent : null;",
        json!([]),
    );
    assert_eq!(shown, json!(want));
}

#[test]
fn a_second_tab_of_a_stations_browser_is_refused_and_becomes_the_station_when_the_first_closes() {
    let server = Server::start("lab-two-tabs");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let (_, _, token) = person_at_a_station(&server, &api, study);
    let downloads = TempDir::new("lab-two-tabs");
    let driver = Driver::start();
    let s = driver.session(downloads.path());
    s.open_paired_station(&server.base, &token);
    s.wait_phase("ready");
    let first = s.cmd("GET", "/window", json!(null)).unwrap();

    // The same browser, another tab on the station's page: refused, saying why.
    let other = s
        .cmd("POST", "/window/new", json!({ "type": "tab" }))
        .unwrap();
    s.cmd("POST", "/window", json!({ "handle": other["handle"] }))
        .unwrap();
    s.goto(&format!("{}/station", server.base));
    s.wait_phase("other-tab");
    let text = s.text("#phase-other-tab");
    assert!(
        text.contains("This station is already open in another tab"),
        "{text}"
    );
    // The first is still the station, its socket not taken over.
    s.cmd("POST", "/window", json!({ "handle": first }))
        .unwrap();
    s.wait_phase("ready");

    // Closing the first makes the second the station.
    s.cmd("DELETE", "/window", json!({})).unwrap();
    s.cmd("POST", "/window", json!({ "handle": other["handle"] }))
        .unwrap();
    s.wait_phase("ready");
}

#[test]
fn the_tracking_displays_axis_is_labelled_at_round_symmetric_ticks() {
    let server = Server::start("lab-axis");
    let downloads = TempDir::new("lab-axis");
    let driver = Driver::start();
    let page = driver.session(downloads.path());
    page.goto(&format!("{}/station-pursuit.js", server.base));
    // The module the station draws with, asked for the gridlines of a range and their
    // labels (a returned promise is awaited by WebDriver).
    let axis = |range: f64| -> Value {
        page.exec(
            "return import('/station-pursuit.js').then((m) => m.axisTicks(arguments[0]).map((t) => [t, m.tickLabel(t)]));",
            json!([range]),
        )
    };
    let ticks = |range: f64| -> Vec<(f64, String)> {
        axis(range)
            .as_array()
            .unwrap()
            .iter()
            .map(|t| (t[0].as_f64().unwrap(), t[1].as_str().unwrap().to_string()))
            .collect()
    };
    // The default study's ±25 mm: the issue's +25, +13, 0, −12, −25 becomes round steps of
    // 10 and the range.
    let default = ticks(25.0);
    let values: Vec<f64> = default.iter().map(|t| t.0).collect();
    assert_eq!(values, [-25.0, -20.0, -10.0, 0.0, 10.0, 20.0, 25.0]);
    let labels: Vec<&str> = default.iter().map(|t| t.1.as_str()).collect();
    assert_eq!(
        labels,
        [
            "−25 mm", "−20 mm", "−10 mm", "0 mm", "+10 mm", "+20 mm", "+25 mm"
        ]
    );
    // Every range the study form allows: symmetric, zero in the middle, ±range at the ends,
    // each tick inside a multiple of one step of 1, 2 or 5 × 10ⁿ.
    for range in [1.0, 2.5, 7.0, 12.0, 30.0, 99.0, 120.0, 500.0] {
        let t = ticks(range);
        let v: Vec<f64> = t.iter().map(|t| t.0).collect();
        assert!(
            v.iter().zip(v.iter().rev()).all(|(a, b)| a == &-b),
            "{range}: {v:?}"
        );
        assert_eq!((v[0], v[v.len() - 1]), (-range, range), "{range}: {v:?}");
        assert!(v.contains(&0.0) && v.len() >= 5, "{range}: {v:?}");
        let step = v[v.len() / 2 + 1];
        let mantissa = step / 10f64.powf(step.log10().floor());
        assert!(
            [1.0, 2.0, 5.0].iter().any(|m| (m - mantissa).abs() < 1e-9),
            "{range}: step {step}"
        );
        assert!(
            step <= range / 2.0 && step * 5.0 > range / 2.0,
            "{range}: step {step}"
        );
        for (value, label) in &t {
            assert!(!label.contains('-'), "{range}: {label} uses a hyphen");
            let number: f64 = label
                .trim_end_matches(" mm")
                .replace('−', "-")
                .trim_start_matches('+')
                .parse()
                .unwrap();
            assert_eq!(number, *value, "{range}: {label}");
        }
    }
}
