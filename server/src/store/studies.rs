//! Studies: name, parameters (JSON), seed, and the lock taken at the first enrolment (a SQL
//! trigger refuses any later change of parameters or seed).

use bdft_protocol::study::StudyParams;
use serde::{Deserialize, Serialize};
use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use crate::error::{AppError, Result};

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Study {
    pub id: i64,
    pub name: String,
    pub params: StudyParams,
    pub seed: u64,
    /// 1 at creation, one more at every edit of the name or parameters: an edit names the
    /// version it was based on.
    pub version: i64,
    pub locked_at: Option<i64>,
    /// SHA-256 of the canonical parameters, set when the protocol is locked.
    pub protocol_hash: Option<String>,
    /// The consent form's text as the lock rendered it from the parameters (what every
    /// subject is shown from then on), and its SHA-256 (none for a study not locked yet, or
    /// locked before migration 0030).
    pub consent_text: Option<String>,
    pub consent_sha256: Option<String>,
    pub created_at: i64,
    /// Who acknowledged that a design is unstable on the machine, when and why (simulated
    /// studies only; cleared by an edit).
    pub instability_ack: Option<InstabilityAck>,
    /// The calibrated version of the population `params` holds (0: the study's own;
    /// `population_versions`).
    pub population_version: i64,
    /// Set when the study is a dry run (synthetic subjects only, so never pooled with a
    /// study's people: results and exports are per study): which study it copies.
    pub dry_run: Option<DryRun>,
}

/// A dry run's origin (`dry_runs`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, utoipa::ToSchema)]
pub struct DryRun {
    /// The study whose pilot runs in it; none for a dry run made on its own.
    pub of_study: Option<i64>,
}

/// Who acknowledged that a study's design is unstable on the machine, when and why.
// The fields are in alphabetical order, the order the stored text and the API's answer have
// had since the acknowledgement was an untyped JSON object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct InstabilityAck {
    /// When, in ms since the Unix epoch.
    pub at: i64,
    /// The experimenter's username.
    pub by: String,
    pub reason: String,
}

#[derive(sqlx::FromRow)]
struct StudyRow {
    id: i64,
    name: String,
    params_json: String,
    seed: i64,
    version: i64,
    locked_at: Option<i64>,
    protocol_hash: Option<String>,
    consent_text: Option<String>,
    consent_sha256: Option<String>,
    created_at: i64,
    instability_ack_json: Option<String>,
    population_json: Option<String>,
    population_version: Option<i64>,
    dry_run_id: Option<i64>,
    dry_run_of: Option<i64>,
}

impl TryFrom<StudyRow> for Study {
    type Error = AppError;
    fn try_from(r: StudyRow) -> Result<Self> {
        let mut params: StudyParams = serde_json::from_str(&r.params_json).map_err(|e| {
            AppError::Internal(anyhow::anyhow!("stored parameters of study {}: {e}", r.id))
        })?;
        if let Some(json) = &r.population_json {
            params.population = serde_json::from_str(json).map_err(|e| {
                AppError::Internal(anyhow::anyhow!("stored population of study {}: {e}", r.id))
            })?;
        }
        Ok(Study {
            id: r.id,
            name: r.name,
            params,
            seed: r.seed as u64,
            version: r.version,
            locked_at: r.locked_at,
            protocol_hash: r.protocol_hash,
            consent_text: r.consent_text,
            consent_sha256: r.consent_sha256,
            created_at: r.created_at,
            instability_ack: r
                .instability_ack_json
                .and_then(|j| serde_json::from_str(&j).ok()),
            population_version: r.population_version.unwrap_or(0),
            dry_run: r.dry_run_id.map(|_| DryRun {
                of_study: r.dry_run_of,
            }),
        })
    }
}

/// A study with the newest calibrated population that applies to it: its own, or for a
/// dry-run copy its parent's when that is newer (`population_versions`).
/// And whether it is a dry run, of which study.
const SELECT: &str = "SELECT s.*, p.population_json, p.version AS population_version, \
     d.study_id AS dry_run_id, d.of_study AS dry_run_of FROM studies s \
     LEFT JOIN dry_runs d ON d.study_id = s.id \
     LEFT JOIN population_versions p ON p.id = (SELECT v.id FROM population_versions v \
     WHERE v.study_id = s.id OR v.study_id = (SELECT d.of_study FROM dry_runs d WHERE d.study_id = s.id) \
     ORDER BY v.id DESC LIMIT 1)";

fn params_json(params: &StudyParams) -> String {
    serde_json::to_string(params).expect("study parameters always serialize")
}

/// Stores a new study (its parameters already validated); returns its id.
pub async fn insert(
    db: &mut AnyConnection,
    name: &str,
    params: &StudyParams,
    seed: u64,
) -> Result<i64> {
    Ok(
        sqlx::query_scalar::<_, i64>(
            "INSERT INTO studies (name, params_json, seed, created_at) VALUES ($1, $2, $3, $4) RETURNING id",
        )
        .bind(name)
        .bind(params_json(params))
        .bind(seed as i64)
        .bind(now_ms())
        .fetch_one(db)
        .await?,
    )
}

pub async fn get<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<Study> {
    let row: Option<StudyRow> = sqlx::query_as(&format!("{SELECT} WHERE s.id = $1"))
        .bind(id)
        .fetch_optional(db)
        .await?;
    row.ok_or(AppError::NotFound("study"))?.try_into()
}

pub async fn all<'c>(db: impl AnyExecutor<'c>) -> Result<Vec<Study>> {
    let rows: Vec<StudyRow> = sqlx::query_as(&format!("{SELECT} ORDER BY s.id"))
        .fetch_all(db)
        .await?;
    rows.into_iter().map(Study::try_from).collect()
}

/// What became of an edit.
#[derive(Debug)]
pub enum Edit {
    Saved,
    /// The study had changed since the version the edit was based on: here it is now.
    Stale(Box<Study>),
}

/// Replaces the name and parameters of a study whose protocol is not locked, if it is still
/// at `version` (then it goes to the next version).
pub async fn update(
    db: &mut AnyConnection,
    id: i64,
    version: i64,
    name: &str,
    params: &StudyParams,
) -> Result<Edit> {
    let done = sqlx::query(
        "UPDATE studies SET name = $1, params_json = $2, instability_ack_json = NULL, version = version + 1 WHERE id = $3 AND locked_at IS NULL AND version = $4",
    )
    .bind(name)
    .bind(params_json(params))
    .bind(id)
    .bind(version)
    .execute(&mut *db)
    .await?;
    if done.rows_affected() == 1 {
        return Ok(Edit::Saved);
    }
    let current = get(&mut *db, id).await?;
    if current.locked_at.is_some() {
        return Err(locked());
    }
    Ok(Edit::Stale(Box::new(current)))
}

/// The answer to an UPDATE guarded by `locked_at IS NULL`: 404 for no such study, 409 when
/// it matched nothing because the protocol is locked.
async fn unless_locked(db: &mut AnyConnection, id: i64, rows: u64) -> Result<()> {
    if rows == 0 {
        get(&mut *db, id).await?;
        return Err(locked());
    }
    Ok(())
}

fn locked() -> AppError {
    AppError::Conflict("the study's protocol is locked: a subject has been enrolled".into())
}

/// Locks the protocol with its hash and the consent form's text as rendered from it, with
/// that text's SHA-256 (the first enrolment does this).
pub async fn lock(
    db: &mut AnyConnection,
    id: i64,
    hash: &str,
    consent_text: &str,
    consent_sha256: &str,
) -> Result<()> {
    sqlx::query(
        "UPDATE studies SET locked_at = $1, protocol_hash = $2, consent_text = $3, consent_sha256 = $4 \
         WHERE id = $5 AND locked_at IS NULL",
    )
    .bind(now_ms())
    .bind(hash)
    .bind(consent_text)
    .bind(consent_sha256)
    .bind(id)
    .execute(db)
    .await?;
    Ok(())
}

/// Records the acknowledgement that a design is unstable (before the lock only).
pub async fn acknowledge_instability(
    db: &mut AnyConnection,
    id: i64,
    ack: &InstabilityAck,
) -> Result<()> {
    let done = sqlx::query(
        "UPDATE studies SET instability_ack_json = $1 WHERE id = $2 AND locked_at IS NULL",
    )
    .bind(super::json_text(ack)?)
    .bind(id)
    .execute(&mut *db)
    .await?;
    unless_locked(db, id, done.rows_affected()).await
}
