//! How the server maps the database's refusals (`impl From<sqlx::Error> for AppError` in
//! `error`): tested here, beside the store, on a real SQLite database, so SQL stays in the
//! store.

use sqlx::{AnyConnection, Connection};

use crate::error::{AppError, ERASED};

/// The error SQLite gives for `statement` after `schema`, as the server maps it.
async fn mapped(schema: &str, statement: &str) -> AppError {
    crate::store::db::drivers();
    let mut db = AnyConnection::connect("sqlite::memory:").await.unwrap();
    sqlx::raw_sql(schema).execute(&mut db).await.unwrap();
    sqlx::query(statement)
        .execute(&mut db)
        .await
        .unwrap_err()
        .into()
}

#[tokio::test]
async fn a_row_removed_under_a_change_is_a_conflict() {
    let e = mapped(
        "PRAGMA foreign_keys = ON; CREATE TABLE trials (id INTEGER PRIMARY KEY); \
         CREATE TABLE surveys (trial_id INTEGER NOT NULL REFERENCES trials(id));",
        "INSERT INTO surveys (trial_id) VALUES (7)",
    )
    .await;
    assert!(
        matches!(&e, AppError::Conflict(m) if m.contains("removed")),
        "{e:?}"
    );
}

#[tokio::test]
async fn the_erasure_triggers_refusals_are_conflicts_other_triggers_are_not() {
    // Every refusal of migration 0021 about an erased subject, raised by a trigger as
    // the migration writes it.
    let migration = include_str!("../../../migrations/0021_erasure.sql");
    let raises: Vec<&str> = migration
        .split("RAISE(ABORT, ")
        .skip(1)
        .map(|rest| &rest[..rest.find("); END;").unwrap()])
        .filter(|message| message.contains("erased subject"))
        .collect();
    assert_eq!(raises.len(), 2, "{raises:?}");
    for message in raises {
        let e = mapped(
            &format!(
                "CREATE TABLE t (x); CREATE TRIGGER r BEFORE INSERT ON t \
                 BEGIN SELECT RAISE(ABORT, {message}); END;"
            ),
            "INSERT INTO t VALUES (1)",
        )
        .await;
        assert!(
            matches!(&e, AppError::Conflict(m) if m.starts_with(ERASED)),
            "{message}: {e:?}"
        );
    }
    let e = mapped(
        "CREATE TABLE t (x); CREATE TRIGGER r BEFORE INSERT ON t \
         BEGIN SELECT RAISE(ABORT, 'audit_log is append-only'); END;",
        "INSERT INTO t VALUES (1)",
    )
    .await;
    assert!(
        matches!(e, AppError::Internal(_)),
        "a bug stays a 500: {e:?}"
    );
}
