//! Backups and restores, end to end: backups taken while a pilot files its trials (the
//! dashboard's "Back up now" in the server — by the API, then in Chromium —, and
//! `bdft-server backup` from another process),
//! each restored into a new path, whose exports equal the original's up to the backup's
//! moment; the schedule and how many it keeps; who may see backups; and every refusal of a
//! restore (a running server, a damaged file, a newer program's file, no manifest), and a
//! restore right after a server stopped the moment it was up.
//!
//! *The backup's moment*, precisely: the audit log is append-only and every change commits
//! with its audit row, so the moment is the backup's last audit row, N = its manifest's
//! `row_counts.audit_log`. The restored database's exports then are the original's (taken
//! after the pilot ended) as of that row: its audit log is the original's first N rows and
//! then the restore's own row; its trials export has, for every trial finished at that
//! moment, the original's row cell for cell — with the survey's cells empty where the
//! survey was answered after the moment (trials still running or to run then differ, as
//! they should); its samples export (of one subject) is the original's cut to those trials,
//! byte for byte; the codebook is the same.

use std::collections::BTreeSet;
use std::path::Path;
use std::process::{Output, Stdio};
use std::time::Duration;

use bdft_tests::controller_link::Proc;
use bdft_tests::exports::parse_csv;
use bdft_tests::server::{ADMIN_PASSWORD, Api, Server, Stop, eventually, short_study, with_db};
use bdft_tests::webdriver::{Driver, artifacts_dir};
use bdft_tests::{TempDir, server_cmd, server_command, server_output, succeeded};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};

/// What a command printed on its standard output.
fn stdout_of(out: Output) -> String {
    String::from_utf8(out.stdout).unwrap()
}

/// The error a refused command printed (it must have failed).
fn refused(out: Output, what: &str) -> String {
    assert!(!out.status.success(), "{what} was not refused");
    String::from_utf8(out.stderr).unwrap()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// An export of `db` as text, by the command line.
fn export(db: &Path, args: &[&str]) -> String {
    let dir = TempDir::new("backup-export");
    let out = dir.path().join("x.csv");
    let mut all = vec!["export", "--db", path(db), "--out", path(&out)];
    all.extend_from_slice(args);
    server_command(all);
    std::fs::read_to_string(&out).unwrap()
}

/// Each line (after the header) of a CSV with no line breaks inside cells, by `column`.
fn lines_by<'a>(text: &'a str, column: &str) -> (&'a str, Vec<(String, &'a str)>) {
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let c = header.split(',').position(|h| h == column).unwrap();
    (
        header,
        lines
            .map(|l| (l.split(',').nth(c).unwrap().to_string(), l))
            .collect(),
    )
}

/// Checks that the database `restored`, restored from a backup with `manifest`, exports
/// what `original` exported at the backup's moment (see the module doc), for the study
/// `study` the pilot ran in.
fn assert_exports_as_of_the_backup(original: &Path, restored: &Path, study: i64, manifest: &Value) {
    let s = study.to_string();
    let n = manifest["row_counts"]["audit_log"].as_u64().unwrap() as usize;
    let (orig_audit, rest_audit) = (
        parse_csv(&export(original, &["--kind", "audit"])),
        parse_csv(&export(restored, &["--kind", "audit"])),
    );
    assert_eq!(
        rest_audit.len(),
        n + 2,
        "header, the N rows of the backup, the restore's row"
    );
    assert_eq!(
        rest_audit[..=n],
        orig_audit[..=n],
        "the audit log up to the moment"
    );
    let action = orig_audit[0].iter().position(|h| h == "action").unwrap();
    assert_eq!(rest_audit[n + 1][action], "backup.restore");
    assert!(
        orig_audit.len() > n + 1,
        "the pilot went on after the backup: the original has rows after the moment"
    );

    let (orig_trials, rest_trials) = (
        parse_csv(&export(original, &["--study", &s, "--kind", "trials"])),
        parse_csv(&export(restored, &["--study", &s, "--kind", "trials"])),
    );
    assert_eq!(orig_trials[0], rest_trials[0]);
    let col = |name: &str| rest_trials[0].iter().position(|h| h == name).unwrap();
    let (id, status, code_at) = (col("trial_id"), col("status"), col("subject_code"));
    let survey: Vec<usize> = (0..rest_trials[0].len())
        .filter(|&c| rest_trials[0][c].starts_with("rating_") || rest_trials[0][c] == "comment")
        .collect();
    let mut finished = BTreeSet::new();
    let mut running = 0;
    for row in &rest_trials[1..] {
        // Not finished at the moment: running, or still to run.
        if matches!(row[status].as_str(), "running" | "scheduled") {
            running += 1;
            continue;
        }
        let mut theirs = orig_trials
            .iter()
            .find(|r| r[id] == row[id])
            .unwrap_or_else(|| panic!("trial {} is in the original", row[id]))
            .clone();
        if survey.iter().all(|&c| row[c].is_empty()) {
            // Its survey was not answered at the moment (or never is: a practice).
            for &c in &survey {
                theirs[c].clear();
            }
        }
        assert_eq!(row, &theirs, "trial {}, finished at the moment", row[id]);
        finished.insert(row[id].clone());
    }
    assert!(!finished.is_empty(), "the backup holds finished trials");
    let finished_in_the_original = orig_trials[1..]
        .iter()
        .filter(|r| !matches!(r[status].as_str(), "running" | "scheduled"))
        .count();
    assert!(
        finished_in_the_original > finished.len(),
        "the original finished more trials after the moment ({} at it, {running} running or to run; {finished_in_the_original} in the end)",
        finished.len(),
    );

    // One subject's samples (the cut is an export too; all of them would be a pilot's
    // whole record twice over): the subject of the first trial finished at the moment.
    let code = &rest_trials[1..]
        .iter()
        .find(|r| finished.contains(&r[id]))
        .unwrap()[code_at];
    let cut_args = [
        "--study",
        &s,
        "--kind",
        "samples",
        "--subject",
        code.as_str(),
    ];
    let (orig_samples, rest_samples) = (export(original, &cut_args), export(restored, &cut_args));
    let (header, orig_lines) = lines_by(&orig_samples, "trial_id");
    let cut: Vec<&str> = std::iter::once(header)
        .chain(
            orig_lines
                .iter()
                .filter(|(id, _)| finished.contains(id))
                .map(|(_, l)| *l),
        )
        .collect();
    let rest: Vec<&str> = rest_samples.lines().collect();
    assert!(rest.len() > 1, "the restored database has records");
    assert!(
        cut == rest,
        "the samples of the trials finished at the moment: {} lines restored, {} in the original's cut",
        rest.len(),
        cut.len()
    );
    assert_eq!(
        export(original, &["--study", &s, "--kind", "codebook"]),
        export(restored, &["--study", &s, "--kind", "codebook"])
    );
}

#[test]
fn backups_taken_while_a_pilot_runs_restore_to_the_exports_of_their_moment() {
    let dir = TempDir::new("backups-dir");
    let server = Server::start_with(
        "backups",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--backup-dir",
            path(dir.path()),
        ],
    );
    let api = server.experimenter();
    // The schedule's first backup is made at start: the directory holds none.
    let (_, v) = eventually(Duration::from_secs(60), || {
        let (code, v) = api.get("/api/backups");
        (v["backups"].as_array()?.len() == 1).then_some((code, v))
    });
    assert_eq!(v["backups"][0]["made_by"], "system:backup-schedule", "{v}");
    assert_eq!(v["every_s"], 86_400);
    assert_eq!(v["keep"], 14);

    // Thirty subjects of 4 s tests (≈ 1,200 s of simulated trials): seconds of filing
    // after the sixth trial, against the fraction of a second the backups take.
    let study = short_study(&api, 4.0, 0.5);
    api.ok(
        &format!("/api/studies/{study}/pilot"),
        json!({ "subjects": 30 }),
    );
    eventually(Duration::from_secs(120), || {
        let (_, s) = api.get("/api/pilot");
        (s["done"].as_u64()? >= 6).then_some(())
    });
    // While the pilot files its trials: the dashboard's backup, then one from another
    // process.
    let by_dashboard = api.ok("/api/backups", json!({}));
    assert_eq!(by_dashboard["made_by"], "admin");
    let by_hand = dir.path().join("by-hand.db");
    let printed: Value = serde_json::from_str(&stdout_of(server_command([
        "backup",
        "--db",
        path(&server.db),
        "--out",
        path(&by_hand),
    ])))
    .unwrap();
    let beside: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("by-hand.db.manifest.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(printed, beside, "the manifest printed is the one written");
    assert_eq!(beside["made_by"], "system:backup-command");
    let (hash, bytes) = sha256(&by_hand);
    assert_eq!(
        (
            beside["sha256"].as_str().unwrap(),
            beside["bytes"].as_u64().unwrap()
        ),
        (hash.as_str(), bytes)
    );
    assert_eq!(beside["format"], "bdft-backup/1");
    assert!(beside["schema_version"].as_i64().unwrap() >= 20, "{beside}");
    assert!(
        beside["protocol_hashes_verified"]["studies"]
            .as_u64()
            .unwrap()
            >= 1
    );
    assert!(beside["row_counts"]["trials"].as_u64().unwrap() >= 4);

    let pilot = eventually(Duration::from_secs(600), || {
        let (_, s) = api.get("/api/pilot");
        (s["running"] == false).then_some(s)
    });
    let dry = pilot["report"]["study_id"]
        .as_i64()
        .expect("the pilot's report");
    let (_, listed) = api.get("/api/backups");
    let file = by_dashboard["file"].as_str().unwrap();
    assert!(
        listed["backups"]
            .as_array()
            .unwrap()
            .iter()
            .any(|b| b == &by_dashboard),
        "listed with its manifest: {listed}"
    );
    // Every backup and restore is in the audit log.
    let (_, audit) = api.get("/api/audit?limit=10000");
    let creates = audit
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["action"] == "backup.create")
        .count();
    assert_eq!(
        creates, 3,
        "the scheduled one, the dashboard's and the command's"
    );

    // The dashboard's panel, in Chromium: the directory's backups with their manifests, and
    // "Back up now".
    let downloads = TempDir::new("backups-browser");
    let driver = Driver::start();
    let dash = driver.session(downloads.path());
    dash.log_in_to_dashboard(&server.base);
    dash.find(&format!("#backups tr[data-row-key='{file}']"));
    dash.click("#backup-now");
    let said = dash.wait_until(
        "const s = document.querySelector('#backups-status'); return s.classList.contains('ok') || s.classList.contains('err') ? s.textContent : null",
        json!([]),
    );
    assert!(said.as_str().unwrap().contains("checked"), "{said}");
    dash.exec(
        "document.getElementById('sec-backups').scrollIntoView()",
        json!([]),
    );
    dash.screenshot(&artifacts_dir().join("dashboard-backups.png"));
    assert_eq!(
        api.get("/api/backups").1["backups"]
            .as_array()
            .unwrap()
            .len(),
        4
    );

    for (backup, manifest) in [(dir.path().join(file), &by_dashboard), (by_hand, &beside)] {
        let into = TempDir::new("restored");
        let db = into.path().join("bdft-lab.db");
        let report: Value = serde_json::from_str(&stdout_of(server_command([
            "restore",
            "--from",
            path(&backup),
            "--db",
            path(&db),
        ])))
        .unwrap();
        assert_eq!(report["sha256"], manifest["sha256"]);
        assert_eq!(report["replaced_kept_as"], Value::Null);
        assert_exports_as_of_the_backup(&server.db, &db, dry, manifest);
    }
}

fn sha256(file: &Path) -> (String, u64) {
    let bytes = std::fs::read(file).unwrap();
    let hash = Sha256::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    (hash, bytes.len() as u64)
}

/// A copy of the backup `from` as `to` with its manifest: the copy changed by `damage`,
/// then its manifest by `edit` (given the copy).
fn copy_backup(
    from: &Path,
    to: &Path,
    damage: impl FnOnce(&Path),
    edit: impl FnOnce(&Path, &mut Value),
) {
    std::fs::copy(from, to).unwrap();
    damage(to);
    let manifest_of = |p: &Path| format!("{}.manifest.json", p.display());
    let mut m: Value =
        serde_json::from_str(&std::fs::read_to_string(manifest_of(from)).unwrap()).unwrap();
    m["file"] = json!(to.file_name().unwrap().to_str().unwrap());
    edit(to, &mut m);
    std::fs::write(manifest_of(to), m.to_string()).unwrap();
}

/// The manifest made to match the file as it is now (a file damaged before it was hashed).
fn rehash(file: &Path, m: &mut Value) {
    let (hash, bytes) = sha256(file);
    m["sha256"] = json!(hash);
    m["bytes"] = json!(bytes);
}

/// Changes the bytes of `file` with `f`.
fn change_bytes(file: &Path, f: impl FnOnce(&mut Vec<u8>)) {
    let mut bytes = std::fs::read(file).unwrap();
    f(&mut bytes);
    std::fs::write(file, &bytes).unwrap();
}

fn restore_refused(from: &Path, db: &Path, what: &str) -> String {
    let e = refused(
        server_output(["restore", "--from", path(from), "--db", path(db)]),
        what,
    );
    let mut staging = db.as_os_str().to_os_string();
    staging.push(".restoring");
    assert!(
        !Path::new(&staging).exists(),
        "{what}: nothing half-written is left"
    );
    e
}

#[test]
fn a_restore_refuses_a_running_server_a_damaged_file_and_a_newer_programs() {
    let server = Server::start("restore-refusals");
    let dir = TempDir::new("restore-refusals-files");
    let good = dir.path().join("good.db");
    server_command(["backup", "--db", path(&server.db), "--out", path(&good)]);
    let e = refused(
        server_output(["backup", "--db", path(&server.db), "--out", path(&good)]),
        "a backup over an existing file",
    );
    assert!(
        e.contains("exists: a backup never overwrites a file"),
        "{e}"
    );
    let e = refused(
        server_output([
            "backup",
            "--db",
            path(&dir.path().join("none.db")),
            "--out",
            path(&dir.path().join("x.db")),
        ]),
        "a backup of no database",
    );
    assert!(e.contains("no such database"), "{e}");

    // Onto the database of a running server.
    let e = restore_refused(&good, &server.db, "a restore under a running server");
    assert!(
        e.contains("is in use: bdft-server serve (pid ")
            && e.contains(&format!("serving {}", server.base))
            && e.contains("Stop it first"),
        "{e}"
    );

    let target = dir.path().join("restored.db");
    // One byte changed after the backup was made: the hash says so.
    let flipped = dir.path().join("flipped.db");
    copy_backup(
        &good,
        &flipped,
        |f| {
            change_bytes(f, |b| {
                let middle = b.len() / 2;
                b[middle] ^= 0xff;
            })
        },
        |_, _| {},
    );
    let e = restore_refused(&flipped, &target, "a changed file");
    assert!(e.contains("flipped.db is damaged: its SHA-256 is"), "{e}");

    // Damaged before it was hashed (its second page wiped): SQLite's check finds it.
    let wiped = dir.path().join("wiped.db");
    copy_backup(
        &good,
        &wiped,
        |f| change_bytes(f, |b| b[4096..8192].fill(0)),
        rehash,
    );
    let e = restore_refused(&wiped, &target, "a file SQLite finds damaged");
    assert!(e.contains("wiped.db is damaged"), "{e}");

    // Made by a newer program: a migration this one does not know.
    let newer = dir.path().join("newer.db");
    copy_backup(
        &good,
        &newer,
        |f| add_migration(f, 9999, "sites of a consortium"),
        |f, m| {
            rehash(f, m);
            let n = m["row_counts"]["_sqlx_migrations"].as_i64().unwrap();
            m["row_counts"]["_sqlx_migrations"] = json!(n + 1);
        },
    );
    let e = restore_refused(&newer, &target, "a newer program's file");
    assert!(
        e.contains("was made by a newer bdft-server: it has migrations this program does not know (9999 sites of a consortium)"),
        "{e}"
    );
    // … and its manifest alone says so, before anything is copied.
    let said = dir.path().join("said-newer.db");
    copy_backup(
        &good,
        &said,
        |_| {},
        |_, m| {
            m["schema_version"] = json!(9999);
            m["program_version"] = json!("9.0.0");
        },
    );
    let e = restore_refused(&said, &target, "a manifest of a newer schema");
    assert!(
        e.contains("was made by a newer bdft-server (9.0.0, schema 9999"),
        "{e}"
    );

    // No manifest beside it.
    let bare = dir.path().join("bare.db");
    std::fs::copy(&good, &bare).unwrap();
    let e = restore_refused(&bare, &target, "a file without its manifest");
    assert!(
        e.contains("bare.db.manifest.json: cannot read the backup's manifest"),
        "{e}"
    );
    assert!(!target.exists(), "no refused restore wrote the database");

    // The good one restores, twice: the second keeps the database it replaces.
    server_command(["restore", "--from", path(&good), "--db", path(&target)]);
    let again: Value = serde_json::from_str(&stdout_of(server_command([
        "restore",
        "--from",
        path(&good),
        "--db",
        path(&target),
    ])))
    .unwrap();
    let kept = again["replaced_kept_as"]
        .as_str()
        .expect("the replaced database is kept");
    let audit = export(Path::new(kept), &["--kind", "audit"]);
    assert!(
        audit.contains("backup.restore"),
        "the replaced one had the first restore"
    );
}

/// A server signalled the moment its address line is out (as a supervisor or a test that
/// reads that line may) stops by its own shutdown, which ends its heartbeat: a restore right
/// after is not refused for the 5 s a killed server's last beat holds the database.
#[test]
fn a_server_stopped_as_soon_as_it_is_up_ends_cleanly_and_a_restore_may_follow_at_once() {
    let mut server = Server::start("prompt-stop");
    let dir = TempDir::new("prompt-stop-files");
    let backup = dir.path().join("backup.db");
    server_command(["backup", "--db", path(&server.db), "--out", path(&backup)]);
    for _ in 0..3 {
        server.restart(Stop::Term, Duration::from_secs(30)).unwrap();
    }
    server.stop(Stop::Term, Duration::from_secs(30)).unwrap();
    server_command(["restore", "--from", path(&backup), "--db", path(&server.db)]);
}

/// Records in the database file `db` a migration it never ran (what a newer program's
/// database holds).
fn add_migration(db: &Path, version: i64, description: &str) {
    with_db(db, async |pool| {
        sqlx::query("INSERT INTO _sqlx_migrations (version, description, success, checksum, execution_time) VALUES (?, ?, 1, x'00', 0)")
            .bind(version)
            .bind(description)
            .execute(pool)
            .await
            .unwrap();
    });
}

#[test]
fn scheduled_backups_keep_the_newest_and_only_admins_see_them() {
    let dir = TempDir::new("backups-schedule");
    let server = Server::start_with(
        "backups-schedule",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--backup-dir",
            path(dir.path()),
            "--backup-every",
            "1s",
            "--backup-keep",
            "2",
        ],
    );
    let api = server.experimenter();
    eventually(Duration::from_secs(120), || {
        let (_, audit) = api.get("/api/audit?limit=10000");
        let scheduled = audit
            .as_array()?
            .iter()
            .filter(|r| r["action"] == "backup.create" && r["actor"] == "system:backup-schedule")
            .count();
        (scheduled >= 4).then_some(())
    });
    let (_, v) = api.get("/api/backups");
    let listed = v["backups"].as_array().unwrap();
    assert!(listed.len() <= 2, "at most the newest 2 are kept: {v}");
    assert_eq!(v["every_s"], 1);
    let files = std::fs::read_dir(dir.path())
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".db")
        })
        .count();
    assert!(files <= 3, "2 kept, and at most one being made: {files}");

    for role in ["experimenter", "analyst"] {
        let (_, other) = server.account(&api, &format!("{role}1"), role);
        let (code, body) = other.get("/api/backups");
        assert_eq!(code, 403, "{role}: {body}");
        assert!(
            body["error"]
                .as_str()
                .unwrap()
                .contains("only an admin manages backups"),
            "{body}"
        );
        assert_eq!(other.post("/api/backups", json!({})).0, 403);
    }

    // Settings a server refuses, with what is allowed.
    let d = path(dir.path());
    let flags_db = dir.path().join("flags.db");
    for (args, says) in [
        (
            vec!["--backup-dir", d, "--backup-every", "5x"],
            "from 1s to 30d",
        ),
        (
            vec!["--backup-dir", d, "--backup-every", "31d"],
            "out of range",
        ),
        (vec!["--backup-every", "6h"], "--backup-dir"),
        (vec!["--backup-dir", d, "--backup-keep", "0"], "1..=10000"),
        (
            vec!["--backup-dir", "/proc/bdft-no-such-place"],
            "--backup-dir /proc/bdft-no-such-place",
        ),
    ] {
        let mut all = vec!["serve", "--db", path(&flags_db), "--listen", "127.0.0.1:0"];
        all.extend(args.iter());
        let e = refused(server_output(all), &format!("serve {args:?}"));
        assert!(e.contains(says), "{args:?}: {e}");
    }

    // Without --backup-dir backups are off, and the answer says how to turn them on.
    let off = Server::start("backups-off");
    let admin = off.experimenter();
    let (code, body) = admin.post("/api/backups", json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("start the server with --backup-dir DIR"),
        "{body}"
    );
    assert_eq!(admin.get("/api/backups").1["dir"], Value::Null);
}

/// On a PostgreSQL store every way to a backup or a restore is refused, naming PostgreSQL's
/// own tools, and nothing is written: the command line, the scheduled backups at start and
/// the dashboard's button.
#[test]
fn on_postgresql_backups_and_restores_are_refused_naming_its_own_tools() {
    let server = Server::start_on_postgres("backups-postgres", &[]);
    let url = server.store();
    let dir = TempDir::new("backups-postgres-files");
    let out = dir.path().join("copy.db");
    let tools = "pg_dump and pg_restore, or continuous archiving";
    let e = refused(
        server_output(["backup", "--db", &url, "--out", path(&out)]),
        "a backup of a PostgreSQL store",
    );
    assert!(e.contains(tools), "{e}");
    assert!(!out.exists(), "nothing written");
    std::fs::write(&out, "a file").unwrap();
    let e = refused(
        server_output(["restore", "--from", path(&out), "--db", &url]),
        "a restore onto a PostgreSQL store",
    );
    assert!(e.contains(tools), "{e}");
    let e = refused(
        server_output([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--db",
            &url,
            "--keys-dir",
            path(dir.path()),
            "--backup-dir",
            path(dir.path()),
        ]),
        "scheduled backups of a PostgreSQL store",
    );
    assert!(e.contains("--backup-dir") && e.contains(tools), "{e}");

    let api = server.login("admin", ADMIN_PASSWORD);
    let (code, body) = api.post("/api/backups", json!({}));
    assert_eq!(code, 409, "{body}");
    assert!(body.to_string().contains(tools), "{body}");
    // The study data is still there to read.
    assert_eq!(api.get("/api/studies").0, 200);
}

/// A backup directory or file given relative to the working directory, two levels up
/// (`../../x`), is where the backups go: the path is not collapsed on its way to SQLite
/// (it was: `sqlite://../../x` read as the host `..` and the path `/../x`, which a URL
/// shortens to `/x`, so every check of a new backup looked for `../x` and failed).
#[test]
fn relative_backup_paths_two_levels_up_work() {
    let root = TempDir::new("backups-relative");
    let cwd = root.path().join("a").join("b");
    std::fs::create_dir_all(&cwd).unwrap();
    std::fs::create_dir_all(root.path().join("x")).unwrap();
    let db = root.path().join("bdft-lab.db");

    // The server's --backup-dir: "Back up now" answers the manifest, the file is there.
    let proc = Proc::try_spawn_in(
        Some(&cwd),
        "bdft-server",
        &[
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--db",
            path(&db),
            "--admin-password",
            ADMIN_PASSWORD,
            "--backup-dir",
            "../../x",
        ],
        "bdft-lab server on http://",
        Stdio::inherit(),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let mut api = Api::anonymous(&format!("http://{}", proc.addr));
    let (code, login) = api.post(
        "/api/login",
        json!({ "username": "admin", "password": ADMIN_PASSWORD }),
    );
    assert_eq!(code, 200, "{login}");
    api.csrf = login["csrf"].as_str().map(str::to_string);
    // The schedule's first backup, at start (it failed, and so would every later one).
    let first = eventually(Duration::from_secs(60), || {
        let (_, audit) = api.get("/api/audit?limit=100");
        audit
            .as_array()?
            .iter()
            .find(|r| {
                r["actor"] == "system:backup-schedule"
                    && r["action"]
                        .as_str()
                        .is_some_and(|a| a.starts_with("backup."))
            })
            .cloned()
    });
    assert_eq!(first["action"], "backup.create", "{first}");
    let (code, manifest) = api.post("/api/backups", json!({}));
    assert_eq!(code, 200, "{manifest}");
    let file = manifest["file"].as_str().unwrap();
    assert!(root.path().join("x").join(file).is_file(), "{manifest}");
    let (_, listed) = api.get("/api/backups");
    assert_eq!(listed["backups"].as_array().unwrap().len(), 2, "{listed}");
    drop(proc);

    // `bdft-server backup --out ../../x/by-hand.db`, and its restore from there.
    succeeded(
        server_cmd(["backup", "--db", path(&db), "--out", "../../x/by-hand.db"]).current_dir(&cwd),
    );
    assert!(root.path().join("x").join("by-hand.db").is_file());
    succeeded(
        server_cmd([
            "restore",
            "--from",
            "../../x/by-hand.db",
            "--db",
            "../../restored.db",
        ])
        .current_dir(&cwd),
    );
    assert!(root.path().join("restored.db").is_file());
}
