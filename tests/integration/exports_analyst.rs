//! Exports for analysts, on a pilot's data: `valid` and `latest` on every trials row (one
//! latest per test, a redone test too), practice unmistakable, units in the headers, samples
//! with join keys cut per subject or test, the subjects' drawn parameters as columns, a
//! codebook naming every column of every export, no float noise, Parquet equal to the CSV,
//! `simulate --out` with the samples export's record layout, and clear errors for bad
//! kinds, formats and cuts (HTTP and command line).

use std::collections::{BTreeMap, BTreeSet};
use std::process::Output;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float64Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use arrow_schema::DataType;
use bdft_tests::server::{Server, pilot_copy, short_study, with_store};
use bdft_tests::{TempDir, controller, server_command, server_output};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde_json::{Value, json};

use crate::exports_audit::{column, parse_csv};

/// Every export of a study.
const STUDY_KINDS: [&str; 7] = [
    "trials", "samples", "subjects", "codebook", "summary", "stats", "notes",
];

/// The Parquet file's rows as the CSV would write them: numbers parsed back from the CSV
/// must be the stored doubles exactly, text equal (the CSV may add a formula guard `'`).
fn assert_parquet_equals_csv(parquet: &[u8], csv: &[Vec<String>], what: &str) {
    let reader = ParquetRecordBatchReaderBuilder::try_new(bytes_of(parquet))
        .unwrap_or_else(|e| panic!("{what}: not Parquet: {e}"))
        .build()
        .unwrap();
    let batches: Vec<RecordBatch> = reader.map(Result::unwrap).collect();
    let header: Vec<String> = batches
        .first()
        .map(|b| {
            b.schema()
                .fields()
                .iter()
                .map(|f| f.name().clone())
                .collect()
        })
        .unwrap_or_default();
    assert_eq!(header, csv[0], "{what}: the Parquet columns are the CSV's");
    let mut row = 1;
    for b in &batches {
        for i in 0..b.num_rows() {
            for (c, a) in b.columns().iter().enumerate() {
                let cell = &csv[row][c];
                let ctx = || format!("{what} row {row} column {}", csv[0][c]);
                if a.is_null(i) {
                    assert_eq!(cell, "", "{}", ctx());
                    continue;
                }
                match a.data_type() {
                    DataType::Int64 => {
                        assert_eq!(
                            cell,
                            &a.as_primitive::<Int64Type>().value(i).to_string(),
                            "{}",
                            ctx()
                        )
                    }
                    DataType::Float64 => {
                        let v = a.as_primitive::<Float64Type>().value(i);
                        assert_eq!(cell.parse::<f64>().unwrap(), v, "{}", ctx());
                    }
                    DataType::Utf8 => {
                        let v = a.as_string::<i32>().value(i);
                        assert!(
                            cell == v || cell.trim_matches('"') == format!("'{v}"),
                            "{}: {cell:?} vs {v:?}",
                            ctx()
                        );
                    }
                    t => panic!("{}: unexpected type {t}", ctx()),
                }
            }
            row += 1;
        }
    }
    assert_eq!(row, csv.len(), "{what}: as many rows");
}

fn bytes_of(b: &[u8]) -> bytes::Bytes {
    bytes::Bytes::from(b.to_vec())
}

/// The value of `name` in each row.
fn values<'a>(rows: &'a [Vec<String>], name: &str) -> Vec<&'a str> {
    let c = column(rows, name);
    rows[1..].iter().map(|r| r[c].as_str()).collect()
}

/// Writes `drawn_json` of every subject of `study` straight into the server's database
/// (another part of the platform fills it at enrolment; no API writes it).
fn set_drawn(server: &Server, study: i64, drawn: &[(&str, Value)]) {
    with_store(server, async |pool| {
        for (code, value) in drawn {
            sqlx::query("UPDATE subjects SET drawn_json = $1 WHERE study_id = $2 AND code = $3")
                .bind(value.to_string())
                .bind(study)
                .bind(code)
                .execute(pool)
                .await
                .unwrap();
        }
    });
}

#[test]
fn a_pilots_analyst_exports_are_tidy_and_parquet_equals_csv() {
    let server = Server::start("exports-analyst");
    let api = server.experimenter();
    let study = short_study(&api, 1.0, 0.5);
    let copy = pilot_copy(&api, study, 2);
    set_drawn(
        &server,
        copy,
        &[
            (
                "S01",
                json!({ "reaction_delay_s": 0.21, "remnant_ratio": 0.15 }),
            ),
            (
                "S02",
                json!({ "reaction_delay_s": 0.25, "grip_gain_1": 1.5 }),
            ),
        ],
    );
    let get_csv = |path: &str| {
        let (code, text) = api.get_text(path);
        assert_eq!(code, 200, "{path}: {text}");
        parse_csv(&text)
    };
    let export = |kind: &str| format!("/api/studies/{copy}/export/{kind}");

    // A redone test: its first attempt is no longer the latest.
    let trials = get_csv(&export("trials"));
    let (id, slot) = (column(&trials, "trial_id"), column(&trials, "slot"));
    let redone = trials[1..].iter().find(|r| r[slot] == "3").unwrap()[id].clone();
    api.ok(
        &format!("/api/trials/{redone}/redo"),
        json!({ "reason": "retry" }),
    );

    let trials = get_csv(&export("trials"));
    let c = |name| column(&trials, name);
    let mut latest_per_test: BTreeMap<(String, String), usize> = BTreeMap::new();
    for r in &trials[1..] {
        *latest_per_test
            .entry((r[c("subject_code")].clone(), r[c("slot")].clone()))
            .or_default() += usize::from(r[c("latest")] == "1");
        let practice = r[c("phase")] == "practice";
        assert_eq!(
            r[c("phase")],
            if r[c("slot")] == "0" {
                "practice"
            } else {
                "test"
            }
        );
        if practice {
            for test_only in ["controller", "blinded_label", "block", "position"] {
                assert_eq!(r[c(test_only)], "", "practice has no {test_only}: {r:?}");
            }
            assert_eq!(r[c("valid")], "0");
        } else {
            assert!(!r[c("controller")].is_empty());
            let complete = r[c("status")] == "complete";
            assert_eq!(r[c("valid")], if complete { "1" } else { "0" }, "{r:?}");
        }
    }
    assert_eq!(latest_per_test.len(), 2 * 11);
    assert!(
        latest_per_test.values().all(|&n| n == 1),
        "{latest_per_test:?}"
    );
    let attempts: Vec<&Vec<String>> = trials[1..]
        .iter()
        .filter(|r| r[c("slot")] == "3" && r[c("subject_code")] == "S01")
        .collect();
    assert_eq!(attempts.len(), 2);
    assert_eq!(
        (
            attempts[0][c("latest")].as_str(),
            attempts[1][c("latest")].as_str()
        ),
        ("0", "1")
    );
    assert_eq!(attempts[1][c("valid")], "0", "the redo has not run");
    // Units in the metric headers, the ratings on the study's scale.
    for h in [
        "mse_tracking_mm2",
        "ms_cab_accel_mm2_s4",
        "rating_accuracy_1to7",
        "target_mean_mm",
    ] {
        column(&trials, h);
    }

    // The codebook names every column of every export, with its type and resolution.
    let book = get_csv(&export("codebook"));
    let (kind_col, name_col) = (column(&book, "export"), column(&book, "column"));
    let resolution: BTreeMap<(String, String), String> = book[1..]
        .iter()
        .map(|r| {
            (
                (r[kind_col].clone(), r[name_col].clone()),
                r[column(&book, "resolution")].clone(),
            )
        })
        .collect();
    let mut exported: BTreeMap<&str, Vec<Vec<String>>> = BTreeMap::new();
    for kind in STUDY_KINDS {
        let rows = get_csv(&export(kind));
        for h in &rows[0] {
            assert!(
                resolution.contains_key(&(kind.to_string(), h.clone())),
                "{kind}.{h} not in the codebook"
            );
        }
        exported.insert(kind, rows);
    }
    let (code, audit) = api.get_text("/api/audit/export");
    assert_eq!(code, 200);
    for h in &parse_csv(&audit)[0] {
        assert!(
            resolution.contains_key(&("audit".to_string(), h.clone())),
            "audit.{h}"
        );
    }

    // No float noise: a number is never finer than its column's resolution (4.7e-16 → 0).
    for (kind, rows) in &exported {
        for (j, h) in rows[0].iter().enumerate() {
            let Some(step) = resolution[&(kind.to_string(), h.clone())]
                .parse::<f64>()
                .ok()
            else {
                continue;
            };
            for r in &rows[1..] {
                let Ok(x) = r[j].parse::<f64>() else { continue };
                assert!(
                    x == 0.0 || x.abs() >= step * 0.5,
                    "{kind}.{h} = {}: finer than {step}",
                    r[j]
                );
                assert!(!r[j].contains('e') && r[j] != "-0", "{kind}.{h} = {}", r[j]);
            }
        }
    }
    assert!(
        values(&trials, "target_mean_mm")
            .iter()
            .all(|m| m.parse::<f64>().unwrap().abs() < 1.0)
    );

    // Subjects: one row each, the drawn parameters as sorted columns, the valid tests counted.
    let subjects = &exported["subjects"];
    let drawn: Vec<&str> = subjects[0]
        .iter()
        .filter(|h| h.starts_with("drawn."))
        .map(String::as_str)
        .collect();
    assert_eq!(
        drawn,
        [
            "drawn.grip_gain_1",
            "drawn.reaction_delay_s",
            "drawn.remnant_ratio"
        ]
    );
    assert_eq!(values(subjects, "subject_code"), ["S01", "S02"]);
    assert_eq!(values(subjects, "drawn.reaction_delay_s"), ["0.21", "0.25"]);
    assert_eq!(values(subjects, "drawn.grip_gain_1"), ["", "1.5"]);
    assert_eq!(values(subjects, "synthetic"), ["1", "1"]);
    for (i, code) in ["S01", "S02"].iter().enumerate() {
        let counted = trials[1..]
            .iter()
            .filter(|r| {
                r[c("subject_code")] == *code && r[c("valid")] == "1" && r[c("latest")] == "1"
            })
            .count();
        assert_eq!(values(subjects, "valid_tests")[i], counted.to_string());
        let order = values(subjects, "order")[i];
        assert!(
            order.starts_with("on: ") || order.starts_with("off: "),
            "{order}"
        );
        assert_eq!(order.matches(" > ").count(), 2 * 4, "{order}");
    }

    // Samples with their join keys; cut per subject and per test: exactly those rows.
    let all = &exported["samples"];
    let keys = [
        "study_id",
        "subject_code",
        "trial_id",
        "phase",
        "station",
        "controller",
        "attempt",
    ];
    assert_eq!(all[0][..7], keys);
    assert_eq!(all[0][7], "t_s");
    assert!(
        values(all, "study_id")
            .iter()
            .all(|s| *s == copy.to_string())
    );
    let s01 = get_csv(&format!("{}?subject=S01", export("samples")));
    let expected: Vec<&Vec<String>> = all[1..]
        .iter()
        .filter(|r| r[column(all, "subject_code")] == "S01")
        .collect();
    assert_eq!(s01[1..].iter().collect::<Vec<_>>(), expected);
    let one_test = trials[1..]
        .iter()
        .find(|r| r[c("phase")] == "test")
        .unwrap()[c("trial_id")]
    .clone();
    let cut = get_csv(&format!("{}?trial={one_test}", export("samples")));
    let expected: Vec<&Vec<String>> = all[1..]
        .iter()
        .filter(|r| r[column(all, "trial_id")] == one_test)
        .collect();
    assert_eq!(cut.len() - 1, 1000, "1 s at 1 kHz");
    assert_eq!(cut[1..].iter().collect::<Vec<_>>(), expected);
    assert!(values(all, "phase").contains(&"practice"));
    let practice_controllers: BTreeSet<&str> = all[1..]
        .iter()
        .filter(|r| r[column(all, "phase")] == "practice")
        .map(|r| r[column(all, "controller")].as_str())
        .collect();
    assert_eq!(practice_controllers, BTreeSet::from([""]));

    // Parquet: the same rows and numbers as the CSV, for every export.
    for kind in STUDY_KINDS {
        let (code, bytes) = api.get_bytes(&format!("{}?format=parquet", export(kind)));
        assert_eq!(code, 200, "{kind}: {}", String::from_utf8_lossy(&bytes));
        assert_parquet_equals_csv(&bytes, &exported[kind], kind);
    }
    let (_, bytes) = api.get_bytes(&format!("{}.parquet?subject=S01", export("samples")));
    assert_parquet_equals_csv(&bytes, &s01, "samples of S01");

    // Bad kinds, formats and cuts: 422 with a message naming the field and what is allowed.
    let refused = |path: &str, field: &str, allowed: &str| {
        let (code, body) = api.get(path);
        assert_eq!(code, 422, "{path}: {body}");
        let msg = body["error"]
            .as_str()
            .unwrap_or_else(|| panic!("{path}: {body}"));
        assert!(
            msg.starts_with(field) && msg.contains(allowed),
            "{path}: {msg}"
        );
    };
    refused(
        &export("sample"),
        "kind:",
        "trials, samples, subjects, codebook",
    );
    refused(
        &format!("{}?format=xlsx", export("trials")),
        "format:",
        "csv, parquet",
    );
    refused(
        &format!("{}?subject=S99", export("samples")),
        "subject:",
        "S01, S02",
    );
    refused(
        &format!("{}?trial=abc", export("samples")),
        "trial:",
        "whole number",
    );
    refused(
        &format!("{}?trial=999999", export("samples")),
        "trial:",
        "recorded test",
    );
    refused(
        &format!("{}?subject=S01", export("trials")),
        "subject, trial:",
        "samples",
    );
    refused(
        &format!("{}?subject=S01&trial={one_test}", export("samples")),
        "subject, trial:",
        "not both",
    );
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn the_command_line_cuts_samples_and_simulate_writes_the_same_record_layout() {
    let dir = TempDir::new("exports-cli");
    let db = dir.path().join("pilot.db");
    let db = db.to_str().unwrap();
    server_command(["pilot", "--db", db, "--subjects", "1", "--seed", "5"]);
    let export = |args: &[&str], file: &str| {
        let path = dir.path().join(file);
        let mut all = vec!["export", "--db", db, "--out", path.to_str().unwrap()];
        all.extend(args);
        server_command(&all);
        std::fs::read(path).unwrap()
    };
    let trials =
        parse_csv(&String::from_utf8(export(&["--kind", "trials"], "trials.csv")).unwrap());
    let c = |name| column(&trials, name);
    let test = trials[1..]
        .iter()
        .find(|r| r[c("phase")] == "test")
        .unwrap();
    let (trial, seed, compensator, seat) = (
        test[c("trial_id")].clone(),
        test[c("seed")].clone(),
        test[c("controller")].clone(),
        test[c("station")].clone(),
    );
    let samples = parse_csv(
        &String::from_utf8(export(&["--kind", "samples", "--trial", &trial], "one.csv")).unwrap(),
    );
    assert!(values(&samples, "trial_id").iter().all(|t| *t == trial));
    assert_eq!(samples.len() - 1, 140_000, "140 s at 1 kHz");
    let parquet = export(
        &[
            "--kind", "samples", "--trial", &trial, "--format", "parquet",
        ],
        "one.parquet",
    );
    assert_parquet_equals_csv(&parquet, &samples, "samples --trial");
    // All of S01's samples (1.4 M rows: counted line by line, not parsed into cells).
    let mine = String::from_utf8(export(
        &["--kind", "samples", "--subject", "S01"],
        "s01.csv",
    ))
    .unwrap();
    let mut lines = mine.lines();
    assert_eq!(lines.next(), Some(samples[0].join(",").as_str()));
    let at = column(&samples, "trial_id");
    let mut per_trial = std::collections::BTreeMap::<String, usize>::new();
    for l in lines {
        assert_eq!(l.split(',').nth(1), Some("S01"), "{l}");
        let id = l.split(',').nth(at).unwrap_or_default().to_string();
        *per_trial.entry(id).or_default() += 1;
    }
    // Every attempt of S01 is there: a completed one with its whole length at 1 kHz, one the
    // interlock stopped with what it recorded before (the pilot's riders can shake the LQR
    // into it, as the thesis lost 2 of its 80 tests).
    assert_eq!(per_trial.len(), trials.len() - 1, "{per_trial:?}");
    for r in &trials[1..] {
        let planned = (r[c("duration_s")].parse::<f64>().unwrap() * 1000.0).round() as usize;
        let n = per_trial[&r[c("trial_id")]];
        if r[c("status")] == "complete" {
            assert_eq!(n, planned, "trial {}", r[c("trial_id")]);
        } else {
            assert!(
                0 < n && n < planned,
                "trial {} ({}): {n}",
                r[c("trial_id")],
                r[c("status")]
            );
        }
    }

    // `simulate --out` of the same compensator, seat and seed: the samples export's record
    // columns (same names, units, order) in the same number format.
    let sim = dir.path().join("sim.csv");
    let out = controller(&[
        "simulate",
        "--compensator",
        &compensator,
        "--signal",
        "steps",
        "--station",
        &seat,
        "--seed",
        &seed,
        "--duration",
        "20",
        "--out",
        sim.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let sim = parse_csv(&std::fs::read_to_string(&sim).unwrap());
    let shared = &samples[0][7..];
    assert_eq!(sim[0], shared, "the record's columns");
    let book =
        parse_csv(&String::from_utf8(export(&["--kind", "codebook"], "codebook.csv")).unwrap());
    for (j, name) in shared.iter().enumerate() {
        let entry = book[1..]
            .iter()
            .find(|r| {
                r[column(&book, "export")] == "samples" && r[column(&book, "column")] == *name
            })
            .unwrap();
        let decimals = entry[column(&book, "resolution")]
            .split_once('.')
            .map_or(0, |(_, d)| d.len());
        // Both writers print a value with at most the column's decimals, without trailing
        // zeros, exponents or a negative zero.
        for (what, rows) in [("simulate", &sim), ("export", &samples)] {
            for r in &rows[1..] {
                let v = &r[7 * usize::from(what == "export") + j];
                let places = v.split_once('.').map_or(0, |(_, d)| d.len());
                let trailing = v.contains('.') && (v.ends_with('0') || v.ends_with('.'));
                let odd = v.contains('e') || v == "-0" || trailing;
                assert!(places <= decimals && !odd, "{what} {name} = {v:?}");
            }
        }
    }

    // Bad values: exit code 2 and a message listing what is allowed.
    let path = dir.path().join("bad.csv");
    let out_arg = path.to_str().unwrap();
    for (args, expected) in [
        (
            vec!["--kind", "sample"],
            "trials, samples, subjects, codebook, summary, stats, notes, identification, audit",
        ),
        (vec!["--kind", "trials", "--format", "xlsx"], "csv, parquet"),
        (
            vec!["--kind", "samples", "--subject", "S99"],
            "allowed: S01",
        ),
        (
            vec!["--kind", "trials", "--subject", "S01"],
            "only the samples export",
        ),
    ] {
        let mut all = vec!["export", "--db", db, "--out", out_arg];
        all.extend(&args);
        let out = server_output(&all);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(
            stderr(&out).contains(expected),
            "{args:?}: {}",
            stderr(&out)
        );
        assert!(!path.exists(), "no file for a refused export");
    }
}
