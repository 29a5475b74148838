//! The checks at the end of a soak: the journal against the exports (`bdft-server export`:
//! trials, subjects, samples) and the audit log; the database's integrity; the server's
//! memory and descriptors at the end against the baseline; the server's log free of panics.
//! Every broken rule is a violation; the figures describe the run.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use super::journal::Journal;
use super::plan::FaultKind;
use super::{Soak, disk};
use crate::exports::parse_csv;

/// What the soak's end says: every broken rule, and the run's figures.
#[derive(Debug)]
pub struct Verdict {
    pub violations: Vec<String>,
    pub figures: Value,
    /// The run's directory (database, server log, journal, exports), when it was kept.
    pub kept: Option<PathBuf>,
}

impl Verdict {
    pub fn passed(&self) -> bool {
        self.violations.is_empty()
    }
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}",
            serde_json::to_string_pretty(&self.figures).unwrap_or_default()
        )?;
        if let Some(dir) = &self.kept {
            writeln!(f, "kept: {}", dir.display())?;
        }
        if self.violations.is_empty() {
            return writeln!(f, "soak passed: no violation");
        }
        writeln!(f, "soak FAILED: {} violation(s)", self.violations.len())?;
        for v in &self.violations {
            writeln!(f, "  - {v}")?;
        }
        Ok(())
    }
}

/// A CSV export as rows of column → cell.
type Rows = Vec<HashMap<String, String>>;

/// How much the server's resident memory may grow from the baseline to the end: the
/// allocator keeps freed memory, and each of the 8 database connections a page cache of up
/// to 2 MiB, so growth below this is no leak.
const RSS_SLACK_KIB: u64 = 32 * 1024;
/// The most database descriptors the server's pool may hold: 8 connections, each with the
/// file and its WAL, and the shared memory.
const DATABASE_FDS: usize = 2 * 8 + 1;
/// Of the complete tests, the records of at most this many are read back in full.
const RECORDS_CHECKED: usize = 40;

pub(super) fn verify(soak: Soak) -> Verdict {
    let journal = std::sync::Arc::clone(&soak.journal);
    let mut v: Vec<String> = Vec::new();
    let dir = soak.server.dir.path().to_path_buf();
    let db = soak.server.db.clone();
    match disk::integrity(&db) {
        Ok(problems) => v.extend(problems.into_iter().map(|p| format!("database: {p}"))),
        Err(e) => v.push(e),
    }
    let exported = |kind: &str| export(&db, &dir, soak.study, kind, &[]);
    let (trials, subjects, audit) =
        match (exported("trials"), exported("subjects"), exported("audit")) {
            (Ok(t), Ok(s), Ok(a)) => (t, s, a),
            (t, s, a) => {
                v.extend([t.err(), s.err(), a.err()].into_iter().flatten());
                return finish(soak, v, json!({}));
            }
        };
    let mut figures = soak.figures();
    check_trials(&journal, &trials, &mut v, &mut figures);
    check_answers(&journal, &trials, &subjects, &mut v);
    check_audit(&trials, &audit, &journal, &mut v);
    check_records(&db, &dir, soak.study, &trials, soak.config.seed, &mut v);
    check_faults(&journal, &trials, &mut v, &mut figures);
    check_resources(&soak, &mut v, &mut figures);
    if let Some(log) = soak.server.log() {
        check_log(log, &mut v);
    }
    v.extend(
        journal
            .of("violation")
            .iter()
            .map(|e| e["what"].as_str().unwrap_or_default().to_string()),
    );
    soak.journal.flush();
    finish(soak, v, figures)
}

fn finish(soak: Soak, violations: Vec<String>, figures: Value) -> Verdict {
    let keep = soak.config.keep || !violations.is_empty();
    let Soak { server, .. } = soak;
    let kept = keep.then(|| server.dir.keep());
    Verdict {
        violations,
        figures,
        kept,
    }
}

/// `bdft-server export --kind KIND` of the study as rows (the CSV kept in the run's
/// directory).
fn export(db: &Path, dir: &Path, study: i64, kind: &str, extra: &[&str]) -> Result<Rows, String> {
    let name = format!("{kind}{}.csv", extra.join("-"));
    let out = dir.join(&name);
    let run = crate::server_cmd(["export", "--db"])
        .arg(db)
        .args(["--study", &study.to_string(), "--kind", kind, "--out"])
        .arg(&out)
        .args(extra)
        .output()
        .map_err(|e| format!("export {kind}: {e}"))?;
    if !run.status.success() {
        return Err(format!(
            "export {kind} failed: {}",
            String::from_utf8_lossy(&run.stderr)
        ));
    }
    let text = std::fs::read_to_string(&out).map_err(|e| format!("{name}: {e}"))?;
    let mut rows = parse_csv(&text).into_iter();
    let header = rows.next().unwrap_or_default();
    Ok(rows
        .map(|r| header.iter().cloned().zip(r).collect())
        .collect())
}

fn cell<'a>(row: &'a HashMap<String, String>, column: &str) -> &'a str {
    row.get(column).map_or("", String::as_str)
}

fn id_of(row: &HashMap<String, String>) -> i64 {
    cell(row, "trial_id").parse().unwrap_or(-1)
}

/// Whether the attempt ran (it has a start time).
fn ran(row: &HashMap<String, String>) -> bool {
    !cell(row, "started_at").is_empty()
}

/// `2026-11-22T07:03:24.650Z` → ms since the Unix epoch.
fn epoch_ms(text: &str) -> Option<i64> {
    let num = |r: std::ops::Range<usize>| text.get(r)?.parse::<i64>().ok();
    let (y, m, d) = (num(0..4)?, num(5..7)?, num(8..10)?);
    let (h, min, s, ms) = (num(11..13)?, num(14..16)?, num(17..19)?, num(20..23)?);
    // Days from 1970-01-01 to y-m-d (proleptic Gregorian; Howard Hinnant's algorithm).
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    Some((((days * 24 + h) * 60 + min) * 60 + s) * 1000 + ms)
}

/// The journal's answers to requests about `key` (e.g. trial.start by trial): 200, another
/// status, or null (unknown whether the server acted).
fn answers(journal: &Journal, event: &str, key: &str) -> HashMap<i64, Vec<Value>> {
    let mut by: HashMap<i64, Vec<Value>> = HashMap::new();
    for e in journal.of(event) {
        if let Some(k) = e[key].as_i64() {
            by.entry(k).or_default().push(e);
        }
    }
    by
}

fn ok(e: &Value) -> bool {
    e["status"] == 200
}

fn unknown(e: &Value) -> bool {
    e["status"].is_null()
}

/// Every test filed with a status and reason; attempts whole; starts as the journal says.
fn check_trials(journal: &Journal, trials: &Rows, v: &mut Vec<String>, figures: &mut Value) {
    let mut seen = HashSet::new();
    let mut by_test: BTreeMap<(String, String), Vec<(i64, bool)>> = BTreeMap::new();
    let mut statuses: BTreeMap<String, usize> = BTreeMap::new();
    for row in trials {
        let id = id_of(row);
        if !seen.insert(id) {
            v.push(format!("trial {id} appears twice in the trials export"));
        }
        let status = cell(row, "status");
        *statuses.entry(status.to_string()).or_insert(0) += 1;
        if status == "running" {
            v.push(format!("trial {id} is still running at the end"));
        }
        if ran(row) {
            if !["complete", "aborted", "incomplete", "invalid"].contains(&status) {
                v.push(format!("trial {id} ran but is filed {status:?}"));
            }
            if status != "complete" && cell(row, "status_reason").trim().is_empty() {
                v.push(format!("trial {id} is filed {status} without a reason"));
            }
        }
        by_test
            .entry((
                cell(row, "subject_code").to_string(),
                cell(row, "slot").to_string(),
            ))
            .or_default()
            .push((
                cell(row, "attempt").parse().unwrap_or(-1),
                cell(row, "latest") == "1",
            ));
    }
    for ((subject, slot), mut attempts) in by_test {
        attempts.sort();
        let numbers: Vec<i64> = attempts.iter().map(|a| a.0).collect();
        if numbers != (1..=numbers.len() as i64).collect::<Vec<_>>() {
            v.push(format!(
                "{subject}'s test {slot} has attempts {numbers:?}, not 1..n"
            ));
        }
        let latest: Vec<i64> = attempts.iter().filter(|a| a.1).map(|a| a.0).collect();
        if latest != [*numbers.last().unwrap_or(&0)] {
            v.push(format!(
                "{subject}'s test {slot}: latest flags on attempts {latest:?} of {numbers:?}"
            ));
        }
    }
    // Starts: what ran was started by the soak, and what the server said it started ran.
    let starts = answers(journal, "trial.start", "trial");
    let rows: HashMap<i64, &HashMap<String, String>> =
        trials.iter().map(|r| (id_of(r), r)).collect();
    // A start the controller's loss interrupted is refused, yet filed (incomplete) as run.
    let filed_anyway = |e: &Value| {
        e["error"]
            .as_str()
            .is_some_and(|m| m.contains("filed incomplete"))
    };
    for (id, row) in &rows {
        if ran(row)
            && !starts
                .get(id)
                .is_some_and(|a| a.iter().any(|e| ok(e) || unknown(e) || filed_anyway(e)))
        {
            v.push(format!(
                "trial {id} ran, but the soak never started it (or was told it did not start)"
            ));
        }
    }
    for (id, attempts) in &starts {
        let started = attempts.iter().filter(|e| ok(e)).count();
        if started > 1 {
            v.push(format!("trial {id} was started {started} times"));
        }
        if started == 1 && !rows.get(id).is_some_and(|r| ran(r)) {
            v.push(format!(
                "trial {id} was started (200) but the export has no start for it"
            ));
        }
    }
    // Accepted as incomplete: the reason is kept.
    for (id, a) in answers(journal, "trial.accept_incomplete", "trial") {
        if a.iter().any(ok)
            && rows
                .get(&id)
                .is_none_or(|r| cell(r, "accepted_reason").is_empty())
        {
            v.push(format!(
                "trial {id} was accepted as incomplete but the export has no reason"
            ));
        }
    }
    let subjects_done = {
        let mut per: HashMap<&str, (usize, usize)> = HashMap::new();
        for row in trials {
            if cell(row, "latest") == "1" {
                let e = per.entry(cell(row, "subject_code")).or_default();
                e.0 += 1;
                if cell(row, "status") != "scheduled" {
                    e.1 += 1;
                }
            }
        }
        per.values().filter(|(all, done)| all == done).count()
    };
    let complete = statuses.get("complete").copied().unwrap_or(0);
    figures["trials"] = json!({
        "attempts": trials.len(),
        "ran": trials.iter().filter(|r| ran(r)).count(),
        "by_status": statuses,
        "starts_answered_200": starts.values().flatten().filter(|e| ok(e)).count(),
        "starts_refused": starts.values().flatten().filter(|e| !ok(e) && !unknown(e)).count(),
        "starts_unknown": starts.values().flatten().filter(|e| unknown(e)).count(),
        "subjects_through_the_whole_schedule": subjects_done,
    });
    if complete < 10 {
        v.push(format!(
            "only {complete} tests completed: the soak did not exercise the lab"
        ));
    }
}

/// Surveys, timing figures and consent: what the soak sent is what the exports hold, once.
fn check_answers(journal: &Journal, trials: &Rows, subjects: &Rows, v: &mut Vec<String>) {
    let rows: HashMap<i64, &HashMap<String, String>> =
        trials.iter().map(|r| (id_of(r), r)).collect();
    let surveys = answers(journal, "survey", "trial");
    let rating = |row: &HashMap<String, String>, key: &str| -> Option<i64> {
        row.iter()
            .find(|(k, _)| k.starts_with(&format!("rating_{key}_1to")))
            .and_then(|(_, c)| c.parse().ok())
    };
    let keys = ["accuracy", "speed", "smoothness", "controllability"];
    let matches = |row: &HashMap<String, String>, sent: &Value| {
        keys.iter()
            .all(|k| rating(row, k) == sent["answers"][k].as_i64())
            && cell(row, "comment") == sent["answers"]["comment"].as_str().unwrap_or("")
    };
    for (id, row) in &rows {
        let stored = rating(row, "accuracy").is_some();
        let sent = surveys.get(id).map(Vec::as_slice).unwrap_or(&[]);
        if sent.iter().any(ok) && !stored {
            v.push(format!(
                "the survey of trial {id} was answered (200) but is not in the export"
            ));
        }
        if stored
            && !sent
                .iter()
                .any(|e| (ok(e) || unknown(e)) && matches(row, e))
        {
            v.push(format!(
                "trial {id}'s survey in the export is not one the soak sent and was told was stored"
            ));
        }
    }
    let timing = answers(journal, "timing", "trial");
    for (id, row) in &rows {
        let frames = cell(row, "display_frames");
        let sent = timing.get(id).map(Vec::as_slice).unwrap_or(&[]);
        if sent.iter().any(ok) && frames.is_empty() {
            v.push(format!(
                "trial {id}'s display timing was stored (200) but is not in the export"
            ));
        }
        if !frames.is_empty()
            && !sent.iter().any(|e| {
                (ok(e) || unknown(e))
                    && e["frames"].as_u64().map(|f| f.to_string()) == Some(frames.to_string())
            })
        {
            v.push(format!(
                "trial {id}'s display frames {frames} in the export are none the soak reported"
            ));
        }
    }
    // Consent: the subjects export holds each subject's decision as the soak gave it.
    let mut decided: HashMap<String, Vec<Value>> = HashMap::new();
    for e in journal.of("consent") {
        if let Some(code) = e["subject"].as_str() {
            decided.entry(code.to_string()).or_default().push(e);
        }
    }
    for row in subjects {
        let code = cell(row, "subject_code");
        let stored = cell(row, "consent_decision");
        let sent = decided.get(code).map(Vec::as_slice).unwrap_or(&[]);
        let agrees = |e: &Value| e["decision"].as_str() == Some(stored);
        if !stored.is_empty() && !sent.iter().any(|e| (ok(e) || unknown(e)) && agrees(e)) {
            v.push(format!(
                "{code}'s consent {stored:?} in the export is not what the soak answered"
            ));
        }
        if sent.iter().any(ok) && stored.is_empty() {
            v.push(format!(
                "{code} consented (200) but the export has no decision"
            ));
        }
    }
}

/// The audit log: each trial that ran started once (a start the controller refused and the
/// server undid does not count), ended once (its result, or an interruption), and each
/// stored survey has its row.
fn check_audit(trials: &Rows, audit: &Rows, journal: &Journal, v: &mut Vec<String>) {
    let mut starts: HashMap<i64, i64> = HashMap::new();
    let mut ends: HashMap<i64, i64> = HashMap::new();
    let mut surveys: HashMap<i64, i64> = HashMap::new();
    let mut consents: HashMap<i64, i64> = HashMap::new();
    let target = |row: &HashMap<String, String>, kind: &str| -> Option<i64> {
        cell(row, "target")
            .strip_prefix(&format!("{kind}:"))
            .and_then(|n| n.parse().ok())
    };
    for row in audit {
        match cell(row, "action") {
            "trial.start" => {
                *starts
                    .entry(target(row, "trial").unwrap_or(-1))
                    .or_default() += 1
            }
            "trial.start_failed" => {
                *starts
                    .entry(target(row, "trial").unwrap_or(-1))
                    .or_default() -= 1
            }
            "trial.finish" => *ends.entry(target(row, "trial").unwrap_or(-1)).or_default() += 1,
            "trial.interrupt" => {
                let detail: Value = serde_json::from_str(cell(row, "detail")).unwrap_or_default();
                for id in detail["trials"].as_array().into_iter().flatten() {
                    *ends.entry(id.as_i64().unwrap_or(-1)).or_default() += 1;
                }
            }
            "survey.submit" => {
                *surveys
                    .entry(target(row, "trial").unwrap_or(-1))
                    .or_default() += 1
            }
            "consent" => {
                *consents
                    .entry(target(row, "subject").unwrap_or(-1))
                    .or_default() += 1
            }
            _ => {}
        }
    }
    for row in trials {
        let id = id_of(row);
        let (s, e) = (
            starts.get(&id).copied().unwrap_or(0),
            ends.get(&id).copied().unwrap_or(0),
        );
        let expected = i64::from(ran(row));
        if s != expected {
            v.push(format!(
                "the audit log has {s} start(s) (less failed ones) of trial {id}, which {}",
                if ran(row) { "ran" } else { "never ran" }
            ));
        }
        if e != expected {
            v.push(format!(
                "the audit log ends trial {id} {e} time(s); it {}",
                if ran(row) { "ran once" } else { "never ran" }
            ));
        }
        let stored = row
            .keys()
            .any(|k| k.starts_with("rating_accuracy") && !cell(row, k).is_empty());
        let n = surveys.get(&id).copied().unwrap_or(0);
        if n != i64::from(stored) {
            v.push(format!(
                "the audit log has {n} survey row(s) of trial {id}, whose survey is {}stored",
                if stored { "" } else { "not " }
            ));
        }
    }
    // Consent rows by subject id (the journal's enrolments name id and code).
    for e in journal.of("subject.enrol") {
        let Some(id) = e["subject"].as_i64() else {
            continue;
        };
        let code = e["code"].as_str().unwrap_or_default();
        let answered = journal
            .of("consent")
            .iter()
            .any(|c| c["subject"] == code && ok(c));
        let n = consents.get(&id).copied().unwrap_or(0);
        if n > 1 || (answered && n != 1) {
            v.push(format!("the audit log has {n} consent row(s) of {code}"));
        }
    }
}

/// The records of complete tests are whole: as many samples as the test's length at 1 kHz.
fn check_records(db: &Path, dir: &Path, study: i64, trials: &Rows, seed: u64, v: &mut Vec<String>) {
    let mut complete: Vec<&HashMap<String, String>> = trials
        .iter()
        .filter(|r| cell(r, "status") == "complete")
        .collect();
    // A seeded sample when there are many.
    let mut rng = bdft_controller::rng::Rng::derive(seed, 0x2ec0);
    while complete.len() > RECORDS_CHECKED {
        let i = (rng.next_u64() % complete.len() as u64) as usize;
        complete.swap_remove(i);
    }
    for row in complete {
        let id = id_of(row);
        let want =
            (cell(row, "duration_s").parse::<f64>().unwrap_or(0.0) * 1000.0).round() as usize;
        match export(db, dir, study, "samples", &["--trial", &id.to_string()]) {
            Ok(samples) if samples.len() == want => {}
            Ok(samples) => v.push(format!(
                "complete trial {id} has {} samples, not {want}",
                samples.len()
            )),
            Err(e) => v.push(e),
        }
    }
}

/// What each fault did to the tests it hit.
fn check_faults(journal: &Journal, trials: &Rows, v: &mut Vec<String>, figures: &mut Value) {
    let rows: HashMap<i64, &HashMap<String, String>> =
        trials.iter().map(|r| (id_of(r), r)).collect();
    let faults = journal.of("fault");
    // When each controller fault's signal had surely landed: kill(1) had returned.
    let signalled: HashMap<i64, i64> = journal
        .of("fault.outcome")
        .iter()
        .filter_map(|o| Some((o["n"].as_i64()?, o["signalled_wall_ms"].as_i64()?)))
        .collect();
    let mut hit: HashSet<i64> = HashSet::new();
    let mut by_kind: BTreeMap<&str, BTreeMap<String, usize>> = BTreeMap::new();
    for kind in FaultKind::ALL {
        if !faults.iter().any(|f| f["kind"] == kind.name()) {
            v.push(format!("no {} fault was injected", kind.name()));
        }
    }
    for f in &faults {
        let kind = f["kind"].as_str().unwrap_or_default();
        let at = f["wall_ms"].as_i64().unwrap_or(0);
        for a in f["affected"].as_array().into_iter().flatten() {
            let id = a["trial"].as_i64().unwrap_or(-1);
            hit.insert(id);
            let Some(row) = rows.get(&id) else { continue };
            let status = cell(row, "status");
            let reason = cell(row, "status_reason");
            let kind_key = FaultKind::ALL
                .into_iter()
                .find(|k| k.name() == kind)
                .map_or("?", |k| k.name());
            *by_kind
                .entry(kind_key)
                .or_default()
                .entry(status.to_string())
                .or_insert(0) += 1;
            let ends_at = a["ends_at"].as_i64().unwrap_or(0);
            let started = epoch_ms(cell(row, "started_at")).unwrap_or(0);
            let (from, to) = (
                f["window_ms"][0].as_i64().unwrap_or(at),
                f["window_ms"][1].as_i64().unwrap_or(at),
            );
            // How long the fault overlapped the test's planned run.
            let overlap = to.min(ends_at) - from.max(started);
            let bad = match kind {
                "controller-kill" | "controller-stop" | "server-restart" => {
                    // A test may end whole before the signal lands: judged from the moment
                    // it had surely landed, a complete filing needs its end before that.
                    let lost_at = f["n"]
                        .as_i64()
                        .and_then(|n| signalled.get(&n).copied())
                        .unwrap_or(at);
                    (status == "complete" && ends_at - lost_at > 500).then(|| {
                        format!(
                            "filed complete though its {} was lost {} ms before its planned end",
                            if kind == "server-restart" {
                                "server"
                            } else {
                                "controller"
                            },
                            ends_at - lost_at
                        )
                    })
                }
                "station-reload" | "station-offline" => (status == "complete" && overlap > 600)
                    .then(|| {
                        format!(
                            "filed complete though its station sent no input for {overlap} ms of it"
                        )
                    }),
                "store-held" => {
                    (status != "complete" && reason.contains("controller lost")).then(|| {
                        "filed as lost with its controller while the store was held".to_string()
                    })
                }
                "station-hidden" => (status == "complete" && overlap > 1200).then(|| {
                    format!("filed complete though its page was hidden for {overlap} ms of it")
                }),
                // Another address's slow clients must not cost a test of the lab's.
                "slow-clients" => (status != "complete").then(|| {
                    format!(
                        "not filed complete while another address held slow bodies ({overlap} ms of it)"
                    )
                }),
                _ => None,
            };
            if let Some(why) = bad {
                v.push(format!("trial {id} ({kind}): {why} [{status}: {reason}]"));
            }
        }
    }
    // Tests stopped without a fault aimed at them: what the load did, reported.
    let mut collateral: BTreeMap<String, usize> = BTreeMap::new();
    for row in trials.iter().filter(|r| ran(r) && !hit.contains(&id_of(r))) {
        let status = cell(row, "status");
        if status != "complete" {
            let reason = cell(row, "status_reason");
            // The reason without its numbers, so that like reasons count together.
            let kind: String = reason
                .chars()
                .map(|c| if c.is_ascii_digit() { '#' } else { c })
                .collect();
            *collateral.entry(format!("{status}: {kind}")).or_insert(0) += 1;
        }
    }
    let mut injected: BTreeMap<&str, usize> = BTreeMap::new();
    for f in &faults {
        *injected
            .entry(f["kind"].as_str().unwrap_or("?"))
            .or_insert(0) += 1;
    }
    figures["faults"] = json!({
        "injected": injected,
        "tests_hit_by_kind": by_kind,
        "other_tests_stopped": collateral,
        "outcomes": journal.of("fault.outcome"),
    });
}

/// Memory and descriptors at the end's quiet point against the baseline's.
fn check_resources(soak: &Soak, v: &mut Vec<String>, figures: &mut Value) {
    let find = |label: &str| soak.quiet.iter().find(|q| q.0 == label);
    let (Some(base), Some(end)) = (find("baseline"), find("end")) else {
        v.push("no baseline or end quiet point to compare".into());
        return;
    };
    figures["resources"] = json!({
        "baseline": { "rss_kib": base.2, "fds": base.3 },
        "end": { "rss_kib": end.2, "fds": end.3 },
        "rss_slack_kib": RSS_SLACK_KIB,
    });
    if base.1 != end.1 {
        v.push(format!(
            "the server process changed between the baseline ({}) and the end ({}): its memory cannot be compared",
            base.1, end.1
        ));
        return;
    }
    if end.2 > base.2 + RSS_SLACK_KIB {
        v.push(format!(
            "the server's memory grew from {} KiB at the baseline to {} KiB at the end (more than {} KiB)",
            base.2, end.2, RSS_SLACK_KIB
        ));
    }
    let kinds: HashSet<&String> = base.3.keys().chain(end.3.keys()).collect();
    for kind in kinds {
        let (b, e) = (
            base.3.get(kind).copied().unwrap_or(0),
            end.3.get(kind).copied().unwrap_or(0),
        );
        let over = if kind == "database" {
            e > DATABASE_FDS
        } else {
            e > b
        };
        if over {
            v.push(format!(
                "the server holds {e} {kind} descriptors at the end, {b} at the baseline"
            ));
        }
    }
}

/// The server never panicked.
fn check_log(log: &Path, v: &mut Vec<String>) {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    for line in text.lines().filter(|l| l.contains("panicked")) {
        v.push(format!("the server's log: {line}"));
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn export_times_read_back_as_epoch_milliseconds() {
        // 10⁹ s after the epoch is 2001-09-09T01:46:40Z; leap day 2024-02-29 is day 19782.
        assert_eq!(
            super::epoch_ms("2001-09-09T01:46:40.700Z"),
            Some(1_000_000_000_700)
        );
        assert_eq!(
            super::epoch_ms("2024-02-29T00:00:00.000Z"),
            Some(19_782 * 86_400_000)
        );
        assert_eq!(super::epoch_ms("not a time"), None);
    }
}
