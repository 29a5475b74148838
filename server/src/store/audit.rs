//! The audit log: append-only (SQL triggers refuse UPDATE and DELETE; the one exception is
//! an erasure replacing the details of the older rows about its subject by a redaction
//! marker, `store::erasure`). Rows are written by [`super::Change::commit`] (or
//! [`super::Change::audit_first`]), inside the transaction of the change they record.
//!
//! Every row names who made it. A logged-in account is named by its username, and the row
//! keeps the account's id (`actor_id`). The other actors say what they are, and each has a
//! ':' or a space, which usernames never have (a trigger refuses a row that is neither):
//! `subject:S01` (the subject, at a station or on their own page), `station:NAME`,
//! `system:WHAT` (the server itself: `system:startup`, `system:controller`, …),
//! `pilot (by NAME)` (a pilot run someone started), `anonymous:login` (a failed log-in).

use serde::Serialize;
use serde_json::Value;
use sqlx::{AnyConnection, AnyExecutor};

use super::db::{now_ms, rfc3339};
use crate::error::Result;

/// Appends a row; returns its id.
pub(super) async fn append(
    db: &mut AnyConnection,
    actor: &str,
    action: &str,
    target: Option<String>,
    detail: &str,
) -> Result<i64> {
    let (id, at, actor_id): (i64, i64, Option<i64>) = sqlx::query_as(
        "INSERT INTO audit_log (at, actor, actor_id, action, target, detail_json) VALUES ($1, $2, (SELECT id FROM experimenters WHERE username = $3), $4, $5, $6) RETURNING id, at, actor_id",
    )
    .bind(now_ms())
    .bind(actor)
    .bind(actor)
    .bind(action)
    .bind(&target)
    .bind(detail)
    .fetch_one(&mut *db)
    .await?;
    let entry = super::audit_chain::Entry {
        id,
        at,
        actor: actor.to_string(),
        actor_id,
        action: action.to_string(),
        target,
        detail_json: Some(detail.to_string()),
    };
    super::audit_chain::chain(db, &entry).await?;
    Ok(id)
}

/// The detail of an action that records nothing besides who did it and to what: `{}`.
#[derive(Debug, Serialize)]
pub struct NoDetail {}

/// The detail of an action whose record is the reason given for it (a trial aborted, found
/// invalid, accepted incomplete, or not started).
#[derive(Debug, Serialize)]
pub struct Reason<'a> {
    pub reason: &'a str,
}

/// One row of the audit log as the dashboard shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct AuditEntry {
    pub id: i64,
    /// RFC 3339 UTC with milliseconds.
    pub at: String,
    pub actor: String,
    /// The account that made the change; absent for the non-person actors.
    pub actor_id: Option<i64>,
    pub action: String,
    pub target: Option<String>,
    #[schema(value_type = Object)]
    pub detail: Option<Value>,
}

pub use super::audit_chain::AuditRow;

/// A field of an audit row's detail (JSON text), read here rather than in SQL: the two
/// stores' JSON functions differ, and a detail that is not an object has no fields.
pub fn detail_field(detail_json: &str, key: &str) -> Option<Value> {
    match serde_json::from_str::<Value>(detail_json) {
        Ok(Value::Object(mut fields)) => fields.remove(key),
        _ => None,
    }
}

/// The `reason` an audit row's detail carries, or "" when it has none.
pub fn reason_of(detail_json: &str) -> String {
    match detail_field(detail_json, "reason") {
        Some(Value::String(reason)) => reason,
        _ => String::new(),
    }
}

/// Up to `limit` rows after the row `after`, oldest first, with `at` in ms (an export reads
/// the whole log page by page).
pub async fn page<'c>(db: impl AnyExecutor<'c>, after: i64, limit: i64) -> Result<Vec<AuditRow>> {
    Ok(sqlx::query_as(
        "SELECT id, at, actor, actor_id, action, target, detail_json FROM audit_log WHERE id > $1 ORDER BY id LIMIT $2",
    )
    .bind(after)
    .bind(limit)
    .fetch_all(db)
    .await?)
}

/// The newest `limit` rows, newest first.
pub async fn newest<'c>(db: impl AnyExecutor<'c>, limit: i64) -> Result<Vec<AuditEntry>> {
    let rows: Vec<AuditRow> = sqlx::query_as(
        "SELECT id, at, actor, actor_id, action, target, detail_json FROM audit_log ORDER BY id DESC LIMIT $1",
    )
    .bind(limit)
    .fetch_all(db)
    .await?;
    Ok(rows
        .into_iter()
        .map(
            |(id, at, actor, actor_id, action, target, detail)| AuditEntry {
                id,
                at: rfc3339(at),
                actor,
                actor_id,
                action,
                target,
                detail: detail.and_then(|d| serde_json::from_str(&d).ok()),
            },
        )
        .collect())
}
