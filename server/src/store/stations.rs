//! Stations: the paired computers at the seats (on the machine, at the desk, or one serving
//! both), each with its bearer token's hash and the subject assigned to it.

use bdft_protocol::records::StationRole;
use serde::Serialize;
use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use super::tokens::token_hash;
use crate::error::{AppError, Result};

#[derive(Debug, Clone, Serialize, sqlx::FromRow, utoipa::ToSchema)]
pub struct Station {
    pub id: i64,
    pub study_id: i64,
    pub name: String,
    /// Which seats it serves.
    #[sqlx(try_from = "String")]
    pub role: StationRole,
    pub subject_id: Option<i64>,
    /// The site it is at (`serve --site`); none for a station paired before sites existed,
    /// which is at the server's first site.
    pub site: Option<String>,
}

const COLUMNS: &str = "id, study_id, name, role, subject_id, site";

pub async fn get<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<Station> {
    sqlx::query_as(&format!("SELECT {COLUMNS} FROM stations WHERE id = $1"))
        .bind(id)
        .fetch_optional(db)
        .await?
        .ok_or(AppError::NotFound("station"))
}

/// The station whose bearer token this is.
pub async fn by_token<'c>(db: impl AnyExecutor<'c>, token: &str) -> Result<Option<Station>> {
    Ok(sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM stations WHERE token_hash = $1"
    ))
    .bind(token_hash(token))
    .fetch_optional(db)
    .await?)
}

pub async fn of_study<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<Vec<Station>> {
    Ok(sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM stations WHERE study_id = $1 ORDER BY id"
    ))
    .bind(study_id)
    .fetch_all(db)
    .await?)
}

/// Every station with a subject assigned.
pub async fn assigned<'c>(db: impl AnyExecutor<'c>) -> Result<Vec<Station>> {
    Ok(sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM stations WHERE subject_id IS NOT NULL ORDER BY id"
    ))
    .fetch_all(db)
    .await?)
}

/// The stations a subject is assigned to.
pub async fn of_subject<'c>(db: impl AnyExecutor<'c>, subject_id: i64) -> Result<Vec<Station>> {
    Ok(sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM stations WHERE subject_id = $1 ORDER BY id"
    ))
    .bind(subject_id)
    .fetch_all(db)
    .await?)
}

/// Stores a newly paired station; returns its id.
pub async fn insert(
    db: &mut AnyConnection,
    study_id: i64,
    name: &str,
    role: StationRole,
    site: &str,
    token: &str,
    pairing_code: &str,
) -> Result<i64> {
    let now = now_ms();
    Ok(sqlx::query_scalar::<_, i64>("INSERT INTO stations (study_id, name, role, site, token_hash, pairing_code, paired_at, created_at) VALUES ($1, $2, $3, $4, $5, $6, $7, $8) RETURNING id")
        .bind(study_id)
        .bind(name)
        .bind(role.as_str())
        .bind(site)
        .bind(token_hash(token))
        .bind(pairing_code)
        .bind(now)
        .bind(now)
        .fetch_one(db)
        .await?)
}

/// Assigns a subject to the station (or none).
pub async fn assign(db: &mut AnyConnection, id: i64, subject_id: Option<i64>) -> Result<()> {
    sqlx::query("UPDATE stations SET subject_id = $1 WHERE id = $2")
        .bind(subject_id)
        .bind(id)
        .execute(db)
        .await?;
    Ok(())
}
