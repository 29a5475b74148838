//! Calibrated versions of a study's synthetic population (`population_versions`).

use bdft_protocol::params::PopulationParams;
use sqlx::AnyConnection;

use super::db::now_ms;
use crate::error::Result;

/// Stores `population` as the study's next version, with the report it came from; returns
/// the version.
pub async fn insert(
    db: &mut AnyConnection,
    study_id: i64,
    population: &PopulationParams,
    report: &serde_json::Value,
    created_by: &str,
) -> Result<i64> {
    let version: i64 = sqlx::query_scalar(
        "SELECT COALESCE(MAX(version), 0) + 1 FROM population_versions WHERE study_id = $1",
    )
    .bind(study_id)
    .fetch_one(&mut *db)
    .await?;
    sqlx::query(
        "INSERT INTO population_versions (study_id, version, population_json, report_json, created_by, created_at) VALUES ($1, $2, $3, $4, $5, $6)",
    )
    .bind(study_id)
    .bind(version)
    .bind(serde_json::to_string(population).expect("a population serializes"))
    .bind(report.to_string())
    .bind(created_by)
    .bind(now_ms())
    .execute(db)
    .await?;
    Ok(version)
}
