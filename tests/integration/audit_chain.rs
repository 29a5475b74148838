//! The tamper-evident audit log: a copy of a running server's database — a SQLite file, or
//! a PostgreSQL database — is tampered with through a raw connection, its triggers dropped
//! first, as someone holding the store would; `bdft-server audit verify` must catch each
//! edit, deletion, reordering, insertion, truncation and whole rewrite, and the forgeries of
//! issue 37 — a redaction marker on a row its erasure did not redact, a row appended after the
//! last checkpoint with a correctly computed unkeyed hash, a redacted row's details tried
//! against their stored hash —, naming the entry. The rewrite recomputes every hash with
//! this test's own implementation of the documented chain formats (store/audit_chain.rs, its
//! HMAC written out here), which so also checks the formats against an independent reading.

use std::path::{Path, PathBuf};
use std::process::Output;

use bdft_tests::audit_chain as chain;
use bdft_tests::postgres::PgDatabase;
use bdft_tests::server::{Server, Stop, eventually, short_study, with_url};
use bdft_tests::{TempDir, server_cmd};

/// A store to tamper with and verify: a SQLite file (its audit key beside it), or a
/// PostgreSQL database (the key in the server's keys directory), kept while this lives.
enum Store {
    File(PathBuf),
    Postgres {
        url: String,
        keys: PathBuf,
        _copy: Option<Box<PgDatabase>>,
    },
}

impl Store {
    fn url(&self) -> String {
        match self {
            Store::File(db) => format!("sqlite://{}", db.display()),
            Store::Postgres { url, .. } => url.clone(),
        }
    }

    /// Runs `sql` with the audit triggers dropped, as someone holding the store would.
    fn tamper(&self, sql: &str) {
        let on = |table: &str| match self {
            Store::File(_) => String::new(),
            Store::Postgres { .. } => format!(" ON {table}"),
        };
        let drops: String = [
            ("audit_log_no_update", "audit_log"),
            ("audit_log_no_delete", "audit_log"),
            ("audit_chain_no_update", "audit_chain"),
            ("audit_chain_no_delete", "audit_chain"),
            ("audit_salts_no_update", "audit_salts"),
            ("audit_salts_only_redacted", "audit_salts"),
            ("audit_redactions_no_update", "audit_redactions"),
            ("audit_redactions_no_delete", "audit_redactions"),
        ]
        .iter()
        .map(|(t, table)| format!("DROP TRIGGER IF EXISTS {t}{};", on(table)))
        .collect();
        with_url(&self.url(), async |pool| {
            sqlx::raw_sql(&drops).execute(pool).await.unwrap();
            sqlx::raw_sql(sql).execute(pool).await.unwrap();
        });
    }

    fn scalar(&self, sql: &str) -> i64 {
        with_url(&self.url(), async |pool| {
            sqlx::query_scalar(sql).fetch_one(pool).await.unwrap()
        })
    }

    /// `bdft-server audit verify` on this store: its outcome and everything it printed.
    fn verify(&self) -> (Output, String) {
        let mut cmd = server_cmd(["audit", "verify", "--db"]);
        match self {
            Store::File(db) => cmd.arg(db),
            Store::Postgres { url, keys, .. } => cmd.arg(url).arg("--keys-dir").arg(keys),
        };
        let out = cmd.output().unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (out, text)
    }

    /// The audit key file: beside the SQLite file, or in the keys directory.
    fn key_file(&self) -> PathBuf {
        match self {
            Store::File(db) => db.with_extension("audit-key"),
            Store::Postgres { keys, .. } => keys.join("bdft-lab.audit-key"),
        }
    }

    /// Every chain row recomputed from the log as it now is, by the documented formats
    /// (`bdft_tests::audit_chain`), the keyed ones with the chain key of the key file.
    fn rewrite_chain(&self) {
        let key = chain::chain_key(&std::fs::read_to_string(self.key_file()).unwrap());
        with_url(&self.url(), async |pool| {
            type Fields = (
                i64,
                i64,
                String,
                Option<i64>,
                String,
                Option<String>,
                Option<String>,
                i64,
                Option<String>,
            );
            let rows: Vec<Fields> = sqlx::query_as(
                "SELECT a.id, a.at, a.actor, a.actor_id, a.action, a.target, a.detail_json, c.format, s.salt \
                 FROM audit_log a JOIN audit_chain c ON c.entry_id = a.id \
                 LEFT JOIN audit_salts s ON s.entry_id = a.id ORDER BY a.id",
            )
            .fetch_all(pool)
            .await
            .unwrap();
            let mut prev = "0".repeat(64);
            for (id, at, actor, actor_id, action, target, detail, format, salt) in rows {
                let row = chain::Row {
                    id,
                    at,
                    actor,
                    actor_id,
                    action,
                    target,
                    detail,
                };
                let salt = chain::unhex(salt.as_deref().unwrap_or(""));
                let (detail_hash, hash) = chain::hashes(&row, format, &prev, &salt, &key);
                sqlx::query(
                    "UPDATE audit_chain SET prev_hash = $1, detail_hash = $2, hash = $3 WHERE entry_id = $4",
                )
                .bind(&prev)
                .bind(&detail_hash)
                .bind(&hash)
                .bind(id)
                .execute(pool)
                .await
                .unwrap();
                prev = hash;
            }
        });
    }
}

use chain::sha_hex;

/// A fresh copy of the SQLite file `source` (with the key beside it) named `name`.
fn copy_file(dir: &Path, source: &Path, name: &str) -> Store {
    let db = dir.join(format!("{name}.db"));
    std::fs::copy(source, &db).unwrap();
    std::fs::copy(
        source.with_extension("audit-key"),
        db.with_extension("audit-key"),
    )
    .unwrap();
    Store::File(db)
}

/// Some studies made through the API; the log verified up to its start's checkpoint.
fn logged_and_checkpointed(server: &Server) -> i64 {
    let api = server.experimenter();
    for _ in 0..4 {
        short_study(&api, 3.0, 1.0);
    }
    let (code, verdict) = api.get("/api/audit/verify");
    assert_eq!(code, 200, "{verdict}");
    assert_eq!(verdict["intact"], true, "{verdict}");
    verdict["last_checkpoint"]
        .as_i64()
        .expect("the start signed a checkpoint")
}

/// `original` verifies; each kind of tampering, on a copy of its own (`copy`), is caught
/// with the entry named; a whole rewrite of the chain is caught by the signed checkpoint;
/// this test's own chain of the untouched log equals the server's.
/// A consistent copy of the running SQLite `server`'s database, with its key, in `dir`.
fn consistent_copy(server: &Server, dir: &Path) -> PathBuf {
    let original = dir.join("original.db");
    with_url(&format!("sqlite://{}", server.db.display()), async |pool| {
        sqlx::query(&format!("VACUUM INTO '{}'", original.display()))
            .execute(pool)
            .await
            .unwrap();
    });
    std::fs::copy(
        server.db.with_extension("audit-key"),
        original.with_extension("audit-key"),
    )
    .unwrap();
    original
}

/// Stops the PostgreSQL `server` (a template database takes no connections while it is
/// copied) and runs `check` on its store and on copies of it made by name (`prefix_NAME`).
fn with_postgres_copies(
    server: &mut Server,
    prefix: &str,
    check: impl FnOnce(&Store, &dyn Fn(&str) -> Store),
) {
    server
        .stop(Stop::Term, std::time::Duration::from_secs(30))
        .unwrap();
    let pg = server.postgres.as_ref().unwrap();
    let keys = server.dir.path().to_path_buf();
    let original = Store::Postgres {
        url: pg.url(),
        keys: keys.clone(),
        _copy: None,
    };
    check(&original, &|name| {
        let copy = pg.blocking_copy(&format!("{prefix}_{name}"));
        Store::Postgres {
            url: copy.url(),
            keys: keys.clone(),
            _copy: Some(Box::new(copy)),
        }
    });
}

fn every_kind_of_tampering_is_named(
    original: &Store,
    copy: &dyn Fn(&str) -> Store,
    checkpoint: i64,
) {
    let entries = original.scalar("SELECT COUNT(*) FROM audit_log");
    assert!(
        entries > checkpoint + 3,
        "{entries} entries, checkpoint at {checkpoint}"
    );
    let (out, text) = original.verify();
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains(&format!("intact: {entries} entries, head "))
            && text.contains(&format!("last checkpoint at entry {checkpoint}")),
        "{text}"
    );

    // Each kind of tampering, on its own copy: caught, and the entry named.
    let mid = checkpoint + 1;
    let cases: [(&str, String, String); 6] = [
        (
            "edited",
            format!("UPDATE audit_log SET actor = 'someone' WHERE id = {mid}"),
            format!("entry {mid}: edited"),
        ),
        (
            "detail",
            format!(r#"UPDATE audit_log SET detail_json = '{{"edited":1}}' WHERE id = {mid}"#),
            format!("entry {mid}: edited: its details"),
        ),
        (
            "deleted",
            format!(
                "DELETE FROM audit_log WHERE id = {mid}; DELETE FROM audit_chain WHERE entry_id = {mid}"
            ),
            format!("entry {mid} was deleted"),
        ),
        (
            "reordered",
            format!(
                "CREATE TEMP TABLE two AS SELECT * FROM audit_log WHERE id IN ({mid}, {n}); \
                 UPDATE audit_log SET (at, actor, actor_id, action, target, detail_json) = \
                 (SELECT at, actor, actor_id, action, target, detail_json FROM two \
                  WHERE two.id = CASE audit_log.id WHEN {mid} THEN {n} ELSE {mid} END) \
                 WHERE id IN ({mid}, {n})",
                n = mid + 1
            ),
            format!(
                "entry {mid}: reordered: it holds what entry {} held",
                mid + 1
            ),
        ),
        (
            "inserted",
            format!(
                "INSERT INTO audit_log (id, at, actor, action, target, detail_json) VALUES ({}, 0, 'system:x', 'study.create', NULL, '{{}}')",
                entries + 1
            ),
            format!("entry {}: inserted behind the server's back", entries + 1),
        ),
        (
            "truncated",
            format!(
                "DELETE FROM audit_log WHERE id >= {checkpoint}; DELETE FROM audit_chain WHERE entry_id >= {checkpoint}"
            ),
            format!("truncated after checkpoint 1: it signed entry {checkpoint}"),
        ),
    ];
    for (name, sql, expected) in cases {
        let db = copy(name);
        db.tamper(&sql);
        let (out, text) = db.verify();
        assert!(!out.status.success(), "{name}: {text}");
        assert!(
            text.contains(&expected),
            "{name}: expected {expected:?} in {text}"
        );
    }

    // A whole rewrite: an early entry edited and every hash after it recomputed. The chain
    // holds again; the signed checkpoint does not.
    let db = copy("rewritten");
    db.tamper("UPDATE audit_log SET actor = 'someone else' WHERE id = 1");
    db.rewrite_chain();
    let (out, text) = db.verify();
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains(&format!(
            "entry {checkpoint}: rewritten: its hash is not the one checkpoint 1 signed"
        )),
        "{text}"
    );
    // The independent implementation agrees with the server's on the untouched copy.
    let db = copy("recomputed");
    db.tamper("SELECT 1");
    db.rewrite_chain();
    let (out, text) = db.verify();
    assert!(
        out.status.success(),
        "the test's own chain equals the server's: {text}"
    );
}

#[test]
fn audit_verify_names_every_kind_of_tampering() {
    let server = Server::start("audit-chain");
    let checkpoint = logged_and_checkpointed(&server);
    // A consistent copy of the running server's database, and its key.
    let dir = TempDir::new("audit-chain-copies");
    let original = consistent_copy(&server, dir.path());
    every_kind_of_tampering_is_named(
        &Store::File(original.clone()),
        &|name| copy_file(dir.path(), &original, name),
        checkpoint,
    );

    // A file that is not ours: a clear error, nothing written.
    let text_file = dir.path().join("notes.txt");
    std::fs::write(&text_file, "not a database").unwrap();
    let (out, text) = Store::File(text_file.clone()).verify();
    assert!(!out.status.success());
    assert!(text.contains("not a database"), "{text}");
    assert_eq!(
        std::fs::read_to_string(&text_file).unwrap(),
        "not a database"
    );
    let empty = dir.path().join("empty.db");
    with_url(
        &format!("sqlite://{}?mode=rwc", empty.display()),
        async |pool| {
            sqlx::query("CREATE TABLE t (x)")
                .execute(pool)
                .await
                .unwrap();
        },
    );
    let (out, text) = Store::File(empty).verify();
    assert!(!out.status.success());
    assert!(
        text.contains("not a bdft-lab database: it has no audit log"),
        "{text}"
    );
}

/// The same on a server's PostgreSQL store (`--db postgres://… --keys-dir`): each copy is a
/// database made from the stopped server's as its template.
#[test]
fn on_postgresql_audit_verify_names_every_kind_of_tampering() {
    let mut server = Server::start_on_postgres("audit-chain-postgres", &[]);
    let checkpoint = logged_and_checkpointed(&server);
    with_postgres_copies(&mut server, "tampered", |original, copy| {
        every_kind_of_tampering_is_named(original, copy, checkpoint);
    });
}

/// A log with an erasure in it (issue 37): two people enrolled, a four-letter note on a test
/// of each, the first erased. Returns (the erased one's note entry, the other's note entry,
/// the erasure's entry, the erased note's details as they were written).
fn logged_with_an_erasure(server: &Server) -> (i64, i64, i64, String) {
    let api = server.experimenter();
    let study = short_study(&api, 3.0, 1.0);
    let mut notes = Vec::new();
    for text in ["ABCD", "WXYZ"] {
        let enrolled = api.ok(
            &format!("/api/studies/{study}/subjects"),
            serde_json::json!({}),
        );
        let subject = enrolled["subject"]["id"].as_i64().unwrap();
        let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
        let trial = detail["trials"][0]["trial"]["id"].as_i64().unwrap();
        let note = api.ok(
            &format!("/api/trials/{trial}/note"),
            serde_json::json!({ "text": text }),
        );
        notes.push((subject, trial, note, text));
    }
    let (erased, erased_trial, erased_note, text) = &notes[0];
    let report = api.ok(
        &format!("/api/subjects/{erased}/erase"),
        serde_json::json!({ "reason": "asked for erasure" }),
    );
    assert!(
        report["removed"]["audit_details_redacted"].as_u64() >= Some(1),
        "{report}"
    );
    let (code, verdict) = api.get("/api/audit/verify");
    assert_eq!(code, 200, "{verdict}");
    assert_eq!(verdict["intact"], true, "{verdict}");
    let (_, log) = api.get("/api/audit?limit=1000");
    let log = log.as_array().unwrap();
    let entry_of = |action: &str, target: String| -> i64 {
        log.iter()
            .find(|e| e["action"] == action && e["target"] == target.as_str())
            .unwrap_or_else(|| panic!("{action} {target} in the log"))["id"]
            .as_i64()
            .unwrap()
    };
    let erasure = entry_of("subject.erase", format!("subject:{erased}"));
    let note_id = erased_note["id"].as_i64().unwrap();
    (
        entry_of("trial.note", format!("trial:{erased_trial}")),
        entry_of("trial.note", format!("trial:{}", notes[1].1)),
        erasure,
        format!(r#"{{"note":{note_id},"text":"{text}"}}"#),
    )
}

/// The three forgeries of issue 37, each on a copy of its own, named by `audit verify`:
/// a redaction marker put on a row its erasure did not redact, a row appended after the
/// last checkpoint with a correctly computed unkeyed hash, and a redacted row's details
/// recovered from their stored hash.
fn the_forgeries_of_issue_37_are_named(
    original: &Store,
    copy: &dyn Fn(&str) -> Store,
    (erased_note, other_note, erasure, erased_detail): (i64, i64, i64, String),
) {
    let (out, text) = original.verify();
    assert!(out.status.success(), "{text}");
    assert!(text.contains("redacted by erasures"), "{text}");

    // (1) The other subject's note, older than the erasure, made to look redacted by it.
    let db = copy("redaction");
    db.tamper(&format!(
        r#"UPDATE audit_log SET detail_json = '{{"erasure":{erasure},"redacted":"subject.erase"}}' WHERE id = {other_note}"#
    ));
    let (out, text) = db.verify();
    assert!(!out.status.success(), "a forged redaction: {text}");
    assert!(
        text.contains(&format!(
            "entry {other_note}: redacted, but not by an erasure"
        )),
        "a forged redaction: {text}"
    );

    // (2) A row appended after the last checkpoint, its hash computed as the chain of
    // migration 0023 computes it (SHA-256, no key).
    let db = copy("appended");
    let last = db.scalar("SELECT MAX(id) FROM audit_log");
    let prev: String = with_url(&db.url(), async |pool| {
        sqlx::query_scalar("SELECT hash FROM audit_chain WHERE entry_id = $1")
            .bind(last)
            .fetch_one(pool)
            .await
            .unwrap()
    });
    let (id, at, detail) = (last + 1, 1_700_000_000_000i64, r#"{"reason":"forged"}"#);
    let detail_hash = sha_hex(detail.as_bytes());
    let content = serde_json::to_string(&serde_json::json!([
        id,
        at,
        "system:startup",
        null,
        "trial.abort",
        "trial:1",
        detail_hash
    ]))
    .unwrap();
    let hash = sha_hex(format!("{prev}\n{content}").as_bytes());
    db.tamper(&format!(
        "INSERT INTO audit_log (id, at, actor, action, target, detail_json) VALUES ({id}, {at}, 'system:startup', 'trial.abort', 'trial:1', '{detail}'); \
         INSERT INTO audit_chain (entry_id, prev_hash, detail_hash, hash) VALUES ({id}, '{prev}', '{detail_hash}', '{hash}')"
    ));
    let (out, text) = db.verify();
    assert!(!out.status.success(), "an appended row: {text}");
    assert!(
        text.contains(&format!(
            "entry {id}: appended after the last checkpoint without the audit key"
        )),
        "an appended row: {text}"
    );

    // (3) The erased note's stored hash is not the SHA-256 of what it said, and nothing
    // that would let its text be tried against that hash (its salt) is left.
    let stored: String = with_url(&original.url(), async |pool| {
        sqlx::query_scalar("SELECT detail_hash FROM audit_chain WHERE entry_id = $1")
            .bind(erased_note)
            .fetch_one(pool)
            .await
            .unwrap()
    });
    assert_ne!(
        stored,
        sha_hex(erased_detail.as_bytes()),
        "the erased note's hash is the plain SHA-256 of {erased_detail}"
    );
    assert_eq!(
        original.scalar(&format!(
            "SELECT COUNT(*) FROM audit_salts WHERE entry_id = {erased_note}"
        )),
        0,
        "the erased note's salt is gone"
    );
    assert!(
        original.scalar(&format!(
            "SELECT COUNT(*) FROM audit_salts WHERE entry_id = {other_note}"
        )) == 1,
        "the other note keeps its salt"
    );
}

#[test]
fn audit_verify_names_the_forgeries_of_issue_37() {
    let server = Server::start("audit-forgeries");
    let logged = logged_with_an_erasure(&server);
    let dir = TempDir::new("audit-forgeries-copies");
    let original = consistent_copy(&server, dir.path());
    the_forgeries_of_issue_37_are_named(
        &Store::File(original.clone()),
        &|name| copy_file(dir.path(), &original, name),
        logged,
    );

    // Without the key file the keyed entries cannot be checked: it says so and fails,
    // rather than calling the log intact.
    let Store::File(keyless) = copy_file(dir.path(), &original, "keyless") else {
        unreachable!("a file")
    };
    std::fs::remove_file(keyless.with_extension("audit-key")).unwrap();
    let (out, text) = Store::File(keyless).verify();
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains("keyed entries cannot be checked")
            && text.contains("NOT checked: ")
            && text.contains("could not be checked whole"),
        "{text}"
    );
}

#[test]
fn on_postgresql_audit_verify_names_the_forgeries_of_issue_37() {
    let mut server = Server::start_on_postgres("audit-forgeries-postgres", &[]);
    let logged = logged_with_an_erasure(&server);
    with_postgres_copies(&mut server, "forged", |original, copy| {
        the_forgeries_of_issue_37_are_named(original, copy, logged);
    });
}

/// A command without the keys directory (`pilot --db postgres://…` without `--keys-dir` or
/// `BDFT_KEYS_DIR`) writes unkeyed entries; the running server signs them (it looks every
/// second), after which the log verifies, counting them.
#[test]
fn on_postgresql_entries_written_without_the_key_are_signed_by_the_server() {
    let server = Server::start_on_postgres("audit-unkeyed", &[]);
    let api = server.experimenter();
    short_study(&api, 3.0, 1.0);
    let url = server.store();
    let mut pilot = server_cmd(["pilot", "--subjects", "1", "--db", &url])
        .env_remove("BDFT_KEYS_DIR")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let unkeyed = |url: &str| -> i64 {
        with_url(url, async |pool| {
            sqlx::query_scalar("SELECT COUNT(*) FROM audit_chain WHERE format = 1")
                .fetch_one(pool)
                .await
                .unwrap()
        })
    };
    eventually(std::time::Duration::from_secs(120), || {
        (unkeyed(&url) > 0).then_some(())
    });
    pilot.kill().unwrap();
    pilot.wait().unwrap();
    let verdict = eventually(std::time::Duration::from_secs(20), || {
        let (_, v) = api.get("/api/audit/verify");
        (v["intact"] == true).then_some(v)
    });
    assert!(verdict["unkeyed"].as_i64() > Some(0), "{verdict}");
    assert!(
        verdict["report"].as_str().is_some_and(|r| r.contains(
            "entries written without the audit key, each covered by a signed checkpoint"
        )),
        "{verdict}"
    );
}
