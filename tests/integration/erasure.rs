//! Erasure on request through the real server and controller: two synthetic subjects run the
//! whole protocol at stations (tests, surveys with comments, a note, a redo, a test accepted
//! as incomplete); an admin erases one. Then every table of the store — listed from
//! `sqlite_master`, or PostgreSQL's `information_schema` when the tests' servers run there,
//! so a table added later is searched too — holds only the allowed traces
//! of the erased subject (its row reduced to id, study, code, enrolment index, starting seat
//! and synthetic flag; the erasure's audit row; the older audit rows with their details
//! redacted), neither the file nor its write-ahead log holds a byte of what they wrote, the
//! other subject is untouched, and the exports and statistics no longer count the erased
//! one. Also the refusals (404, 422, 403, 409 for a running test; notes racing the erasure
//! filed before it or refused after it, never a 500) and the backups listed as
//! still holding the data (those copied before the erasure, by their manifests).

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use bdft_tests::postgres::servers_on_postgres;
use bdft_tests::server::{
    ADMIN_PASSWORD, Api, Server, assigned_station, dry_run, eventually, pair_station,
    person_at_a_station, run_trial, short_study, with_db, with_store,
};
use bdft_tests::webdriver::{Session, artifacts_dir};
use bdft_tests::{TempDir, server_cmd, succeeded};
use serde_json::{Value, json};
use sqlx::AnyPool;

use crate::accounts::{BrowserLab, browser_lab, dashboard, shown};
use crate::exports_audit::{column, parse_csv};

fn shot(s: &Session, name: &str) {
    s.screenshot(&artifacts_dir().join(format!("{name}.png")));
}

/// What the erased subject wrote or was written about them; none of it may survive.
const MARK: &str = "ERASE-ME";

/// A synthetic subject enrolled in `study` and consented at a station of its own: (subject
/// id, code, the page token, the station's client).
fn at_a_station(api: &Api, study: i64) -> (i64, String, String, Api) {
    let e = api.ok(
        &format!("/api/studies/{study}/subjects"),
        json!({ "synthetic": true }),
    );
    let subject = e["subject"]["id"].as_i64().unwrap();
    let (_, token) = assigned_station(api, study, subject);
    let st = Api::with_bearer(&api.base, &token);
    st.ok("/api/station/consent", json!({ "decision": "agreed" }));
    (
        subject,
        e["subject"]["code"].as_str().unwrap().to_string(),
        e["subject_token"].as_str().unwrap().to_string(),
        st,
    )
}

/// Runs the subject at `station` through every test, answering each survey with `comment`.
/// A test that did not complete (a controller lost on a loaded machine) holds a synthetic
/// subject — the server repeats only a person's tests by itself —: the experimenter redoes
/// it, as they would.
fn run_protocol(api: &Api, subject: i64, station: &Api, comment: &str) {
    loop {
        let (_, state) = station.get("/api/station/state");
        match state["phase"].as_str().unwrap() {
            "ready" => {
                let t = state["test"]["trial_id"].as_i64().unwrap();
                run_trial(api, subject, t);
            }
            "held" => {
                let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
                let trials: Vec<&Value> = detail["trials"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|t| &t["trial"])
                    .collect();
                let unsettled = trials
                    .iter()
                    .find(|t| {
                        t["status"] != "complete"
                            && t["accepted_reason"].is_null()
                            && !trials.iter().any(|u| {
                                u["slot"] == t["slot"]
                                    && u["attempt"].as_i64() > t["attempt"].as_i64()
                            })
                    })
                    .unwrap_or_else(|| panic!("held, but every test is settled: {detail}"));
                api.ok(
                    &format!("/api/trials/{}/redo", unsettled["id"]),
                    json!({ "reason": "it did not complete" }),
                );
            }
            "survey" => {
                let t = state["trial_id"].as_i64().unwrap();
                station.ok(
                    "/api/station/survey",
                    json!({ "trial_id": t, "accuracy": 5, "speed": 4, "smoothness": 3, "controllability": 6, "comment": format!("{comment} on trial {t}") }),
                );
            }
            "done" => return,
            other => panic!("unexpected phase {other}: {state}"),
        }
    }
}

/// A table of the database: its columns, the columns that refer to another table (by
/// foreign key: column → table), and each row's cells as SQL literals (`quote()`: NULL, 12,
/// 'text', X'0A…'), so any column of any type can be searched.
struct Table {
    columns: Vec<String>,
    refers: BTreeMap<String, String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    fn cell(&self, row: &[String], name: &str) -> String {
        row[self.columns.iter().position(|c| c == name).unwrap()].clone()
    }

    /// The columns that name a row of `parent` (`subjects`, `trials`): its foreign keys to it,
    /// and a column named as such a reference is (`subject_id`, `trial_id`) whatever its
    /// declaration.
    fn naming(&self, parent: &str) -> BTreeSet<&str> {
        let named = format!("{}_id", parent.trim_end_matches('s'));
        self.columns
            .iter()
            .filter(|c| **c == named || self.refers.get(*c).is_some_and(|t| t == parent))
            .map(String::as_str)
            .collect()
    }
}

/// Every table of the server's store, by name, as its catalogue lists them (`sqlite_master`,
/// or PostgreSQL's `information_schema`), each cell as SQLite's `quote()` writes it.
fn every_table(server: &Server) -> BTreeMap<String, Table> {
    match server.postgres {
        Some(_) => with_store(server, postgres_tables),
        None => with_db(&server.db, sqlite_tables),
    }
}

async fn sqlite_tables(pool: &AnyPool) -> BTreeMap<String, Table> {
    {
        let names: Vec<String> =
            sqlx::query_scalar("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")
                .fetch_all(pool)
                .await
                .unwrap();
        let mut out = BTreeMap::new();
        for t in names {
            let columns: Vec<String> = sqlx::query_scalar(&format!(
                "SELECT name FROM pragma_table_info('{t}') ORDER BY cid"
            ))
            .fetch_all(pool)
            .await
            .unwrap();
            let refers: Vec<(String, String)> = sqlx::query_as(&format!(
                "SELECT \"from\", \"table\" FROM pragma_foreign_key_list('{t}')"
            ))
            .fetch_all(pool)
            .await
            .unwrap();
            let select = columns
                .iter()
                .map(|c| format!("quote(\"{c}\")"))
                .collect::<Vec<_>>()
                .join(" || char(31) || ");
            let rows: Vec<String> = sqlx::query_scalar(&format!("SELECT {select} FROM \"{t}\""))
                .fetch_all(pool)
                .await
                .unwrap();
            let rows = rows
                .into_iter()
                .map(|r| r.split('\u{1f}').map(str::to_string).collect())
                .collect();
            out.insert(
                t,
                Table {
                    columns,
                    refers: refers.into_iter().collect(),
                    rows,
                },
            );
        }
        out
    }
}

/// PostgreSQL's tables, each cell written as SQLite's `quote()` would (numbers bare, text
/// and JSON quoted, bytes as X'…', NULL), so that one search reads both stores.
async fn postgres_tables(pool: &AnyPool) -> BTreeMap<String, Table> {
    let names: Vec<String> = sqlx::query_scalar(
        "SELECT table_name::text FROM information_schema.tables WHERE table_schema = 'public' AND table_type = 'BASE TABLE' ORDER BY 1",
    )
    .fetch_all(pool)
    .await
    .unwrap();
    let mut out = BTreeMap::new();
    for t in names {
        let typed: Vec<(String, String)> = sqlx::query_as(
            "SELECT column_name::text, data_type::text FROM information_schema.columns WHERE table_schema = 'public' AND table_name = $1 ORDER BY ordinal_position",
        )
        .bind(&t)
        .fetch_all(pool)
        .await
        .unwrap();
        let refers: Vec<(String, String)> = sqlx::query_as(
            "SELECT kcu.column_name::text, ccu.table_name::text FROM information_schema.table_constraints tc \
             JOIN information_schema.key_column_usage kcu ON kcu.constraint_name = tc.constraint_name AND kcu.table_schema = tc.table_schema \
             JOIN information_schema.constraint_column_usage ccu ON ccu.constraint_name = tc.constraint_name AND ccu.table_schema = tc.table_schema \
             WHERE tc.constraint_type = 'FOREIGN KEY' AND tc.table_schema = 'public' AND tc.table_name = $1",
        )
        .bind(&t)
        .fetch_all(pool)
        .await
        .unwrap();
        let select = typed
            .iter()
            .map(|(c, ty)| match ty.as_str() {
                "bigint" | "integer" | "smallint" | "double precision" | "real" | "numeric" => {
                    format!("COALESCE(\"{c}\"::text, 'NULL')")
                }
                "bytea" => {
                    format!("COALESCE('X''' || upper(encode(\"{c}\", 'hex')) || '''', 'NULL')")
                }
                _ => format!("COALESCE(quote_literal(\"{c}\"::text), 'NULL')"),
            })
            .collect::<Vec<_>>()
            .join(" || chr(31) || ");
        let rows: Vec<String> = sqlx::query_scalar(&format!("SELECT {select} FROM \"{t}\""))
            .fetch_all(pool)
            .await
            .unwrap();
        out.insert(
            t,
            Table {
                columns: typed.into_iter().map(|(c, _)| c).collect(),
                refers: refers.into_iter().collect(),
                rows: rows
                    .into_iter()
                    .map(|r| r.split('\u{1f}').map(str::to_string).collect())
                    .collect(),
            },
        );
    }
    out
}

/// The JSON of a quoted text cell.
fn json_cell(quoted: &str) -> Value {
    serde_json::from_str(&quoted.trim_matches('\'').replace("''", "'")).unwrap_or(Value::Null)
}

/// Whether the database file or its write-ahead log holds [`MARK`] anywhere, in a row or
/// in a free page.
fn files_hold_mark(server: &Server) -> bool {
    ["bdft-lab.db", "bdft-lab.db-wal"].iter().any(|file| {
        std::fs::read(server.dir.path().join(file))
            .unwrap_or_default()
            .windows(MARK.len())
            .any(|w| w == MARK.as_bytes())
    })
}

/// An export's rows (CSV).
fn export(api: &Api, study: i64, kind: &str) -> Vec<Vec<String>> {
    let (code, text) = api.get_text(&format!("/api/studies/{study}/export/{kind}"));
    assert_eq!(code, 200, "{kind}: {text}");
    parse_csv(&text)
}

fn codes_in(rows: &[Vec<String>]) -> BTreeSet<String> {
    let c = column(rows, "subject_code");
    rows[1..].iter().map(|r| r[c].clone()).collect()
}

/// The largest `n` of an export with an `n` column (subjects counted).
fn largest_n(rows: &[Vec<String>]) -> i64 {
    let c = column(rows, "n");
    rows[1..]
        .iter()
        .map(|r| r[c].parse::<i64>().unwrap())
        .max()
        .unwrap_or(0)
}

#[test]
fn an_erased_subject_leaves_only_the_erasure_in_every_table_and_no_count() {
    // On PostgreSQL (BDFT_TEST_STORE=postgres) there are no backups (they are SQLite files)
    // and no file to read: the tables are searched as on SQLite, the rest is SQLite's.
    let on_sqlite = !servers_on_postgres();
    let backups = TempDir::new("erasure-backups");
    let mut args = vec!["--admin-password", ADMIN_PASSWORD];
    if on_sqlite {
        args.extend(["--backup-dir", backups.path().to_str().unwrap()]);
    }
    let server = Server::start_with("erasure", &args);
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 1.0, 0.5));
    let (erased, code, page_token, erased_station) = at_a_station(&api, study);
    let (kept, kept_code, _, kept_station) = at_a_station(&api, study);
    run_protocol(&api, erased, &erased_station, &format!("{MARK} survey"));
    run_protocol(&api, kept, &kept_station, "kept survey");

    // A note, a redo with its reason, and the new attempt accepted as incomplete.
    let (_, detail) = api.get(&format!("/api/subjects/{erased}"));
    let last = detail["trials"].as_array().unwrap().last().unwrap()["trial"]["id"]
        .as_i64()
        .unwrap();
    api.ok(
        &format!("/api/trials/{last}/note"),
        json!({ "text": format!("{MARK} note") }),
    );
    let redo = api.ok(
        &format!("/api/trials/{last}/redo"),
        json!({ "reason": format!("{MARK} redo") }),
    );
    api.ok(
        &format!("/api/trials/{}/incomplete", redo["id"]),
        json!({ "reason": format!("{MARK} accepted") }),
    );
    let (_, detail) = api.get(&format!("/api/subjects/{erased}"));
    let trials = detail["trials"].as_array().unwrap();
    let erased_trials: BTreeSet<i64> = trials
        .iter()
        .map(|t| t["trial"]["id"].as_i64().unwrap())
        .collect();
    assert!(
        erased_trials.len() >= 12,
        "practice, ten tests and the redo"
    );
    let surveys = trials.iter().filter(|t| !t["survey"].is_null()).count();
    assert_eq!(surveys, 10, "{detail}");

    // Before: both subjects in every export and count.
    for kind in ["trials", "subjects", "samples"] {
        assert_eq!(
            codes_in(&export(&api, study, kind)),
            BTreeSet::from([code.clone(), kept_code.clone()]),
            "{kind}"
        );
    }
    assert_eq!(largest_n(&export(&api, study, "summary")), 2);
    assert!(
        export(&api, study, "notes")
            .iter()
            .any(|r| r.iter().any(|c| c.contains(MARK)))
    );
    let kept_before = api.get(&format!("/api/subjects/{kept}")).1;

    // Backups: the schedule's first, made at start, and one made now that holds everything
    // the subject did; and a file whose manifest cannot be read (what it holds is unknown).
    let holds_mark = |file: &Value| {
        std::fs::read(backups.path().join(file.as_str().unwrap()))
            .unwrap()
            .windows(MARK.len())
            .any(|w| w == MARK.as_bytes())
    };
    let made_before = on_sqlite.then(|| {
        let scheduled = eventually(Duration::from_secs(60), || {
            let (_, v) = api.get("/api/backups");
            let listed = v["backups"].as_array()?;
            (listed.len() == 1 && v["running"] == false).then(|| listed[0]["file"].clone())
        });
        let before_erasure = api.ok("/api/backups", json!({}))["file"].clone();
        assert!(holds_mark(&before_erasure), "the backup holds the data");
        std::fs::write(backups.path().join("copied-by-hand.db"), "a copy").unwrap();
        std::fs::write(backups.path().join("copied-by-hand.db.manifest.json"), "{}").unwrap();
        (scheduled, before_erasure)
    });

    // The audit rows about the subject, read before the erasure: by their target, or by
    // their details naming the subject (a station's assignment).
    let before = every_table(&server);
    let audit_before: BTreeMap<String, (String, Value)> = before["audit_log"]
        .rows
        .iter()
        .map(|r| {
            let a = &before["audit_log"];
            (
                a.cell(r, "id"),
                (a.cell(r, "target"), json_cell(&a.cell(r, "detail_json"))),
            )
        })
        .collect();

    // The searches below can find the text: the tables' and the files'.
    assert!(
        before
            .values()
            .any(|t| t.rows.iter().any(|r| r.iter().any(|c| c.contains(MARK)))),
        "the tables hold the subject's text before the erasure"
    );
    assert!(
        !on_sqlite || files_hold_mark(&server),
        "the files hold the subject's text before the erasure"
    );

    let reason = "the subject asked for erasure (request 7)";
    let report = api.ok(
        &format!("/api/subjects/{erased}/erase"),
        json!({ "reason": reason }),
    );
    assert_eq!(report["code"], code.as_str(), "{report}");
    assert_eq!(report["by"], "admin");
    assert_eq!(report["reason"], reason);
    assert_eq!(
        report["removed"]["trials"].as_u64(),
        Some(erased_trials.len() as u64),
        "{report}"
    );
    assert_eq!(report["removed"]["surveys"], 10, "{report}");
    assert_eq!(report["removed"]["notes"], 1, "{report}");
    assert_eq!(report["removed"]["stations_released"], 1, "{report}");
    assert!(
        report["removed"]["records"].as_u64().unwrap() >= 11,
        "{report}"
    );
    assert_eq!(report["wal_cleared"], true, "{report}");
    let held: Vec<(&str, bool)> = report["backups_holding_data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| (b["backup"].as_str().unwrap(), b["problem"].is_null()))
        .collect();
    match &made_before {
        Some((scheduled, before_erasure)) => assert_eq!(
            held,
            [
                (scheduled.as_str().unwrap(), true),
                (before_erasure.as_str().unwrap(), true),
                ("copied-by-hand.db", false)
            ],
            "{report}"
        ),
        None => assert_eq!(held, [], "no backups on PostgreSQL: {report}"),
    }
    assert!(report["backups_unchecked"].is_null(), "{report}");
    // A backup made after the erasure holds none of it, and is not listed.
    let after_erasure = on_sqlite.then(|| api.ok("/api/backups", json!({}))["file"].clone());
    assert!(!after_erasure.as_ref().is_some_and(holds_mark));
    let listed = api.get("/api/erasures").1;
    assert_eq!(listed["erasures"].as_array().unwrap().len(), 1, "{listed}");
    assert_eq!(listed["erasures"][0]["code"], code.as_str());
    assert_eq!(
        listed["erasures"][0]["backups_holding_data"],
        report["backups_holding_data"]
    );

    // Once only; an erased subject takes no further part.
    let (status, body) = api.post(
        &format!("/api/subjects/{erased}/erase"),
        json!({ "reason": reason }),
    );
    assert_eq!(status, 409, "{body}");
    assert!(body["error"].as_str().unwrap().contains("erased already"));
    let (status, body) = api.post(
        &format!("/api/subjects/{erased}/withdraw"),
        json!({ "reason": "x" }),
    );
    assert_eq!(status, 409, "{body}");
    let (station, _) = pair_station(&api, study, "both");
    let (status, body) = api.post(
        &format!("/api/stations/{station}/assign"),
        json!({ "subject_id": erased }),
    );
    assert_eq!(status, 409, "{body}");
    assert_eq!(
        Api::with_bearer(&server.base, &page_token)
            .get("/api/subject")
            .0,
        401,
        "the subject's page token opens nothing"
    );
    assert_eq!(
        erased_station.get("/api/station/state").1["phase"],
        "waiting",
        "the station is free"
    );

    // Every table: only the allowed traces.
    let tables = every_table(&server);
    assert!(tables.contains_key("audit_log") && tables.contains_key("trial_records"));
    let sid = erased.to_string();
    let trial_ids: BTreeSet<String> = erased_trials.iter().map(i64::to_string).collect();
    let audit = &tables["audit_log"];
    let erasure = audit
        .rows
        .iter()
        .find(|r| audit.cell(r, "action") == "'subject.erase'")
        .expect("the erasure is in the audit log");
    let erasure_id = audit.cell(erasure, "id");
    let marker =
        json!({ "erasure": erasure_id.parse::<i64>().unwrap(), "redacted": "subject.erase" });
    let mut redacted = 0;
    for (name, table) in &tables {
        let subject_cols = table.naming("subjects");
        let trial_cols = table.naming("trials");
        for row in &table.rows {
            let where_ = format!("{name} row {row:?}");
            assert!(
                !row.iter()
                    .any(|c| c.contains(MARK) || c.contains(&page_token)),
                "what the subject wrote or held survives: {where_}"
            );
            for (col, value) in table.columns.iter().zip(row) {
                if subject_cols.contains(col.as_str()) {
                    assert_ne!(value, &sid, "{col} names the erased subject: {where_}");
                }
                if trial_cols.contains(col.as_str()) {
                    assert!(
                        !trial_ids.contains(value),
                        "{col} names an erased trial: {where_}"
                    );
                }
            }
            if name == "subjects" && table.cell(row, "id") == sid {
                // The row keeps what stops its id, code and index being reused, and the
                // time of the erasure; everything else is gone.
                let kept = [
                    "id",
                    "study_id",
                    "code",
                    "enrol_index",
                    "synthetic",
                    "starting_station",
                ];
                for (col, value) in table.columns.iter().zip(row) {
                    match col.as_str() {
                        c if kept.contains(&c) => {}
                        "token_hash" => assert_eq!(value, &format!("'erased:{sid}'")),
                        "created_at" | "erased_at" => assert_eq!(value, &audit.cell(erasure, "at")),
                        other => assert_eq!(value, "NULL", "{other} of the erased subject"),
                    }
                }
            }
            if name == "audit_log" {
                let detail = json_cell(&table.cell(row, "detail_json"));
                let earlier = audit_before.get(&table.cell(row, "id"));
                let about = earlier.is_some_and(|(target, detail)| {
                    *target == format!("'subject:{sid}'")
                        || trial_ids.iter().any(|t| *target == format!("'trial:{t}'"))
                        || detail["subject_id"] == erased
                });
                if row == erasure {
                    assert_eq!(detail, json!({ "code": code, "reason": reason }));
                    assert_eq!(table.cell(row, "actor"), "'admin'");
                    assert_ne!(table.cell(row, "actor_id"), "NULL");
                } else if about {
                    assert_eq!(detail, marker, "an audit row about the subject: {where_}");
                    redacted += 1;
                } else if let Some((_, was)) = earlier {
                    assert_eq!(&detail, was, "another row's details changed: {where_}");
                } else {
                    assert_ne!(detail, marker, "{where_}");
                }
            }
        }
    }
    assert_eq!(
        redacted,
        report["removed"]["audit_details_redacted"]
            .as_i64()
            .unwrap()
    );
    // Enrolment, assignment, consent, the start and finish of the eleven runs (more when one
    // ran again), ten surveys, the note, the redo and the acceptance.
    assert!(redacted >= 38, "{redacted}");
    // Not in the file's free pages either, nor in the write-ahead log.
    assert!(
        !on_sqlite || !files_hold_mark(&server),
        "the files still hold the erased subject's text"
    );

    // The other subject is untouched; exports and statistics count only them.
    assert_eq!(api.get(&format!("/api/subjects/{kept}")).1, kept_before);
    for kind in ["trials", "subjects", "samples"] {
        assert_eq!(
            codes_in(&export(&api, study, kind)),
            BTreeSet::from([kept_code.clone()]),
            "{kind}"
        );
    }
    assert_eq!(largest_n(&export(&api, study, "summary")), 1);
    let stats = export(&api, study, "stats");
    assert!(largest_n(&stats) <= 1, "{stats:?}");
    for kind in ["notes", "codebook"] {
        assert!(
            !export(&api, study, kind)
                .iter()
                .any(|r| r.iter().any(|c| c.contains(MARK))),
            "{kind}"
        );
    }
    let (_, audit) = api.get_text("/api/audit/export");
    assert!(
        !audit.contains(MARK) && audit.contains("subject.erase"),
        "{audit}"
    );
    let (_, subjects) = api.get(&format!("/api/studies/{study}/subjects"));
    let row = subjects
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["subject"]["id"] == erased)
        .unwrap();
    assert!(row["subject"]["erased_at"].is_i64(), "{row}");
    assert_eq!(
        (row["tests"].as_i64(), row["tests_complete"].as_i64()),
        (Some(0), Some(0))
    );

    // Restoring the backup made before the erasure brings the data back, and the restore
    // says whom to erase again. (Onto a database restored from the backup made after it: a
    // copy of the live one would be held by this running server's heartbeat.)
    let (Some((_, before_erasure)), Some(after_erasure)) = (made_before, after_erasure) else {
        return;
    };
    let restored = TempDir::new("erasure-restored");
    let db = restored.path().join("bdft-lab.db");
    let restore = |backup: &Value| {
        let out = succeeded(
            server_cmd(["restore", "--from"])
                .arg(backups.path().join(backup.as_str().unwrap()))
                .arg("--db")
                .arg(&db),
        );
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        (
            serde_json::from_slice::<Value>(&out.stdout).unwrap(),
            stderr,
        )
    };
    let (first, _) = restore(&after_erasure);
    assert_eq!(first["erasures_undone"], json!([]), "{first}");
    let (again, warned) = restore(&before_erasure);
    let undone = &again["erasures_undone"];
    assert_eq!(undone.as_array().unwrap().len(), 1, "{again}");
    assert_eq!(
        (
            &undone[0]["subject_id"],
            &undone[0]["code"],
            &undone[0]["reason"]
        ),
        (&json!(erased), &json!(code), &json!(reason)),
        "{again}"
    );
    assert!(again["erasures_unchecked"].is_null(), "{again}");
    assert!(
        warned.contains(&format!("the backup predates the erasure of {code}"))
            && warned.contains("erase them again"),
        "{warned}"
    );
}

#[test]
fn erasure_is_refused_to_strangers_bad_reasons_and_a_running_test() {
    let server = Server::start("erasure-refusals");
    let admin = server.experimenter();
    let (_, experimenter) = server.account(&admin, "erin", "experimenter");
    let (_, analyst) = server.account(&admin, "andy", "analyst");
    let study = short_study(&admin, 60.0, 60.0);
    let (subject, _, _) = person_at_a_station(&server, &admin, study);
    let erase = format!("/api/subjects/{subject}/erase");

    for (who, api) in [("experimenter", &experimenter), ("analyst", &analyst)] {
        let (status, body) = api.post(&erase, json!({ "reason": "because" }));
        assert_eq!(status, 403, "{who}: {body}");
        assert!(body["error"].as_str().unwrap().contains("only an admin"));
        assert_eq!(api.get("/api/erasures").0, 403, "{who}");
    }
    let (status, _) = admin.post("/api/subjects/999999/erase", json!({ "reason": "because" }));
    assert_eq!(status, 404);
    // Each refusal names the field that is wrong.
    for (body, named) in [
        (json!({}), "reason"),
        (json!({ "reason": "   " }), "reason"),
        (json!({ "reason": "x".repeat(501) }), "reason"),
        (json!({ "reason": 5 }), "reason"),
        (json!({ "reason": "x", "also": 1 }), "also"),
    ] {
        let (status, err) = admin.post(&erase, body.clone());
        assert_eq!(status, 422, "{body}: {err}");
        assert!(
            err["error"].as_str().unwrap().contains(named),
            "{body}: {err}"
        );
    }

    // A running test: refused until it is stopped.
    let practice = admin.get(&format!("/api/subjects/{subject}")).1["trials"][0]["trial"]["id"]
        .as_i64()
        .unwrap();
    admin.ok(&format!("/api/trials/{practice}/start"), json!({}));
    let (status, body) = admin.post(&erase, json!({ "reason": "because" }));
    assert_eq!(status, 409, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(
        error.contains("running test") && error.contains(&format!("trial {practice}")),
        "{error}"
    );
    admin.ok(
        &format!("/api/trials/{practice}/abort"),
        json!({ "reason": "to erase" }),
    );
    eventually(Duration::from_secs(20), || {
        let (_, s) = admin.get(&format!("/api/subjects/{subject}"));
        (s["trials"][0]["trial"]["status"] != "running").then_some(())
    });
    // Notes racing the erasure: each is filed before it (and erased with it) or refused
    // after it, never a server error.
    let note = format!("/api/trials/{practice}/note");
    let (report, (statuses, refusal)) = std::thread::scope(|s| {
        let racing = s.spawn(|| {
            let mut statuses = Vec::new();
            loop {
                let (status, body) = experimenter.post(&note, json!({ "text": "racing" }));
                statuses.push(status);
                if status != 200 {
                    return (statuses, body);
                }
            }
        });
        let report = admin.ok(&erase, json!({ "reason": "because" }));
        (report, racing.join().unwrap())
    });
    let (last, filed) = statuses.split_last().unwrap();
    assert_eq!(*last, 404, "{refusal}");
    assert_eq!(report["removed"]["notes"], filed.len(), "{report}");
    // The practice, its new attempt (an aborted test is re-queued) and ten tests.
    assert_eq!(report["removed"]["trials"], 12, "{report}");
    // No backup directory: nothing could be checked, and the answer says so.
    assert!(report["backup_dir"].is_null() && report["backups_holding_data"] == json!([]));
}

#[test]
fn in_chromium_an_admin_erases_after_confirming_and_the_study_links_its_package() {
    let BrowserLab {
        server,
        admin,
        study,
        subject,
        code,
        downloads,
        driver,
    } = browser_lab("erasure-browser");
    let code = code.as_str();
    let erased =
        || admin.get(&format!("/api/subjects/{subject}")).1["subject"]["erased_at"].is_i64();

    let dash = dashboard(&driver, &downloads, &server.base, "admin");
    assert!(shown(&dash, "#sec-erasure"), "an admin sees the erasure");
    dash.find(&format!("#erase-subject option[value='{subject}']"));
    dash.choose("#erase-subject", &subject.to_string());
    // No reason, no erasure: the form says what is missing.
    dash.click("#erase-submit");
    dash.wait_until(
        "const s = document.querySelector('#erase-status'); return s.textContent.includes('reason') ? true : null",
        json!([]),
    );
    dash.type_into("#erase-reason", "the subject asked (request 3)");
    // It asks first, naming the subject; Cancel erases nothing.
    dash.click("#erase-submit");
    dash.find("#confirm-dialog");
    assert!(dash.text("#confirm-title").contains(code));
    assert!(dash.text("#confirm-text").contains("cannot be undone"));
    shot(&dash, "erasure-confirm");
    dash.click("#confirm-cancel");
    dash.wait_until(
        "return document.querySelector('#confirm-dialog').open ? null : true",
        json!([]),
    );
    assert!(!erased(), "Cancel does not erase");
    dash.click("#erase-submit");
    dash.find("#confirm-dialog");
    dash.click("#confirm-ok");
    eventually(Duration::from_secs(20), || erased().then_some(()));
    // The erasures list it; the subject list says the data were erased.
    dash.wait_until(
        "const t = document.querySelector('#erasures tbody'); return t && t.textContent.includes(arguments[0]) && t.textContent.includes('request 3') ? true : null",
        json!([code]),
    );
    dash.wait_until(
        "const r = document.querySelector(`#subjects tr[data-subject-id='${arguments[0]}']`); return r && r.textContent.includes('data erased') ? true : null",
        json!([subject]),
    );
    shot(&dash, "erasure-done");

    // The study's ethics-board package: linked, and styled by its stylesheet (the head and
    // foot that carry the hash repeat on printed pages).
    let href = dash.exec(
        "return document.querySelector('#protocol-package').getAttribute('href')",
        json!([]),
    );
    assert_eq!(href, format!("/api/studies/{study}/protocol.html"));
    dash.goto(&format!("{}{}", server.base, href.as_str().unwrap()));
    dash.find("#print");
    assert_eq!(
        dash.exec(
            "return document.querySelectorAll('table.pages .running code.hash').length",
            json!([])
        ),
        2
    );
    assert_eq!(
        dash.exec(
            "return getComputedStyle(document.querySelector('table.pages > tfoot')).display",
            json!([])
        ),
        "table-footer-group"
    );
    shot(&dash, "protocol-package");

    // An analyst sees no erasure.
    let ana = dashboard(&driver, &downloads, &server.base, "ana");
    ana.find("#subjects");
    assert!(!shown(&ana, "#sec-erasure"), "an analyst sees the erasure");
}
