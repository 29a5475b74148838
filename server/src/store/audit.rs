//! The audit log: append-only (SQL triggers refuse UPDATE and DELETE). Rows are written by
//! [`super::Change::commit`], inside the transaction of the change they record.

use serde::Serialize;
use serde_json::Value;
use sqlx::{SqliteConnection, SqliteExecutor};

use super::db::{now_ms, rfc3339};
use crate::error::Result;

pub(super) async fn append(
    db: &mut SqliteConnection,
    actor: &str,
    action: &str,
    target: Option<String>,
    detail: &Value,
) -> Result<()> {
    sqlx::query(
        "INSERT INTO audit_log (at, actor, action, target, detail_json) VALUES (?, ?, ?, ?, ?)",
    )
    .bind(now_ms())
    .bind(actor)
    .bind(action)
    .bind(target)
    .bind(detail.to_string())
    .execute(db)
    .await?;
    Ok(())
}

/// One row of the audit log as the dashboard shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct AuditEntry {
    pub id: i64,
    /// RFC 3339 UTC with milliseconds.
    pub at: String,
    pub actor: String,
    pub action: String,
    pub target: Option<String>,
    #[schema(value_type = Object)]
    pub detail: Option<Value>,
}

/// id, at, actor, action, target, detail_json
pub type AuditRow = (i64, i64, String, String, Option<String>, Option<String>);

/// Up to `limit` rows after the row `after`, oldest first, with `at` in ms (an export reads
/// the whole log page by page).
pub async fn page<'c>(
    db: impl SqliteExecutor<'c>,
    after: i64,
    limit: i64,
) -> Result<Vec<AuditRow>> {
    Ok(sqlx::query_as(
        "SELECT id, at, actor, action, target, detail_json FROM audit_log WHERE id > ? ORDER BY id LIMIT ?",
    )
    .bind(after)
    .bind(limit)
    .fetch_all(db)
    .await?)
}

/// The newest `limit` rows, newest first.
pub async fn newest<'c>(db: impl SqliteExecutor<'c>, limit: i64) -> Result<Vec<AuditEntry>> {
    let rows: Vec<AuditRow> = sqlx::query_as(
        "SELECT id, at, actor, action, target, detail_json FROM audit_log ORDER BY id DESC LIMIT ?",
    )
    .bind(limit)
    .fetch_all(db)
    .await?;
    Ok(rows
        .into_iter()
        .map(|(id, at, actor, action, target, detail)| AuditEntry {
            id,
            at: rfc3339(at),
            actor,
            action,
            target,
            detail: detail.and_then(|d| serde_json::from_str(&d).ok()),
        })
        .collect())
}
