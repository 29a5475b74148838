//! The queries behind the exports and statistics: every attempt of every test of the
//! subjects who have not withdrawn, in schedule order.

use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::records::{TestPhase, TrialStatus};
use bdft_protocol::study::CancellationArm;
use sqlx::AnyExecutor;

use crate::error::Result;

/// One test attempt with its subject and survey, as the exports and statistics read it.
#[derive(Debug, sqlx::FromRow)]
pub struct TrialExportRow {
    pub study_id: i64,
    pub trial_id: i64,
    pub code: String,
    pub enrol_index: i64,
    #[sqlx(try_from = "crate::store::db::Flag")]
    pub synthetic: bool,
    #[sqlx(try_from = "String")]
    pub starting_station: Seat,
    #[sqlx(try_from = "String")]
    pub station: Seat,
    pub block: i64,
    pub position: i64,
    pub slot: i64,
    pub attempt: i64,
    #[sqlx(try_from = "String")]
    pub controller: CompensatorKind,
    pub blinded_label: String,
    #[sqlx(try_from = "String")]
    pub phase: TestPhase,
    #[sqlx(try_from = "String")]
    pub status: TrialStatus,
    pub status_reason: Option<String>,
    pub target_seed: i64,
    pub target_mean_mm: f64,
    pub target_std_mm: f64,
    pub target_ms_step_mm2: Option<f64>,
    pub k_bf: f64,
    pub duration_s: f64,
    pub mse_tracking_mm2: Option<f64>,
    pub ms_cab_accel: Option<f64>,
    pub cab_aw_m_s2: Option<f64>,
    pub cab_vdv_m_s175: Option<f64>,
    pub accuracy: Option<i64>,
    pub speed: Option<i64>,
    pub smoothness: Option<i64>,
    pub controllability: Option<i64>,
    pub comment: Option<String>,
    pub protocol_hash: Option<String>,
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
    pub consent_version: Option<String>,
    /// How the test ran: the station's figures (`TimingReport` without the id) and the
    /// controller's (`TimingSummary`), as JSON; and the experimenter's acceptance.
    pub client_timing_json: Option<String>,
    pub timing_json: Option<String>,
    pub accepted_reason: Option<String>,
    /// This row is the latest attempt of its test (subject and slot).
    #[sqlx(try_from = "crate::store::db::Flag")]
    pub latest: bool,
    /// The configuration version the trial ran, as "name vN" (none: not from a version).
    pub config_version: Option<String>,
    /// The design was tuned to the subject (migration 0026).
    #[sqlx(try_from = "crate::store::db::Flag")]
    pub personalized: bool,
    /// The design the trial ran (`CompensatorSpec`).
    pub compensator_json: String,
    /// The site whose machine ran it (migration 0027).
    pub site: Option<String>,
    /// What it cancelled the feedthrough with (migration 0031).
    #[sqlx(try_from = "String")]
    pub cancellation: CancellationArm,
    /// When cancellation's guard turned it off (s into the test; migration 0031).
    pub cancellation_off_at_s: Option<f64>,
    /// The machine's condition it ran under (migration 0032).
    pub condition: String,
    /// What an adaptive design did over the test (`AdaptationStatus` as JSON; migration
    /// 0033); none for a fixed design.
    pub adaptation_json: Option<String>,
}

const TRIALS_SQL: &str = "SELECT s.study_id, t.id AS trial_id, s.code, s.enrol_index, s.synthetic, s.starting_station, t.station, t.block, t.position, t.slot, t.attempt, \
     t.controller, t.blinded_label, t.phase, t.status, t.status_reason, t.target_seed, t.target_mean_mm, t.target_std_mm, t.target_ms_step_mm2, t.k_bf, t.duration_s, \
     t.mse_tracking_mm2, t.ms_cab_accel, t.cab_aw_m_s2, t.cab_vdv_m_s175, v.accuracy, v.speed, v.smoothness, v.controllability, v.comment, t.protocol_hash, t.started_at, t.finished_at, s.consent_version, \
     t.client_timing_json, t.timing_json, t.accepted_reason, \
     NOT EXISTS (SELECT 1 FROM trials u WHERE u.subject_id = t.subject_id AND u.slot = t.slot AND u.attempt > t.attempt) AS latest, \
     c.name || ' v' || c.version AS config_version, t.personalized, t.compensator_json, t.site, t.cancellation, t.cancellation_off_at_s, t.condition, t.adaptation_json \
     FROM trials t JOIN subjects s ON s.id = t.subject_id LEFT JOIN surveys v ON v.trial_id = t.id \
     LEFT JOIN compensator_configs c ON c.id = t.config_id \
     WHERE s.study_id = $1 AND ($2 OR s.withdrawn_at IS NULL) ORDER BY s.enrol_index, t.slot, t.attempt";

/// Whose tests a query reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Withdrawn {
    /// The subjects who have not withdrawn (every analysis and every per-test export).
    LeftOut,
    /// All the study's subjects (the subjects export, which says who withdrew).
    Included,
}

/// Every attempt of every test of the study's subjects (who have not withdrawn, unless
/// `Withdrawn::Included`).
pub async fn trial_rows<'c>(
    db: impl AnyExecutor<'c>,
    study_id: i64,
    withdrawn: Withdrawn,
) -> Result<Vec<TrialExportRow>> {
    Ok(sqlx::query_as(TRIALS_SQL)
        .bind(study_id)
        .bind(withdrawn == Withdrawn::Included)
        .fetch_all(db)
        .await?)
}

/// A trial that has a record, with the keys that join its samples to the other exports.
#[derive(Debug, sqlx::FromRow)]
pub struct RecordedTrial {
    pub trial_id: i64,
    pub code: String,
    #[sqlx(rename = "station")]
    pub seat: String,
    #[sqlx(rename = "controller")]
    pub compensator: String,
    pub attempt: i64,
    #[sqlx(try_from = "String")]
    pub phase: TestPhase,
}

/// The trials of the study's remaining subjects that have a record, in schedule order:
/// all, or only subject `code`'s, or only trial `trial_id`.
pub async fn recorded_trials<'c>(
    db: impl AnyExecutor<'c>,
    study_id: i64,
    code: Option<&str>,
    trial_id: Option<i64>,
) -> Result<Vec<RecordedTrial>> {
    Ok(sqlx::query_as(
        "SELECT t.id AS trial_id, s.code, t.station, t.controller, t.attempt, t.phase FROM trials t JOIN subjects s ON s.id = t.subject_id \
         JOIN trial_records r ON r.trial_id = t.id WHERE s.study_id = $1 AND s.withdrawn_at IS NULL \
         AND ($2 IS NULL OR s.code = $2) AND ($3 IS NULL OR t.id = $3) ORDER BY s.enrol_index, t.slot, t.attempt",
    )
    .bind(study_id)
    .bind(code)
    .bind(trial_id)
    .fetch_all(db)
    .await?)
}

/// A subject as the subjects export reads it, with the parameters drawn for a synthetic
/// subject (`drawn_json`: a flat object of name → number; NULL for a person). Not
/// `subjects::Subject`, which parses the draw into today's `SubjectDraw`: the export takes
/// it as an open map, so a subject drawn with another version's parameters still exports
/// (and so does the rest of its study).
#[derive(Debug, sqlx::FromRow)]
pub struct SubjectExportRow {
    pub id: i64,
    pub code: String,
    pub enrol_index: i64,
    #[sqlx(try_from = "crate::store::db::Flag")]
    pub synthetic: bool,
    #[sqlx(rename = "starting_station")]
    pub starting_seat: String,
    pub consent_version: Option<String>,
    pub consent_decision: Option<String>,
    pub consent_sha256: Option<String>,
    pub consent_at: Option<i64>,
    pub withdrawn_at: Option<i64>,
    pub drawn_json: Option<String>,
}

/// Every subject of the study, withdrawn or not, in enrolment order; not the erased (whose
/// tests are gone with their data, so no other export has them either).
pub async fn subject_rows<'c>(
    db: impl AnyExecutor<'c>,
    study_id: i64,
) -> Result<Vec<SubjectExportRow>> {
    Ok(sqlx::query_as(
        "SELECT id, code, enrol_index, synthetic, starting_station, consent_version, consent_decision, consent_sha256, consent_at, withdrawn_at, drawn_json \
         FROM subjects WHERE study_id = $1 AND erased_at IS NULL ORDER BY enrol_index",
    )
    .bind(study_id)
    .fetch_all(db)
    .await?)
}

/// The codes of the study's subjects who have not withdrawn (nor been erased), in enrolment
/// order (what a per-subject export may name).
pub async fn subject_codes<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<Vec<String>> {
    Ok(sqlx::query_scalar(
        "SELECT code FROM subjects WHERE study_id = $1 AND withdrawn_at IS NULL AND erased_at IS NULL ORDER BY enrol_index",
    )
    .bind(study_id)
    .fetch_all(db)
    .await?)
}

/// One note or reason about a test: the experimenter's notes, the reasons given for a redo,
/// an abort, filing incomplete or a failed start, and the reason a test's status was filed
/// with (a fault, the E-stop, a lost controller).
#[derive(Debug, sqlx::FromRow)]
pub struct NoteRow {
    pub study_id: i64,
    pub trial_id: Option<i64>,
    pub code: String,
    pub slot: Option<i64>,
    pub attempt: Option<i64>,
    /// `note`, `redo`, `abort`, `accept_incomplete`, `start_failed`, `invalid` or `status`.
    pub kind: String,
    pub status: Option<String>,
    pub at: Option<i64>,
    pub author: String,
    pub text: String,
}

/// Audit actions whose detail carries the reason an experimenter gave for a test, and the
/// kind each is exported as.
const REASON_ACTIONS: &str =
    "'trial.redo', 'trial.abort', 'trial.accept_incomplete', 'trial.start_failed', 'trial.invalid'";

/// Every note and reason about the study's subjects who have not withdrawn and their tests,
/// in schedule order, then time.
pub async fn note_rows<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<Vec<NoteRow>> {
    let sql = format!(
        "SELECT s.study_id, x.trial_id, s.code, t.slot, t.attempt, x.kind, t.status, x.at, x.author, x.text FROM ( \
           SELECT n.subject_id, n.trial_id, 'note' AS kind, n.created_at AS at, n.author, n.text FROM notes n \
           UNION ALL \
           SELECT tt.subject_id, tt.id, substr(a.action, 7), a.at, a.actor, a.detail_json \
             FROM audit_log a JOIN trials tt ON tt.id = CAST(substr(a.target, 7) AS BIGINT) WHERE a.action IN ({REASON_ACTIONS}) AND a.target LIKE 'trial:%' \
           UNION ALL \
           SELECT tt.subject_id, tt.id, 'status', tt.finished_at, '', tt.status_reason FROM trials tt WHERE tt.status_reason IS NOT NULL \
         ) x JOIN subjects s ON s.id = x.subject_id LEFT JOIN trials t ON t.id = x.trial_id \
         WHERE s.study_id = $1 AND s.withdrawn_at IS NULL ORDER BY s.enrol_index, t.slot, t.attempt, x.at"
    );
    let mut rows: Vec<NoteRow> = sqlx::query_as(&sql).bind(study_id).fetch_all(db).await?;
    // A reason's row carries its audit detail: the reason is read from it here.
    for row in &mut rows {
        if row.kind != "note" && row.kind != "status" {
            row.text = super::audit::reason_of(&row.text);
        }
    }
    Ok(rows)
}
