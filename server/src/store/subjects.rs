//! Subjects (pseudonymous: a code and a page token's hash), their consent and withdrawal, and
//! the experimenter's notes about them. An erased subject (`erasure`) changes no more.

use bdft_protocol::params::{Seat, SubjectDraw};
use bdft_protocol::records::ConsentDecision;
use serde::Serialize;
use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use super::tokens::token_hash;
use crate::error::{AppError, Result};

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Subject {
    pub id: i64,
    pub study_id: i64,
    /// The pseudonym ("S01"); nothing else identifies the person.
    pub code: String,
    pub enrol_index: i64,
    pub synthetic: bool,
    /// The seat of the subject's first tests (the API's key: `starting_station`).
    #[serde(rename = "starting_station")]
    pub starting_seat: Seat,
    pub consent_version: Option<String>,
    pub consent_decision: Option<ConsentDecision>,
    pub consent_at: Option<i64>,
    /// SHA-256 of the consent form's text the decision was made on (none for a decision
    /// recorded before migration 0030).
    pub consent_sha256: Option<String>,
    pub withdrawn_at: Option<i64>,
    pub withdraw_reason: Option<String>,
    pub created_at: i64,
    /// A synthetic subject's drawn parameters (`subjects.drawn_json`); none for a person.
    pub drawn: Option<SubjectDraw>,
    /// When the subject's data were erased (`store::erasure`): then only the id, study,
    /// code, enrolment index, starting seat and synthetic flag are left, and `created_at` is
    /// this time too.
    pub erased_at: Option<i64>,
}

#[derive(sqlx::FromRow)]
struct SubjectRow {
    id: i64,
    study_id: i64,
    code: String,
    enrol_index: i64,
    #[sqlx(try_from = "crate::store::db::Flag")]
    synthetic: bool,
    starting_station: String,
    consent_version: Option<String>,
    consent_decision: Option<String>,
    consent_at: Option<i64>,
    consent_sha256: Option<String>,
    withdrawn_at: Option<i64>,
    withdraw_reason: Option<String>,
    created_at: i64,
    drawn_json: Option<String>,
    erased_at: Option<i64>,
}

impl TryFrom<SubjectRow> for Subject {
    type Error = AppError;
    fn try_from(r: SubjectRow) -> Result<Self> {
        let corrupt =
            |e: String| AppError::Internal(anyhow::anyhow!("stored subject {}: {e}", r.id));
        Ok(Subject {
            starting_seat: r
                .starting_station
                .parse::<Seat>()
                .map_err(|e| corrupt(e.to_string()))?,
            consent_decision: r
                .consent_decision
                .as_deref()
                .map(str::parse::<ConsentDecision>)
                .transpose()
                .map_err(corrupt)?,
            id: r.id,
            study_id: r.study_id,
            code: r.code,
            enrol_index: r.enrol_index,
            synthetic: r.synthetic,
            consent_version: r.consent_version,
            consent_at: r.consent_at,
            consent_sha256: r.consent_sha256,
            withdrawn_at: r.withdrawn_at,
            withdraw_reason: r.withdraw_reason,
            created_at: r.created_at,
            drawn: r
                .drawn_json
                .as_deref()
                .map(serde_json::from_str)
                .transpose()
                .map_err(|e| corrupt(format!("drawn parameters: {e}")))?,
            erased_at: r.erased_at,
        })
    }
}

const COLUMNS: &str = "id, study_id, code, enrol_index, synthetic, starting_station, consent_version, consent_decision, consent_at, consent_sha256, withdrawn_at, withdraw_reason, created_at, drawn_json, erased_at";

pub async fn get<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<Subject> {
    let row: Option<SubjectRow> =
        sqlx::query_as(&format!("SELECT {COLUMNS} FROM subjects WHERE id = $1"))
            .bind(id)
            .fetch_optional(db)
            .await?;
    row.ok_or(AppError::NotFound("subject"))?.try_into()
}

/// The subject whose page token this is.
pub async fn by_token<'c>(db: impl AnyExecutor<'c>, token: &str) -> Result<Option<Subject>> {
    let row: Option<SubjectRow> = sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM subjects WHERE token_hash = $1"
    ))
    .bind(token_hash(token))
    .fetch_optional(db)
    .await?;
    row.map(Subject::try_from).transpose()
}

pub async fn of_study<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<Vec<Subject>> {
    let rows: Vec<SubjectRow> = sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM subjects WHERE study_id = $1 ORDER BY enrol_index"
    ))
    .bind(study_id)
    .fetch_all(db)
    .await?;
    rows.into_iter().map(Subject::try_from).collect()
}

pub async fn count_in_study<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<u32> {
    let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM subjects WHERE study_id = $1")
        .bind(study_id)
        .fetch_one(db)
        .await?;
    Ok(n as u32)
}

/// A new subject row; returns its id.
#[derive(Debug)]
pub struct NewSubject<'a> {
    pub study_id: i64,
    pub code: &'a str,
    pub enrol_index: u32,
    pub synthetic: bool,
    pub token: &'a str,
    pub starting_seat: Seat,
    pub drawn: Option<&'a SubjectDraw>,
}

pub async fn insert(db: &mut AnyConnection, s: &NewSubject<'_>) -> Result<i64> {
    Ok(sqlx::query_scalar::<_, i64>(
        "INSERT INTO subjects (study_id, code, enrol_index, synthetic, token_hash, starting_station, created_at, drawn_json) VALUES ($1, $2, $3, $4, $5, $6, $7, $8) RETURNING id",
    )
    .bind(s.study_id)
    .bind(s.code)
    .bind(i64::from(s.enrol_index))
    .bind(i64::from(s.synthetic))
    .bind(token_hash(s.token))
    .bind(s.starting_seat.as_str())
    .bind(now_ms())
    .bind(
        s.drawn
            .map(|d| serde_json::to_string(d).expect("a draw serializes")),
    )
    .fetch_one(db)
    .await?)
}

/// The refusal of a change to an erased subject (a SQL trigger refuses it as well).
pub fn refuse_erased(subject: &Subject) -> AppError {
    AppError::Conflict(format!(
        "{}'s data were erased; an erased subject takes no further part",
        subject.code
    ))
}

/// Records the subject's decision on the consent form `version` whose text hashes to
/// `text_sha256`; only the first decision counts.
pub async fn record_consent(
    db: &mut AnyConnection,
    subject_id: i64,
    version: &str,
    text_sha256: &str,
    decision: ConsentDecision,
) -> Result<()> {
    let done = sqlx::query("UPDATE subjects SET consent_version = $1, consent_decision = $2, consent_at = $3, consent_sha256 = $4 WHERE id = $5 AND consent_decision IS NULL AND erased_at IS NULL")
        .bind(version)
        .bind(decision.as_str())
        .bind(now_ms())
        .bind(text_sha256)
        .bind(subject_id)
        .execute(&mut *db)
        .await?;
    if done.rows_affected() == 0 {
        return refuse_unchanged(db, subject_id, "consent has already been recorded").await;
    }
    Ok(())
}

pub async fn withdraw(db: &mut AnyConnection, subject_id: i64, reason: &str) -> Result<()> {
    let done = sqlx::query("UPDATE subjects SET withdrawn_at = $1, withdraw_reason = $2 WHERE id = $3 AND withdrawn_at IS NULL AND erased_at IS NULL")
        .bind(now_ms())
        .bind(reason)
        .bind(subject_id)
        .execute(&mut *db)
        .await?;
    if done.rows_affected() == 0 {
        return refuse_unchanged(db, subject_id, "the subject has already withdrawn").await;
    }
    Ok(())
}

/// The refusal of a one-time change to `subject_id` (consent, withdrawal) that changed
/// nothing: the subject was erased, or else the change was made before (`already`).
async fn refuse_unchanged(db: &mut AnyConnection, subject_id: i64, already: &str) -> Result<()> {
    let subject = get(&mut *db, subject_id).await?;
    if subject.erased_at.is_some() {
        return Err(refuse_erased(&subject));
    }
    Err(AppError::Conflict(already.into()))
}

#[derive(Debug, Clone, Serialize, sqlx::FromRow, utoipa::ToSchema)]
pub struct Note {
    pub id: i64,
    pub trial_id: Option<i64>,
    pub text: String,
    pub author: String,
    pub created_at: i64,
}

pub async fn notes<'c>(db: impl AnyExecutor<'c>, subject_id: i64) -> Result<Vec<Note>> {
    Ok(sqlx::query_as(
        "SELECT id, trial_id, text, author, created_at FROM notes WHERE subject_id = $1 ORDER BY id",
    )
    .bind(subject_id)
    .fetch_all(db)
    .await?)
}

pub async fn add_note(
    db: &mut AnyConnection,
    subject_id: i64,
    trial_id: i64,
    text: &str,
    author: &str,
) -> Result<i64> {
    Ok(sqlx::query_scalar::<_, i64>(
        "INSERT INTO notes (subject_id, trial_id, text, author, created_at) VALUES ($1, $2, $3, $4, $5) RETURNING id",
    )
    .bind(subject_id)
    .bind(trial_id)
    .bind(text)
    .bind(author)
    .bind(now_ms())
    .fetch_one(db)
    .await?)
}
