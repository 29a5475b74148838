//! Reads and writes of the experiment's data. Every multi-row change is one transaction, so
//! nothing is ever half-stored.

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::study::StudyParams;
use bdft_protocol::trial::{FaultKind, Outcome, RECORD_CHANNELS};
use serde::Serialize;
use sqlx::{Sqlite, SqlitePool, Transaction};

use crate::db::{now_ms, random_token, token_hash};
use crate::study::{protocol_hash, schedule, starting_station, target};

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{0} not found")]
    NotFound(&'static str),
    #[error("{0}")]
    Conflict(String),
    #[error("{0}")]
    Invalid(String),
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
}

pub type Result<T> = std::result::Result<T, StoreError>;

#[derive(Debug, Clone, Serialize)]
pub struct Study {
    pub id: i64,
    pub name: String,
    pub params: StudyParams,
    pub seed: u64,
    pub locked_at: Option<i64>,
    pub protocol_hash: Option<String>,
    pub created_at: i64,
}

#[derive(sqlx::FromRow)]
struct StudyDb {
    id: i64,
    name: String,
    params_json: String,
    seed: i64,
    locked_at: Option<i64>,
    protocol_hash: Option<String>,
    created_at: i64,
}

impl TryFrom<StudyDb> for Study {
    type Error = StoreError;
    fn try_from(r: StudyDb) -> Result<Self> {
        Ok(Study {
            id: r.id,
            name: r.name,
            params: serde_json::from_str(&r.params_json)
                .map_err(|e| StoreError::Invalid(format!("stored study parameters: {e}")))?,
            seed: r.seed as u64,
            locked_at: r.locked_at,
            protocol_hash: r.protocol_hash,
            created_at: r.created_at,
        })
    }
}

pub async fn create_study(
    pool: &SqlitePool,
    name: &str,
    params: &StudyParams,
    seed: u64,
) -> Result<i64> {
    params
        .validate()
        .map_err(|e| StoreError::Invalid(e.to_string()))?;
    let json = serde_json::to_string(params).expect("params serialize");
    let id = sqlx::query(
        "INSERT INTO studies (name, params_json, seed, created_at) VALUES (?, ?, ?, ?)",
    )
    .bind(name)
    .bind(json)
    .bind(seed as i64)
    .bind(now_ms())
    .execute(pool)
    .await?
    .last_insert_rowid();
    Ok(id)
}

pub async fn study(pool: &SqlitePool, id: i64) -> Result<Study> {
    let row: Option<StudyDb> = sqlx::query_as("SELECT * FROM studies WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await?;
    row.ok_or(StoreError::NotFound("study"))?.try_into()
}

pub async fn studies(pool: &SqlitePool) -> Result<Vec<Study>> {
    let rows: Vec<StudyDb> = sqlx::query_as("SELECT * FROM studies ORDER BY id")
        .fetch_all(pool)
        .await?;
    rows.into_iter().map(Study::try_from).collect()
}

/// Replaces the parameters of a study that has not started.
pub async fn update_study(
    pool: &SqlitePool,
    id: i64,
    name: &str,
    params: &StudyParams,
) -> Result<()> {
    params
        .validate()
        .map_err(|e| StoreError::Invalid(e.to_string()))?;
    let json = serde_json::to_string(params).expect("params serialize");
    let done = sqlx::query(
        "UPDATE studies SET name = ?, params_json = ? WHERE id = ? AND locked_at IS NULL",
    )
    .bind(name)
    .bind(json)
    .bind(id)
    .execute(pool)
    .await?;
    if done.rows_affected() == 0 {
        study(pool, id).await?;
        return Err(StoreError::Conflict(
            "the study's protocol is locked: a subject has been enrolled".into(),
        ));
    }
    Ok(())
}

#[derive(Debug, Clone, Serialize, sqlx::FromRow)]
pub struct Subject {
    pub id: i64,
    pub study_id: i64,
    pub code: String,
    pub enrol_index: i64,
    pub synthetic: bool,
    pub starting_station: String,
    pub consent_version: Option<String>,
    pub consent_decision: Option<String>,
    pub consent_at: Option<i64>,
    pub withdrawn_at: Option<i64>,
    pub withdraw_reason: Option<String>,
    pub created_at: i64,
}

const SUBJECT_COLUMNS: &str = "id, study_id, code, enrol_index, synthetic, starting_station, consent_version, consent_decision, consent_at, withdrawn_at, withdraw_reason, created_at";

/// Enrols the next subject: locks the protocol (first subject), draws the schedule and every
/// target, and stores them, all in one transaction. Returns the subject and its page token.
pub async fn enrol(pool: &SqlitePool, study_id: i64, synthetic: bool) -> Result<(Subject, String)> {
    let mut tx = pool.begin().await?;
    let row: Option<StudyDb> = sqlx::query_as("SELECT * FROM studies WHERE id = ?")
        .bind(study_id)
        .fetch_optional(&mut *tx)
        .await?;
    let st: Study = row.ok_or(StoreError::NotFound("study"))?.try_into()?;
    let hash = match &st.protocol_hash {
        Some(h) => h.clone(),
        None => {
            let h = protocol_hash(&st.params);
            sqlx::query("UPDATE studies SET locked_at = ?, protocol_hash = ? WHERE id = ?")
                .bind(now_ms())
                .bind(&h)
                .bind(study_id)
                .execute(&mut *tx)
                .await?;
            h
        }
    };
    let (index,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM subjects WHERE study_id = ?")
        .bind(study_id)
        .fetch_one(&mut *tx)
        .await?;
    let index = index as u32;
    let code = format!("S{:02}", index + 1);
    let token = random_token();
    let subject_id = sqlx::query(
        "INSERT INTO subjects (study_id, code, enrol_index, synthetic, token_hash, starting_station, created_at) VALUES (?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(study_id)
    .bind(&code)
    .bind(i64::from(index))
    .bind(synthetic)
    .bind(token_hash(&token))
    .bind(starting_station(index).as_str())
    .bind(now_ms())
    .execute(&mut *tx)
    .await?
    .last_insert_rowid();
    for t in schedule(&st.params, st.seed, index) {
        let tg = target(&st.params, &t).map_err(|e| StoreError::Invalid(e.to_string()))?;
        let spec = if t.practice {
            bdft_controller::compensator::default_spec(t.controller, &st.params.plant)
        } else {
            st.params
                .controllers
                .iter()
                .find(|c| c.kind() == t.controller)
                .cloned()
                .expect("scheduled controllers are the study's")
        };
        sqlx::query(
            "INSERT INTO trials (subject_id, slot, practice, station, block, position, controller, blinded_label, compensator_json, k_bf, duration_s, target_seed, target_levels_json, target_mean_mm, target_std_mm, protocol_hash) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(subject_id)
        .bind(i64::from(t.slot))
        .bind(t.practice)
        .bind(t.station.as_str())
        .bind(i64::from(t.block))
        .bind(i64::from(t.position))
        .bind(t.controller.name())
        .bind(&t.blinded_label)
        .bind(serde_json::to_string(&spec).expect("spec serializes"))
        .bind(st.params.k_bf)
        .bind(t.duration_s)
        .bind(t.target_seed as i64)
        .bind(serde_json::to_string(&tg.levels_mm).expect("levels serialize"))
        .bind(tg.mean_mm)
        .bind(tg.std_mm)
        .bind(&hash)
        .execute(&mut *tx)
        .await?;
    }
    let subject: Subject = sqlx::query_as(&format!(
        "SELECT {SUBJECT_COLUMNS} FROM subjects WHERE id = ?"
    ))
    .bind(subject_id)
    .fetch_one(&mut *tx)
    .await?;
    tx.commit().await?;
    Ok((subject, token))
}

pub async fn subject(pool: &SqlitePool, id: i64) -> Result<Subject> {
    sqlx::query_as(&format!(
        "SELECT {SUBJECT_COLUMNS} FROM subjects WHERE id = ?"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await?
    .ok_or(StoreError::NotFound("subject"))
}

pub async fn subjects(pool: &SqlitePool, study_id: i64) -> Result<Vec<Subject>> {
    Ok(sqlx::query_as(&format!(
        "SELECT {SUBJECT_COLUMNS} FROM subjects WHERE study_id = ? ORDER BY enrol_index"
    ))
    .bind(study_id)
    .fetch_all(pool)
    .await?)
}

#[derive(Debug, Clone, Serialize, sqlx::FromRow)]
pub struct Trial {
    pub id: i64,
    pub subject_id: i64,
    pub slot: i64,
    pub attempt: i64,
    pub practice: bool,
    pub station: String,
    pub block: i64,
    pub position: i64,
    pub controller: String,
    pub blinded_label: String,
    pub compensator_json: String,
    pub k_bf: f64,
    pub duration_s: f64,
    pub target_seed: i64,
    pub target_levels_json: String,
    pub target_mean_mm: f64,
    pub target_std_mm: f64,
    pub status: String,
    pub status_reason: Option<String>,
    pub protocol_hash: Option<String>,
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
    pub mse_tracking_mm2: Option<f64>,
    pub ms_cab_accel: Option<f64>,
    pub timing_json: Option<String>,
    pub client_timing_json: Option<String>,
}

pub async fn trial(pool: &SqlitePool, id: i64) -> Result<Trial> {
    sqlx::query_as("SELECT * FROM trials WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await?
        .ok_or(StoreError::NotFound("trial"))
}

/// Every attempt of every test of a subject, in schedule order.
pub async fn trials_of(pool: &SqlitePool, subject_id: i64) -> Result<Vec<Trial>> {
    Ok(
        sqlx::query_as("SELECT * FROM trials WHERE subject_id = ? ORDER BY slot, attempt")
            .bind(subject_id)
            .fetch_all(pool)
            .await?,
    )
}

/// The subject's next test: the first slot whose latest attempt is still scheduled.
pub async fn next_trial(pool: &SqlitePool, subject_id: i64) -> Result<Option<Trial>> {
    Ok(sqlx::query_as(
        "SELECT t.* FROM trials t WHERE t.subject_id = ? AND t.status IN ('scheduled', 'running') \
         AND t.attempt = (SELECT MAX(attempt) FROM trials u WHERE u.subject_id = t.subject_id AND u.slot = t.slot) \
         ORDER BY t.slot LIMIT 1",
    )
    .bind(subject_id)
    .fetch_optional(pool)
    .await?)
}

/// Marks a scheduled trial running; fails if it is not scheduled (two starts racing).
pub async fn mark_running(pool: &SqlitePool, trial_id: i64) -> Result<()> {
    let done = sqlx::query("UPDATE trials SET status = 'running', started_at = ? WHERE id = ? AND status = 'scheduled'")
        .bind(now_ms())
        .bind(trial_id)
        .execute(pool)
        .await?;
    if done.rows_affected() == 0 {
        return Err(StoreError::Conflict(format!(
            "trial {trial_id} is not waiting to start"
        )));
    }
    Ok(())
}

/// Puts a trial that could not be started back in the queue.
pub async fn unmark_running(pool: &SqlitePool, trial_id: i64) -> Result<()> {
    sqlx::query("UPDATE trials SET status = 'scheduled', started_at = NULL WHERE id = ? AND status = 'running'").bind(trial_id).execute(pool).await?;
    Ok(())
}

/// How an outcome is filed: the experimenter's abort and the e-stop are "aborted"; any other
/// fault leaves the test "incomplete".
pub fn status_of(outcome: &Outcome) -> (&'static str, Option<String>) {
    match outcome {
        Outcome::Complete => ("complete", None),
        Outcome::Aborted { reason } => ("aborted", Some(reason.clone())),
        Outcome::Faulted {
            fault: FaultKind::EStop,
            message,
        } => ("aborted", Some(format!("e-stop: {message}"))),
        Outcome::Faulted { message, .. } => ("incomplete", Some(message.clone())),
    }
}

/// The full-rate record of a trial, one channel per `RECORD_CHANNELS` entry.
#[derive(Debug, Clone, Default)]
pub struct Record {
    pub dt: f64,
    pub channels: Vec<Vec<f32>>,
}

fn blob(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

pub fn unblob(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Commits a finished trial — status, metrics, timing and the full record — in one
/// transaction. Only a running trial takes a result (a result arriving after a restart
/// marked it incomplete is dropped).
pub async fn commit_result(
    pool: &SqlitePool,
    result: &TrialResult,
    record: &Record,
) -> Result<bool> {
    let (status, reason) = status_of(&result.outcome);
    let mut tx = pool.begin().await?;
    let done = sqlx::query(
        "UPDATE trials SET status = ?, status_reason = ?, finished_at = MAX(?, COALESCE(started_at, 0)), mse_tracking_mm2 = ?, ms_cab_accel = ?, timing_json = ? WHERE id = ? AND status = 'running'",
    )
    .bind(status)
    .bind(reason)
    .bind(now_ms())
    .bind(result.metrics.mse_tracking_mm2)
    .bind(result.metrics.ms_cab_accel)
    .bind(serde_json::to_string(&result.timing).expect("timing serializes"))
    .bind(result.trial_id as i64)
    .execute(&mut *tx)
    .await?;
    if done.rows_affected() == 0 {
        return Ok(false);
    }
    if record.channels.len() == RECORD_CHANNELS.len() && !record.channels[0].is_empty() {
        insert_record(&mut tx, result.trial_id as i64, record).await?;
    }
    tx.commit().await?;
    Ok(true)
}

async fn insert_record(
    tx: &mut Transaction<'_, Sqlite>,
    trial_id: i64,
    record: &Record,
) -> Result<()> {
    let mut q = sqlx::query(
        "INSERT OR REPLACE INTO trial_records (trial_id, dt, samples, target_mm, hand_mm, feedthrough_mm, cyl_ref_mm, valve_cmd, cyl_pos_mm, cab_accel_mm_s2, device_mm, tick_latency_us) \
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(trial_id)
    .bind(record.dt)
    .bind(record.channels[0].len() as i64);
    for c in &record.channels {
        q = q.bind(blob(c));
    }
    q.execute(&mut **tx).await?;
    Ok(())
}

/// Marks every running trial incomplete (after a server restart or a controller death).
pub async fn interrupt_running(pool: &SqlitePool, reason: &str) -> Result<Vec<i64>> {
    let ids: Vec<(i64,)> = sqlx::query_as("UPDATE trials SET status = 'incomplete', status_reason = ?, finished_at = MAX(?, COALESCE(started_at, 0)) WHERE status = 'running' RETURNING id")
        .bind(reason)
        .bind(now_ms())
        .fetch_all(pool)
        .await?;
    Ok(ids.into_iter().map(|r| r.0).collect())
}

/// Appends to the audit log.
pub async fn audit(
    pool: &SqlitePool,
    actor: &str,
    action: &str,
    target: Option<String>,
    detail: serde_json::Value,
) -> Result<()> {
    sqlx::query(
        "INSERT INTO audit_log (at, actor, action, target, detail_json) VALUES (?, ?, ?, ?, ?)",
    )
    .bind(now_ms())
    .bind(actor)
    .bind(action)
    .bind(target)
    .bind(detail.to_string())
    .execute(pool)
    .await?;
    Ok(())
}
