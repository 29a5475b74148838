//! What subjects' identification tests measured: the feedthrough at each excited frequency
//! and the seated body fitted to it (migration 0025), one row per completed attempt,
//! written in the trial's filing transaction.

use bdft_controller::analysis::personal::PersonalDesign;
use bdft_protocol::identification::{BodyFit, FitReport, FrfPoint};
use serde::{Serialize, Serializer};
use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use crate::error::{AppError, Result};

/// One completed identification test's outcome.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Identification {
    pub trial_id: i64,
    pub subject_id: i64,
    pub points: Vec<FrfPoint>,
    /// The fitted body, or why the fit failed (`fit_error`); reported with its unidentified
    /// parameters empty (`BodyFit::report`).
    #[serde(serialize_with = "as_report")]
    #[schema(value_type = Option<FitReport>)]
    pub fit: Option<BodyFit>,
    pub fit_error: Option<String>,
    /// The designs tuned to the fitted body, in a personalized study (migration 0026).
    #[schema(value_type = Option<Vec<Object>>)]
    pub designs: Option<Vec<PersonalDesign>>,
    /// When it was filed (ms since the epoch).
    pub created_at: i64,
}

fn as_report<S: Serializer>(fit: &Option<BodyFit>, s: S) -> std::result::Result<S::Ok, S::Error> {
    fit.as_ref().map(BodyFit::report).serialize(s)
}

/// A stored fit, `checked` so that one stored before unidentified parameters were named
/// with their reasons (or left empty) reads as one stored now.
fn stored_fit(json: &str) -> serde_json::Result<BodyFit> {
    serde_json::from_str::<BodyFit>(json).map(BodyFit::checked)
}

#[derive(sqlx::FromRow)]
struct Row {
    trial_id: i64,
    subject_id: i64,
    points_json: String,
    fit_json: Option<String>,
    fit_error: Option<String>,
    designs_json: Option<String>,
    created_at: i64,
}

impl TryFrom<Row> for Identification {
    type Error = AppError;
    fn try_from(r: Row) -> Result<Self> {
        let bad = |e: serde_json::Error| {
            AppError::Internal(anyhow::anyhow!(
                "stored identification of trial {}: {e}",
                r.trial_id
            ))
        };
        Ok(Self {
            trial_id: r.trial_id,
            subject_id: r.subject_id,
            points: serde_json::from_str(&r.points_json).map_err(bad)?,
            fit: r
                .fit_json
                .as_deref()
                .map(stored_fit)
                .transpose()
                .map_err(bad)?,
            fit_error: r.fit_error,
            designs: r
                .designs_json
                .as_deref()
                .map(serde_json::from_str)
                .transpose()
                .map_err(bad)?,
            created_at: r.created_at,
        })
    }
}

/// Stores what trial `trial_id` of subject `subject_id` measured: the points, and the fit
/// or why it failed, and the designs tuned to it in a personalized study.
pub async fn insert(
    db: &mut AnyConnection,
    trial_id: i64,
    subject_id: i64,
    points: &[FrfPoint],
    fit: std::result::Result<&BodyFit, &str>,
    designs: Option<&[PersonalDesign]>,
) -> Result<()> {
    let (fit_json, fit_error) = match fit {
        Ok(f) => (
            Some(serde_json::to_string(f).expect("fits serialize")),
            None,
        ),
        Err(e) => (None, Some(e)),
    };
    sqlx::query(
        "INSERT INTO identifications (trial_id, subject_id, points_json, fit_json, fit_error, designs_json, created_at) \
         VALUES ($1, $2, $3, $4, $5, $6, $7)",
    )
    .bind(trial_id)
    .bind(subject_id)
    .bind(serde_json::to_string(points).expect("points serialize"))
    .bind(fit_json)
    .bind(fit_error)
    .bind(designs.map(|d| serde_json::to_string(d).expect("designs serialize")))
    .bind(now_ms())
    .execute(db)
    .await?;
    Ok(())
}

/// The subject's identifications, oldest first.
pub async fn of_subject<'c>(
    db: impl AnyExecutor<'c>,
    subject_id: i64,
) -> Result<Vec<Identification>> {
    let rows: Vec<Row> =
        sqlx::query_as("SELECT * FROM identifications WHERE subject_id = $1 ORDER BY trial_id")
            .bind(subject_id)
            .fetch_all(db)
            .await?;
    rows.into_iter().map(Identification::try_from).collect()
}

/// The body fitted by the subject's latest identification test with a fit.
pub async fn latest_fit<'c>(db: impl AnyExecutor<'c>, subject_id: i64) -> Result<Option<BodyFit>> {
    let json: Option<(String,)> = sqlx::query_as(
        "SELECT fit_json FROM identifications WHERE subject_id = $1 AND fit_json IS NOT NULL \
         ORDER BY trial_id DESC LIMIT 1",
    )
    .bind(subject_id)
    .fetch_optional(db)
    .await?;
    json.map(|(j,)| {
        stored_fit(&j).map_err(|e| {
            AppError::Internal(anyhow::anyhow!(
                "stored body fit of subject {subject_id}: {e}"
            ))
        })
    })
    .transpose()
}

/// The identifications of a study's subjects who have not withdrawn, with their codes, in
/// enrolment order.
pub async fn of_study<'c>(
    db: impl AnyExecutor<'c>,
    study_id: i64,
) -> Result<Vec<(String, Identification)>> {
    #[derive(sqlx::FromRow)]
    struct Coded {
        code: String,
        #[sqlx(flatten)]
        row: Row,
    }
    let rows: Vec<Coded> = sqlx::query_as(
        "SELECT s.code, i.* FROM identifications i JOIN subjects s ON s.id = i.subject_id \
         WHERE s.study_id = $1 AND s.withdrawn_at IS NULL ORDER BY s.enrol_index, i.trial_id",
    )
    .bind(study_id)
    .fetch_all(db)
    .await?;
    rows.into_iter()
        .map(|c| Ok((c.code, Identification::try_from(c.row)?)))
        .collect()
}
