//! The tamper-evident audit log: a copy of a running server's database is tampered with
//! through a raw SQLite connection, its triggers dropped first, as someone holding the file
//! would; `bdft-server audit verify` must catch each edit, deletion, reordering, insertion,
//! truncation and whole rewrite, naming the entry. The rewrite recomputes every hash with
//! this test's own implementation of the documented chain format (store/audit_chain.rs),
//! which so also checks the format against an independent reading.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use bdft_tests::server::{Server, short_study};
use bdft_tests::{TempDir, binary};
use sha2::{Digest, Sha256};

fn block_on<T>(f: impl std::future::Future<Output = T>) -> T {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(f)
}

async fn connect(db: &Path) -> sqlx::SqlitePool {
    let opts = sqlx::sqlite::SqliteConnectOptions::new()
        .filename(db)
        .busy_timeout(std::time::Duration::from_secs(10));
    sqlx::SqlitePool::connect_with(opts).await.unwrap()
}

/// Runs `sql` on `db` with the audit triggers dropped.
fn tamper(db: &Path, sql: &str) {
    block_on(async {
        let pool = connect(db).await;
        for t in [
            "audit_log_no_update",
            "audit_log_no_delete",
            "audit_chain_no_update",
            "audit_chain_no_delete",
        ] {
            sqlx::query(&format!("DROP TRIGGER IF EXISTS {t}"))
                .execute(&pool)
                .await
                .unwrap();
        }
        sqlx::raw_sql(sql).execute(&pool).await.unwrap();
        pool.close().await;
    });
}

fn verify(db: &Path) -> (Output, String) {
    let out = Command::new(binary("bdft-server"))
        .args(["audit", "verify", "--db"])
        .arg(db)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out, text)
}

fn sha_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Every chain row recomputed from the log as it now is, by the documented format.
fn rewrite_chain(db: &Path) {
    block_on(async {
        let pool = connect(db).await;
        type Row = (
            i64,
            i64,
            String,
            Option<i64>,
            String,
            Option<String>,
            Option<String>,
        );
        let rows: Vec<Row> = sqlx::query_as(
            "SELECT id, at, actor, actor_id, action, target, detail_json FROM audit_log ORDER BY id",
        )
        .fetch_all(&pool)
        .await
        .unwrap();
        let mut prev = "0".repeat(64);
        for (id, at, actor, actor_id, action, target, detail) in rows {
            let detail_hash = sha_hex(detail.unwrap_or_default().as_bytes());
            let content = serde_json::to_string(&serde_json::json!([
                id,
                at,
                actor,
                actor_id,
                action,
                target,
                detail_hash
            ]))
            .unwrap();
            let hash = sha_hex(format!("{prev}\n{content}").as_bytes());
            sqlx::query(
                "UPDATE audit_chain SET prev_hash = ?, detail_hash = ?, hash = ? WHERE entry_id = ?",
            )
            .bind(&prev)
            .bind(&detail_hash)
            .bind(&hash)
            .bind(id)
            .execute(&pool)
            .await
            .unwrap();
            prev = hash;
        }
        pool.close().await;
    });
}

/// A fresh copy of `source` (with the key beside it) named `name`.
fn copy(dir: &Path, source: &Path, name: &str) -> PathBuf {
    let db = dir.join(format!("{name}.db"));
    std::fs::copy(source, &db).unwrap();
    std::fs::copy(
        source.with_extension("audit-key"),
        db.with_extension("audit-key"),
    )
    .unwrap();
    db
}

fn scalar(db: &Path, sql: &str) -> i64 {
    block_on(async {
        let pool = connect(db).await;
        let v: i64 = sqlx::query_scalar(sql).fetch_one(&pool).await.unwrap();
        pool.close().await;
        v
    })
}

#[test]
fn audit_verify_names_every_kind_of_tampering() {
    let server = Server::start("audit-chain");
    let api = server.experimenter();
    for _ in 0..4 {
        short_study(&api, 3.0, 1.0);
    }
    let (code, verdict) = api.get("/api/audit/verify");
    assert_eq!(code, 200, "{verdict}");
    assert_eq!(verdict["intact"], true, "{verdict}");
    let checkpoint = verdict["last_checkpoint"]
        .as_i64()
        .expect("the start signed a checkpoint");

    // A consistent copy of the running server's database, and its key.
    let dir = TempDir::new("audit-chain-copies");
    let original = dir.path().join("original.db");
    block_on(async {
        let pool = connect(&server.db).await;
        sqlx::query(&format!("VACUUM INTO '{}'", original.display()))
            .execute(&pool)
            .await
            .unwrap();
        pool.close().await;
    });
    std::fs::copy(
        server.db.with_extension("audit-key"),
        original.with_extension("audit-key"),
    )
    .unwrap();
    let entries = scalar(&original, "SELECT COUNT(*) FROM audit_log");
    assert!(
        entries > checkpoint + 3,
        "{entries} entries, checkpoint at {checkpoint}"
    );

    let (out, text) = verify(&original);
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
        let db = copy(dir.path(), &original, name);
        tamper(&db, &sql);
        let (out, text) = verify(&db);
        assert!(!out.status.success(), "{name}: {text}");
        assert!(
            text.contains(&expected),
            "{name}: expected {expected:?} in {text}"
        );
    }

    // A whole rewrite: an early entry edited and every hash after it recomputed. The chain
    // holds again; the signed checkpoint does not.
    let db = copy(dir.path(), &original, "rewritten");
    tamper(
        &db,
        "UPDATE audit_log SET actor = 'someone else' WHERE id = 1",
    );
    rewrite_chain(&db);
    let (out, text) = verify(&db);
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains(&format!(
            "entry {checkpoint}: rewritten: its hash is not the one checkpoint 1 signed"
        )),
        "{text}"
    );
    // The independent implementation agrees with the server's on the untouched copy.
    let db = copy(dir.path(), &original, "recomputed");
    tamper(&db, "SELECT 1");
    rewrite_chain(&db);
    let (out, text) = verify(&db);
    assert!(
        out.status.success(),
        "the test's own chain equals the server's: {text}"
    );

    // A file that is not ours: a clear error, nothing written.
    let text_file = dir.path().join("notes.txt");
    std::fs::write(&text_file, "not a database").unwrap();
    let (out, text) = verify(&text_file);
    assert!(!out.status.success());
    assert!(text.contains("not a database"), "{text}");
    assert_eq!(
        std::fs::read_to_string(&text_file).unwrap(),
        "not a database"
    );
    let empty = dir.path().join("empty.db");
    block_on(async {
        let opts = sqlx::sqlite::SqliteConnectOptions::new()
            .filename(&empty)
            .create_if_missing(true);
        let pool = sqlx::SqlitePool::connect_with(opts).await.unwrap();
        sqlx::query("CREATE TABLE t (x)")
            .execute(&pool)
            .await
            .unwrap();
        pool.close().await;
    });
    let (out, text) = verify(&empty);
    assert!(!out.status.success());
    assert!(
        text.contains("not a bdft-lab database: it has no audit log"),
        "{text}"
    );
}
