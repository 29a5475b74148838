//! The multi-site store's two dialects agree: the PostgreSQL migrations
//! (`migrations/postgres/`) give the schema the SQLite ones (`migrations/`) give, as the
//! server opens it — the same tables; each column with its type (SQLite's INTEGER, REAL,
//! TEXT, BLOB as BIGINT, DOUBLE PRECISION, TEXT, BYTEA), nullability, default and primary
//! key; the same foreign keys, unique sets, named indexes and triggers — and the rules the
//! triggers and constraints keep refuse the same statements, a trigger with the same message.
//! A migration added in one dialect only fails here.
//!
//! Against the PostgreSQL server the test command starts (`scripts/test.sh`:
//! `BDFT_TEST_POSTGRES`, a Unix socket); each test makes a database of its own there. Without
//! that server the test fails, naming the variable: it never skips.

use std::collections::BTreeSet;

use bdft_tests::TempDir;
use bdft_tests::postgres::PgDatabase;
use sqlx::error::ErrorKind;
use sqlx::postgres::PgPool;
use sqlx::{Row, SqlitePool};

/// A column as both dialects can say it.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct Column {
    table: String,
    name: String,
    /// integer, real, text or blob.
    kind: String,
    not_null: bool,
    default: Option<String>,
    primary_key: bool,
}

/// A foreign key: (table, column) → (table, column).
type ForeignKey = (String, String, String, String);

/// An index: its table, columns in order, whether unique, and its name when it was made by
/// CREATE INDEX (an index a constraint made has a name each dialect invents).
type Index = (String, Vec<String>, bool, Option<String>);

#[derive(Debug, PartialEq)]
struct Schema {
    tables: BTreeSet<String>,
    columns: BTreeSet<Column>,
    foreign_keys: BTreeSet<ForeignKey>,
    indexes: BTreeSet<Index>,
    /// (table, trigger name).
    triggers: BTreeSet<(String, String)>,
}

/// The bookkeeping tables of sqlx and SQLite, not the store's.
fn is_store_table(name: &str) -> bool {
    name != "_sqlx_migrations" && !name.starts_with("sqlite_")
}

fn strings<R: Row>(rows: &[R], i: usize) -> Vec<String>
where
    for<'r> String: sqlx::Decode<'r, R::Database> + sqlx::Type<R::Database>,
    usize: sqlx::ColumnIndex<R>,
{
    rows.iter().map(|r| r.get::<String, _>(i)).collect()
}

async fn sqlite_schema(pool: &SqlitePool) -> Schema {
    let tables: BTreeSet<String> = strings(
        &sqlx::query("SELECT name FROM sqlite_master WHERE type = 'table'")
            .fetch_all(pool)
            .await
            .unwrap(),
        0,
    )
    .into_iter()
    .filter(|t| is_store_table(t))
    .collect();
    let mut columns = BTreeSet::new();
    let mut foreign_keys = BTreeSet::new();
    let mut indexes = BTreeSet::new();
    for t in &tables {
        for r in
            sqlx::query("SELECT name, type, \"notnull\", dflt_value, pk FROM pragma_table_info(?1)")
                .bind(t)
                .fetch_all(pool)
                .await
                .unwrap()
        {
            let declared: String = r.get(1);
            let pk = r.get::<i64, _>(4) > 0;
            columns.insert(Column {
                table: t.clone(),
                name: r.get(0),
                kind: match declared.to_uppercase().as_str() {
                    "INTEGER" => "integer",
                    "REAL" => "real",
                    "TEXT" => "text",
                    "BLOB" => "blob",
                    other => panic!("{t}: a column of SQLite type {other}"),
                }
                .into(),
                // A primary key holds no NULL in intent (SQLite alone lets a TEXT key be
                // NULL, a bug it keeps for compatibility).
                not_null: r.get::<i64, _>(2) == 1 || pk,
                default: r.get(3),
                primary_key: pk,
            });
        }
        for r in sqlx::query("SELECT \"from\", \"table\", \"to\" FROM pragma_foreign_key_list(?1)")
            .bind(t)
            .fetch_all(pool)
            .await
            .unwrap()
        {
            let to_table: String = r.get(1);
            foreign_keys.insert((
                t.clone(),
                r.get(0),
                to_table.trim_matches('"').to_string(),
                r.get(2),
            ));
        }
        for r in sqlx::query("SELECT name, \"unique\", origin FROM pragma_index_list(?1)")
            .bind(t)
            .fetch_all(pool)
            .await
            .unwrap()
        {
            let (name, origin): (String, String) = (r.get(0), r.get(2));
            if origin == "pk" {
                continue;
            }
            let cols = strings(
                &sqlx::query("SELECT name FROM pragma_index_info(?1) ORDER BY seqno")
                    .bind(&name)
                    .fetch_all(pool)
                    .await
                    .unwrap(),
                0,
            );
            indexes.insert((
                t.clone(),
                cols,
                r.get::<i64, _>(1) == 1,
                (origin == "c").then_some(name),
            ));
        }
    }
    let triggers = sqlx::query("SELECT tbl_name, name FROM sqlite_master WHERE type = 'trigger'")
        .fetch_all(pool)
        .await
        .unwrap()
        .iter()
        .map(|r| (r.get(0), r.get(1)))
        .collect();
    Schema {
        tables,
        columns,
        foreign_keys,
        indexes,
        triggers,
    }
}

async fn postgres_schema(pool: &PgPool) -> Schema {
    let tables: BTreeSet<String> = strings(
        &sqlx::query(
            "SELECT table_name::text FROM information_schema.tables \
             WHERE table_schema = 'public' AND table_type = 'BASE TABLE'",
        )
        .fetch_all(pool)
        .await
        .unwrap(),
        0,
    )
    .into_iter()
    .filter(|t| is_store_table(t))
    .collect();
    let primary: BTreeSet<(String, String)> = sqlx::query(
        "SELECT c.relname::text, a.attname::text FROM pg_index i \
         JOIN pg_class c ON c.oid = i.indrelid \
         JOIN pg_attribute a ON a.attrelid = i.indrelid AND a.attnum = ANY(i.indkey) \
         WHERE i.indisprimary AND c.relnamespace = 'public'::regnamespace",
    )
    .fetch_all(pool)
    .await
    .unwrap()
    .iter()
    .map(|r| (r.get(0), r.get(1)))
    .collect();
    let columns = sqlx::query(
        "SELECT table_name::text, column_name::text, data_type::text, is_nullable::text, \
                column_default::text \
         FROM information_schema.columns WHERE table_schema = 'public'",
    )
    .fetch_all(pool)
    .await
    .unwrap()
    .iter()
    .filter(|r| is_store_table(&r.get::<String, _>(0)))
    .map(|r| {
        let (table, name, data_type): (String, String, String) = (r.get(0), r.get(1), r.get(2));
        let default: Option<String> = r.get(4);
        Column {
            primary_key: primary.contains(&(table.clone(), name.clone())),
            kind: match data_type.as_str() {
                "bigint" => "integer",
                "double precision" => "real",
                "text" => "text",
                "bytea" => "blob",
                other => panic!("{table}.{name}: PostgreSQL type {other} has no SQLite twin"),
            }
            .into(),
            not_null: r.get::<String, _>(3) == "NO",
            // '…'::text is how PostgreSQL keeps a text literal.
            default: default.map(|d| d.trim_end_matches("::text").to_string()),
            table,
            name,
        }
    })
    .collect();
    let foreign_keys = sqlx::query(
        "SELECT cl.relname::text, a.attname::text, rcl.relname::text, ra.attname::text, \
                array_length(c.conkey, 1) \
         FROM pg_constraint c \
         JOIN pg_class cl ON cl.oid = c.conrelid \
         JOIN pg_class rcl ON rcl.oid = c.confrelid \
         JOIN pg_attribute a ON a.attrelid = c.conrelid AND a.attnum = c.conkey[1] \
         JOIN pg_attribute ra ON ra.attrelid = c.confrelid AND ra.attnum = c.confkey[1] \
         WHERE c.contype = 'f' AND cl.relnamespace = 'public'::regnamespace",
    )
    .fetch_all(pool)
    .await
    .unwrap()
    .iter()
    .map(|r| {
        assert_eq!(r.get::<i32, _>(4), 1, "a foreign key of one column");
        (r.get(0), r.get(1), r.get(2), r.get(3))
    })
    .collect();
    let indexes = sqlx::query(
        "SELECT t.relname::text, ix.relname::text, i.indisunique, \
                EXISTS (SELECT 1 FROM pg_constraint c WHERE c.conindid = i.indexrelid), \
                ARRAY(SELECT a.attname::text FROM unnest(i.indkey) WITH ORDINALITY k(n, o) \
                      JOIN pg_attribute a ON a.attrelid = i.indrelid AND a.attnum = k.n \
                      ORDER BY k.o) \
         FROM pg_index i JOIN pg_class t ON t.oid = i.indrelid \
         JOIN pg_class ix ON ix.oid = i.indexrelid \
         WHERE NOT i.indisprimary AND t.relnamespace = 'public'::regnamespace",
    )
    .fetch_all(pool)
    .await
    .unwrap()
    .iter()
    .filter(|r| is_store_table(&r.get::<String, _>(0)))
    .map(|r| {
        let by_constraint: bool = r.get(3);
        (
            r.get(0),
            r.get::<Vec<String>, _>(4),
            r.get(2),
            (!by_constraint).then(|| r.get(1)),
        )
    })
    .collect();
    let triggers = sqlx::query(
        "SELECT c.relname::text, t.tgname::text FROM pg_trigger t \
         JOIN pg_class c ON c.oid = t.tgrelid \
         WHERE NOT t.tgisinternal AND c.relnamespace = 'public'::regnamespace",
    )
    .fetch_all(pool)
    .await
    .unwrap()
    .iter()
    .map(|r| (r.get(0), r.get(1)))
    .collect();
    Schema {
        tables,
        columns,
        foreign_keys,
        indexes,
        triggers,
    }
}

/// Asserts two sets equal, naming what only one side has.
fn same<T: Ord + std::fmt::Debug>(what: &str, sqlite: &BTreeSet<T>, postgres: &BTreeSet<T>) {
    let only_sqlite: Vec<_> = sqlite.difference(postgres).collect();
    let only_postgres: Vec<_> = postgres.difference(sqlite).collect();
    assert!(
        only_sqlite.is_empty() && only_postgres.is_empty(),
        "{what} differ:\n  only in SQLite:     {only_sqlite:#?}\n  only in PostgreSQL: {only_postgres:#?}"
    );
}

/// A fresh SQLite store, made as the server makes it (migrated, its log chained), then
/// reopened through SQLite's own driver, whose rows name the declared column types.
async fn sqlite_store(dir: &TempDir) -> SqlitePool {
    let path = dir.path().join("store.db");
    bdft_server::store::db::open(&path)
        .await
        .unwrap()
        .close()
        .await;
    SqlitePool::connect_with(
        sqlx::sqlite::SqliteConnectOptions::new()
            .filename(&path)
            .foreign_keys(true),
    )
    .await
    .unwrap()
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

#[test]
fn both_dialects_migrate_to_the_same_schema() {
    runtime().block_on(async {
        let dir = TempDir::new("dialects");
        let sqlite = sqlite_schema(&sqlite_store(&dir).await).await;
        let pg = PgDatabase::new("schema").await;
        let pool = pg.migrated().await;
        let postgres = postgres_schema(&pool).await;
        pool.close().await;
        // The comparison can fail: the store has its tables, keys and rules.
        assert!(sqlite.tables.len() >= 24, "{:?}", sqlite.tables);
        assert!(sqlite.triggers.len() >= 14, "{:?}", sqlite.triggers);
        same("tables", &sqlite.tables, &postgres.tables);
        same("columns", &sqlite.columns, &postgres.columns);
        same("foreign keys", &sqlite.foreign_keys, &postgres.foreign_keys);
        same("indexes", &sqlite.indexes, &postgres.indexes);
        same("triggers", &sqlite.triggers, &postgres.triggers);
        assert_eq!(sqlite, postgres);
    });
}

/// The migrations' numbers in `dir` (the files' leading digits).
fn versions(dir: &str) -> BTreeSet<u32> {
    std::fs::read_dir(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(dir))
        .unwrap()
        .filter_map(|e| {
            let name = e.unwrap().file_name().into_string().unwrap();
            name.ends_with(".sql")
                .then(|| name.split('_').next().unwrap().parse().unwrap())
        })
        .collect()
}

/// PostgreSQL's first migration is SQLite's schema after `POSTGRES_BASE`; every migration
/// after it comes in both dialects under one number.
const POSTGRES_BASE: u32 = 26;

#[test]
fn every_migration_after_the_base_comes_in_both_dialects() {
    let sqlite = versions("../migrations");
    let postgres = versions("../migrations/postgres");
    assert_eq!(postgres.first(), Some(&POSTGRES_BASE), "{postgres:?}");
    assert!(sqlite.contains(&POSTGRES_BASE), "{sqlite:?}");
    let after =
        |v: &BTreeSet<u32>| -> BTreeSet<u32> { v.range(POSTGRES_BASE + 1..).copied().collect() };
    same(
        "migrations after the base",
        &after(&sqlite),
        &after(&postgres),
    );
}

/// What a statement did: the rows a query gave (one text column), or why it was refused —
/// a trigger's message, or the kind of constraint it broke (the dialects word those
/// differently).
#[derive(Debug, Clone, PartialEq)]
enum Outcome {
    Done(Vec<Option<String>>),
    Refused(String),
    Breaks(String),
}

fn outcome<R: Row>(result: Result<Vec<R>, sqlx::Error>) -> Outcome
where
    for<'r> Option<String>: sqlx::Decode<'r, R::Database> + sqlx::Type<R::Database>,
    usize: sqlx::ColumnIndex<R>,
{
    match result {
        Ok(rows) => Outcome::Done(rows.iter().map(|r| r.get::<Option<String>, _>(0)).collect()),
        Err(e) => match e.as_database_error() {
            Some(d) if matches!(d.kind(), ErrorKind::Other) => {
                Outcome::Refused(d.message().to_string())
            }
            Some(d) => Outcome::Breaks(format!("{:?}", d.kind())),
            None => panic!("not an answer of the database: {e}"),
        },
    }
}

const TRIAL: &str = "INSERT INTO trials (id, subject_id, slot, station, block, position, \
    controller, blinded_label, compensator_json, k_bf, duration_s, target_seed, \
    target_levels_json, target_mean_mm, target_std_mm, queue_order) VALUES ";
const REDACT: &str =
    "UPDATE audit_log SET detail_json = '{\"erasure\":5,\"redacted\":\"subject.erase\"}'";

/// Statements and what each must do, in order, on a fresh store: every rule a trigger or
/// constraint keeps, each broken once and kept once.
fn script() -> Vec<(String, Outcome)> {
    use Outcome::{Breaks, Done, Refused};
    let ok = || Done(vec![]);
    let erased_no_change = "the subject's data were erased; an erased subject does not change";
    let append_only = "audit_log is append-only (only an erasure redacts the details of the rows about its subject)";
    let immutable = "a configuration version is immutable; create a new version";
    let s = |sql: &str| sql.to_string();
    vec![
        // The one row a fresh store holds: the E-stop latch, released.
        (
            s("SELECT CAST(id AS TEXT) || ':' || CAST(latched AS TEXT) FROM estop_latch"),
            Done(vec![Some("1:0".into())]),
        ),
        (
            s(
                "INSERT INTO experimenters (id, username, password_hash, created_at) VALUES (1, 'alice', 'h', 0)",
            ),
            ok(),
        ),
        (
            s(
                "INSERT INTO experimenters (id, username, password_hash, created_at, role) VALUES (2, 'bob', 'h', 0, 'boss')",
            ),
            Breaks("CheckViolation".into()),
        ),
        (
            s(
                "INSERT INTO experimenters (id, username, password_hash, created_at) VALUES (3, 'alice', 'h', 0)",
            ),
            Breaks("UniqueViolation".into()),
        ),
        (
            s("INSERT INTO audit_log (id, at, actor, action) VALUES (1, 0, 'alice', 'login')"),
            Refused("audit actor is neither an account nor a described non-person actor".into()),
        ),
        (
            s(
                "INSERT INTO audit_log (id, at, actor, actor_id, action) VALUES (1, 0, 'alice', 1, 'login')",
            ),
            ok(),
        ),
        (
            s(
                "INSERT INTO audit_log (id, at, actor, action, target) VALUES (2, 0, 'system:pilot', 'study.create', 'study:1')",
            ),
            ok(),
        ),
        (
            s("UPDATE audit_log SET actor = 'mallory' WHERE id = 1"),
            Refused(append_only.into()),
        ),
        (
            s("DELETE FROM audit_log WHERE id = 1"),
            Refused("audit_log is append-only".into()),
        ),
        (
            s(
                "INSERT INTO studies (id, name, params_json, seed, created_at, locked_at) VALUES (1, 's', '{}', 7, 0, 5)",
            ),
            ok(),
        ),
        (
            s("UPDATE studies SET seed = 8 WHERE id = 1"),
            Refused("the study protocol is locked".into()),
        ),
        (s("UPDATE studies SET name = 't' WHERE id = 1"), ok()),
        (
            s(
                "INSERT INTO subjects (id, study_id, code, enrol_index, token_hash, starting_station, created_at) VALUES (1, 9, 'S01', 0, 'tk1', 'on', 0)",
            ),
            Breaks("ForeignKeyViolation".into()),
        ),
        (
            s(
                "INSERT INTO subjects (id, study_id, code, enrol_index, token_hash, starting_station, created_at) VALUES (1, 1, 'S01', 0, 'tk1', 'on', 0)",
            ),
            ok(),
        ),
        (
            s(
                "INSERT INTO compensator_configs (id, name, version, kind, spec_json, created_at) VALUES (1, 'lqr-a', 1, 'lqr', '{\"lqr\":1}', 0)",
            ),
            ok(),
        ),
        (
            s(
                "INSERT INTO compensator_configs (id, name, version, kind, spec_json, created_at) VALUES (2, 'lqr-a', 0, 'lqr', '{}', 0)",
            ),
            Breaks("CheckViolation".into()),
        ),
        (
            s("INSERT INTO study_configs (study_id, kind, config_id) VALUES (1, 'lqr', 1)"),
            ok(),
        ),
        (
            s("UPDATE compensator_configs SET name = 'b' WHERE id = 1"),
            Refused(immutable.into()),
        ),
        (
            s("DELETE FROM compensator_configs WHERE id = 1"),
            Refused(immutable.into()),
        ),
        (
            format!(
                "{TRIAL}(1, 1, 0, 'on', 0, 0, 'lqr', 'A', '{{\"lqr\":1}}', 0.78, 140, 1, '[]', 0, 1, 0)"
            ),
            ok(),
        ),
        // The trial names the configuration version its design came from; a design of no
        // version names none.
        (
            s("SELECT CAST(config_id AS TEXT) FROM trials WHERE id = 1"),
            Done(vec![Some("1".into())]),
        ),
        (
            format!(
                "{TRIAL}(2, 1, 1, 'on', 0, 1, 'lqr', 'B', '{{\"lqr\":2}}', 0.78, 140, 2, '[]', 0, 1, 1)"
            ),
            ok(),
        ),
        (
            s("SELECT CAST(config_id AS TEXT) FROM trials WHERE id = 2"),
            Done(vec![None]),
        ),
        (
            format!(
                "{TRIAL}(3, 1, 2, 'sideways', 0, 2, 'pid', 'C', '{{}}', 0.78, 140, 3, '[]', 0, 1, 2)"
            ),
            Breaks("CheckViolation".into()),
        ),
        (
            format!(
                "{TRIAL}(3, 1, 0, 'on', 0, 2, 'pid', 'C', '{{}}', 0.78, 140, 3, '[]', 0, 1, 2)"
            ),
            Breaks("UniqueViolation".into()),
        ),
        (
            s("UPDATE trials SET personalized = 2 WHERE id = 1"),
            Breaks("CheckViolation".into()),
        ),
        (
            s(
                "INSERT INTO identifications (trial_id, subject_id, points_json, created_at) VALUES (1, 1, '[]', 0)",
            ),
            Breaks("CheckViolation".into()),
        ),
        (
            s("INSERT INTO estop_latch (id, latched, changed_at) VALUES (2, 1, 0)"),
            Breaks("CheckViolation".into()),
        ),
        (
            s(
                "INSERT INTO audit_log (id, at, actor, actor_id, action, target, detail_json) VALUES (3, 0, 'alice', 1, 'trial.start', 'trial:1', '{\"n\":1}')",
            ),
            ok(),
        ),
        (
            s(
                "INSERT INTO audit_log (id, at, actor, actor_id, action, target, detail_json) VALUES (4, 0, 'alice', 1, 'note.add', 'study:1', '{\"subject_id\":1}')",
            ),
            ok(),
        ),
        // Erasure: only together with its audit row, then final.
        (
            s("UPDATE subjects SET erased_at = 10 WHERE id = 1"),
            Refused("a subject is erased only together with its subject.erase audit row".into()),
        ),
        (
            s(
                "INSERT INTO audit_log (id, at, actor, actor_id, action, target, detail_json) VALUES (5, 10, 'alice', 1, 'subject.erase', 'subject:1', '{\"reason\":\"asked\"}')",
            ),
            ok(),
        ),
        (s("UPDATE subjects SET erased_at = 10 WHERE id = 1"), ok()),
        (
            s("UPDATE subjects SET code = 'S99' WHERE id = 1"),
            Refused(erased_no_change.into()),
        ),
        (
            format!(
                "{TRIAL}(4, 1, 3, 'on', 0, 3, 'pid', 'D', '{{}}', 0.78, 140, 4, '[]', 0, 1, 3)"
            ),
            Refused("the subject's data were erased; an erased subject gets no tests".into()),
        ),
        // The one exception to the append-only log: the erasure's marker on the older rows
        // about its subject (by target, by trial, by the details' subject_id), and only there.
        (format!("{REDACT} WHERE id = 3"), ok()),
        (format!("{REDACT} WHERE id = 4"), ok()),
        (
            format!("{REDACT} WHERE id = 2"),
            Refused(append_only.into()),
        ),
        (
            format!("{REDACT} WHERE id = 5"),
            Refused(append_only.into()),
        ),
        (
            s(
                "UPDATE audit_log SET detail_json = '{\"erasure\":5,\"redacted\":\"other\"}' WHERE id = 1",
            ),
            Refused(append_only.into()),
        ),
        (
            s("SELECT detail_json FROM audit_log ORDER BY id"),
            Done(vec![
                None,
                None,
                Some("{\"erasure\":5,\"redacted\":\"subject.erase\"}".into()),
                Some("{\"erasure\":5,\"redacted\":\"subject.erase\"}".into()),
                Some("{\"reason\":\"asked\"}".into()),
            ]),
        ),
        (
            s(
                "INSERT INTO audit_chain (entry_id, prev_hash, detail_hash, hash) VALUES (1, 'a', 'b', 'c')",
            ),
            ok(),
        ),
        (
            s(
                "INSERT INTO audit_chain (entry_id, prev_hash, detail_hash, hash, chained_late) VALUES (2, 'a', 'b', 'c', 2)",
            ),
            Breaks("CheckViolation".into()),
        ),
        (
            s("UPDATE audit_chain SET hash = 'd'"),
            Refused("audit_chain is append-only".into()),
        ),
        (
            s("DELETE FROM audit_chain"),
            Refused("audit_chain is append-only".into()),
        ),
        (
            s(
                "INSERT INTO audit_checkpoints (id, entry_id, head_hash, at, public_key, signature) VALUES (1, 1, 'c', 0, 'k', 's')",
            ),
            ok(),
        ),
        (
            s("UPDATE audit_checkpoints SET signature = 't'"),
            Refused("audit_checkpoints is append-only".into()),
        ),
        (
            s("DELETE FROM audit_checkpoints"),
            Refused("audit_checkpoints is append-only".into()),
        ),
    ]
}

#[test]
fn both_dialects_refuse_what_the_stores_rules_refuse() {
    runtime().block_on(async {
        let dir = TempDir::new("dialect-rules");
        let sqlite = sqlite_store(&dir).await;
        let pg = PgDatabase::new("rules").await;
        let postgres = pg.migrated().await;
        for (sql, want) in script() {
            let on_sqlite = outcome(sqlx::query(&sql).fetch_all(&sqlite).await);
            let on_postgres = outcome(sqlx::query(&sql).fetch_all(&postgres).await);
            assert_eq!(on_sqlite, want, "SQLite: {sql}");
            assert_eq!(on_postgres, want, "PostgreSQL: {sql}");
        }
        postgres.close().await;
    });
}

/// The server's own store code on PostgreSQL (`--db postgres://…`): it migrates a fresh
/// database with the PostgreSQL migrations and chains its log; a change commits with its
/// audit row under the write lock; flags are written and read as integers; a study's
/// parameters round-trip; opening it again changes nothing.
#[test]
fn the_servers_store_runs_on_postgres() {
    use bdft_server::store::{self, db::Location};
    runtime().block_on(async {
        let pg = PgDatabase::new("server").await;
        let url = pg.url();
        let at: Location = url.parse().unwrap();
        assert_eq!(
            at,
            Location::Postgres(url),
            "a postgres:// URL names PostgreSQL"
        );
        let pool = store::db::open_location(&at, None).await.unwrap();
        let none: (bool, Vec<String>) = (false, vec![]);
        assert_eq!(store::latch::stored(&pool).await.unwrap(), none);
        let params = bdft_server::engine::study::schedule::default_params();
        let mut change = store::Change::begin(&pool, "system:dialect-test")
            .await
            .unwrap();
        let id = store::studies::insert(change.db(), "on postgres", &params, 7)
            .await
            .unwrap();
        store::latch::set_site(change.db(), "lab-a", true)
            .await
            .unwrap();
        // Set twice: the site's row is written over, not added again.
        store::latch::set_site(change.db(), "lab-a", true)
            .await
            .unwrap();
        change
            .commit(
                "study.create",
                Some(format!("study:{id}")),
                store::audit::NoDetail {},
            )
            .await
            .unwrap();
        assert_eq!(
            store::latch::stored(&pool).await.unwrap(),
            (false, vec!["lab-a".to_string()])
        );
        // The latch of every site latches each; its reset clears each site's own too.
        let mut change = store::Change::begin(&pool, "system:dialect-test")
            .await
            .unwrap();
        store::latch::set_all(change.db(), true).await.unwrap();
        change
            .commit("estop", None, store::audit::NoDetail {})
            .await
            .unwrap();
        assert!(store::latch::stored(&pool).await.unwrap().0);
        let mut change = store::Change::begin(&pool, "system:dialect-test")
            .await
            .unwrap();
        store::latch::set_all(change.db(), false).await.unwrap();
        change
            .commit("estop.reset", None, store::audit::NoDetail {})
            .await
            .unwrap();
        assert_eq!(store::latch::stored(&pool).await.unwrap(), none);
        let study = store::studies::get(&pool, id).await.unwrap();
        assert_eq!((study.name.as_str(), study.seed), ("on postgres", 7));
        assert_eq!(study.params, params);
        let audited: Vec<(String, Option<String>, String)> =
            sqlx::query_as("SELECT action, target, actor FROM audit_log ORDER BY id")
                .fetch_all(&pool)
                .await
                .unwrap();
        let entry = |action: &str, target: Option<String>| {
            (
                action.to_string(),
                target,
                "system:dialect-test".to_string(),
            )
        };
        assert_eq!(
            audited,
            [
                entry("study.create", Some(format!("study:{id}"))),
                entry("estop", None),
                entry("estop.reset", None)
            ]
        );
        let chained: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM audit_chain")
            .fetch_one(&pool)
            .await
            .unwrap();
        assert_eq!(chained, 3, "the entries joined the hash chain");
        pool.close().await;
        let again = store::db::open_location(&at, None).await.unwrap();
        assert_eq!(store::studies::all(&again).await.unwrap().len(), 1);
        again.close().await;
    });
}

/// A PostgreSQL store that cannot grant a lock in time answers as a busy SQLite store does
/// (503, "try again"), not as a bug; a statement that is wrong stays a bug.
#[test]
fn a_busy_postgres_store_is_unavailable_not_a_bug() {
    use bdft_server::error::AppError;
    use bdft_server::store::db::Location;
    runtime().block_on(async {
        let pg = PgDatabase::new("busy").await;
        let pool = bdft_server::store::db::open_location(&Location::Postgres(pg.url()), None)
            .await
            .unwrap();
        let mut holder = pool.begin().await.unwrap();
        sqlx::query("UPDATE estop_latch SET changed_at = 1 WHERE id = 1")
            .execute(&mut *holder)
            .await
            .unwrap();
        let mut waiter = pool.acquire().await.unwrap();
        sqlx::query("SET lock_timeout = '20ms'")
            .execute(&mut *waiter)
            .await
            .unwrap();
        let e = sqlx::query("UPDATE estop_latch SET changed_at = 2 WHERE id = 1")
            .execute(&mut *waiter)
            .await
            .unwrap_err();
        let e = AppError::from(e);
        assert!(
            matches!(&e, AppError::Unavailable(m) if m.contains("busy")),
            "{e:?}"
        );
        let wrong = sqlx::query("SELEC 1")
            .execute(&mut *waiter)
            .await
            .unwrap_err();
        assert!(matches!(AppError::from(wrong), AppError::Internal(_)));
        holder.rollback().await.unwrap();
        drop(waiter);
        pool.close().await;
    });
}
