//! Copies of the database and what is read to check one: `VACUUM INTO` (a consistent
//! snapshot written while others go on writing), SQLite's integrity check, every table's row
//! count, the migrations a file holds, and the trials whose protocol hash is not their
//! study's.

use std::collections::BTreeMap;
use std::path::Path;

use sqlx::{AnyConnection, AnyExecutor};

use crate::error::{AppError, Result};

/// Writes a copy of the database to `out` (which must not exist): SQLite reads it in one read
/// transaction, so the copy is the database as one moment left it, whatever is written
/// meanwhile (WAL: writers are not held up), and compact (free pages left out).
pub async fn vacuum_into<'c>(db: impl AnyExecutor<'c>, out: &Path) -> Result<()> {
    let path = out.to_str().ok_or_else(|| {
        AppError::BadRequest(format!(
            "{}: the path is not valid UTF-8; choose another name",
            out.display()
        ))
    })?;
    sqlx::query("VACUUM INTO ?").bind(path).execute(db).await?;
    Ok(())
}

/// SQLite's `PRAGMA integrity_check`: `["ok"]`, or the problems it found (at most 100).
pub async fn integrity_check(db: &mut AnyConnection) -> Result<Vec<String>> {
    let rows: Vec<(String,)> = sqlx::query_as("PRAGMA integrity_check(100)")
        .fetch_all(db)
        .await?;
    Ok(rows.into_iter().map(|r| r.0).collect())
}

/// Every table's number of rows, by name (SQLite's own tables left out).
pub async fn row_counts(db: &mut AnyConnection) -> Result<BTreeMap<String, i64>> {
    let tables: Vec<(String,)> = sqlx::query_as(
        "SELECT name FROM sqlite_schema WHERE type = 'table' AND name NOT LIKE 'sqlite\\_%' ESCAPE '\\' ORDER BY name",
    )
    .fetch_all(&mut *db)
    .await?;
    let mut counts = BTreeMap::new();
    for (table,) in tables {
        // A name from the schema itself, quoted as an identifier.
        let (n,): (i64,) = sqlx::query_as(&format!(
            "SELECT count(*) FROM \"{}\"",
            table.replace('"', "\"\"")
        ))
        .fetch_one(&mut *db)
        .await?;
        counts.insert(table, n);
    }
    Ok(counts)
}

/// A migration a database file has applied.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AppliedMigration {
    pub version: i64,
    pub description: String,
    pub checksum: Vec<u8>,
}

/// The migrations the file has applied, oldest first (none for a file that is not a
/// database of this program).
pub async fn applied_migrations(db: &mut AnyConnection) -> Result<Vec<AppliedMigration>> {
    let has_table: Option<(String,)> = sqlx::query_as(
        "SELECT name FROM sqlite_schema WHERE type = 'table' AND name = '_sqlx_migrations'",
    )
    .fetch_optional(&mut *db)
    .await?;
    if has_table.is_none() {
        return Ok(Vec::new());
    }
    let rows: Vec<(i64, String, Vec<u8>)> = sqlx::query_as(
        "SELECT version, description, checksum FROM _sqlx_migrations WHERE success ORDER BY version",
    )
    .fetch_all(db)
    .await?;
    Ok(rows
        .into_iter()
        .map(|(version, description, checksum)| AppliedMigration {
            version,
            description,
            checksum,
        })
        .collect())
}

/// Each locked study's id, stored parameters (JSON) and protocol hash.
pub async fn locked_studies<'c>(db: impl AnyExecutor<'c>) -> Result<Vec<(i64, String, String)>> {
    Ok(sqlx::query_as(
        "SELECT id, params_json, protocol_hash FROM studies WHERE protocol_hash IS NOT NULL ORDER BY id",
    )
    .fetch_all(db)
    .await?)
}

/// The consent forms the locks kept (migration 0030): (study, text, its stored SHA-256).
pub async fn locked_consent_forms<'c>(
    db: impl AnyExecutor<'c>,
) -> Result<Vec<(i64, String, String)>> {
    Ok(sqlx::query_as(
        "SELECT id, consent_text, consent_sha256 FROM studies WHERE consent_text IS NOT NULL ORDER BY id",
    )
    .fetch_all(db)
    .await?)
}

/// Trials that carry a protocol hash other than their study's: (trial, study).
pub async fn trials_off_their_protocol<'c>(db: impl AnyExecutor<'c>) -> Result<Vec<(i64, i64)>> {
    Ok(sqlx::query_as(
        "SELECT t.id, st.id FROM trials t JOIN subjects s ON s.id = t.subject_id JOIN studies st ON st.id = s.study_id \
         WHERE t.protocol_hash IS NOT NULL AND t.protocol_hash IS NOT st.protocol_hash ORDER BY t.id",
    )
    .fetch_all(db)
    .await?)
}

/// The number of trials that carry a protocol hash.
pub async fn hashed_trials<'c>(db: impl AnyExecutor<'c>) -> Result<i64> {
    let (n,): (i64,) =
        sqlx::query_as("SELECT count(*) FROM trials WHERE protocol_hash IS NOT NULL")
            .fetch_one(db)
            .await?;
    Ok(n)
}

/// Rows of the audit log.
pub async fn audit_rows<'c>(db: impl AnyExecutor<'c>) -> Result<i64> {
    let (n,): (i64,) = sqlx::query_as("SELECT count(*) FROM audit_log")
        .fetch_one(db)
        .await?;
    Ok(n)
}

/// The last migration the database has applied.
pub async fn schema_version<'c>(db: impl AnyExecutor<'c>) -> Result<i64> {
    let (v,): (i64,) =
        sqlx::query_as("SELECT COALESCE(MAX(version), 0) FROM _sqlx_migrations WHERE success")
            .fetch_one(db)
            .await?;
    Ok(v)
}
