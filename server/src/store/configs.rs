//! Versioned controller configurations (`compensator_configs`, immutable once created) and
//! the versions a study picked (`study_configs`).

use bdft_protocol::params::{CompensatorKind, CompensatorSpec};
use serde::Serialize;
use sqlx::{AnyConnection, AnyExecutor};
use utoipa::ToSchema;

use super::db::now_ms;
use crate::error::{AppError, Result};

/// One version of a named configuration.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ConfigVersion {
    pub id: i64,
    pub name: String,
    pub version: i64,
    pub kind: CompensatorKind,
    pub spec: CompensatorSpec,
    pub created_at: i64,
}

#[derive(sqlx::FromRow)]
struct Row {
    id: i64,
    name: String,
    version: i64,
    spec_json: String,
    created_at: i64,
}

impl TryFrom<Row> for ConfigVersion {
    type Error = AppError;
    fn try_from(r: Row) -> Result<Self> {
        let spec: CompensatorSpec = serde_json::from_str(&r.spec_json).map_err(|e| {
            AppError::Internal(anyhow::anyhow!("stored configuration {}: {e}", r.id))
        })?;
        Ok(Self {
            id: r.id,
            name: r.name,
            version: r.version,
            kind: spec.kind(),
            spec,
            created_at: r.created_at,
        })
    }
}

const COLUMNS: &str = "id, name, version, spec_json, created_at";

/// The text a version's design is stored as: what enrolment writes to `compensator_json`,
/// so the trials' trigger can tell a trial ran this version.
pub fn spec_text(spec: &CompensatorSpec) -> String {
    serde_json::to_string(spec).expect("specs serialize")
}

/// Adds the next version of `name` (1 for a new name); returns its id and version.
pub async fn insert(
    db: &mut AnyConnection,
    name: &str,
    spec: &CompensatorSpec,
) -> Result<(i64, i64)> {
    let (next,): (i64,) = sqlx::query_as(
        "SELECT COALESCE(MAX(version), 0) + 1 FROM compensator_configs WHERE name = $1",
    )
    .bind(name)
    .fetch_one(&mut *db)
    .await?;
    let (id,): (i64,) = sqlx::query_as(
        "INSERT INTO compensator_configs (name, version, kind, spec_json, created_at) VALUES ($1, $2, $3, $4, $5) RETURNING id",
    )
    .bind(name)
    .bind(next)
    .bind(spec.kind().name())
    .bind(spec_text(spec))
    .bind(now_ms())
    .fetch_one(db)
    .await?;
    Ok((id, next))
}

/// Every version, by name then version.
pub async fn all<'c>(db: impl AnyExecutor<'c>) -> Result<Vec<ConfigVersion>> {
    let rows: Vec<Row> = sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM compensator_configs ORDER BY name, version"
    ))
    .fetch_all(db)
    .await?;
    rows.into_iter().map(ConfigVersion::try_from).collect()
}

pub async fn get<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<ConfigVersion> {
    let row: Option<Row> = sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM compensator_configs WHERE id = $1"
    ))
    .bind(id)
    .fetch_optional(db)
    .await?;
    row.ok_or(AppError::NotFound("configuration version"))?
        .try_into()
}

/// The versions `study_id` picked, as (kind name, configuration id).
pub async fn picked<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<Vec<(String, i64)>> {
    Ok(sqlx::query_as(
        "SELECT kind, config_id FROM study_configs WHERE study_id = $1 ORDER BY kind",
    )
    .bind(study_id)
    .fetch_all(db)
    .await?)
}

/// `study_id` takes `config_id` for its design of the version's kind (replacing an earlier
/// pick of that kind).
pub async fn pick(
    db: &mut AnyConnection,
    study_id: i64,
    kind: CompensatorKind,
    config_id: i64,
) -> Result<()> {
    sqlx::query(
        "INSERT INTO study_configs (study_id, kind, config_id) VALUES ($1, $2, $3) \
         ON CONFLICT (study_id, kind) DO UPDATE SET config_id = excluded.config_id",
    )
    .bind(study_id)
    .bind(kind.name())
    .bind(config_id)
    .execute(db)
    .await?;
    Ok(())
}
