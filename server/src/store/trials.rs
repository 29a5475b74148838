//! Trials (one row per attempt of a scheduled test), their status transitions, surveys and
//! the station's timing figures.
//!
//! *Invariant:* a trial takes a result only while `running`; a status changes only by the
//! guarded UPDATEs here, so two users racing cannot move a trial twice.

use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::records::{TestPhase, TrialStatus};
use bdft_protocol::study::{CancellationArm, SurveyAnswer};
use serde::{Deserialize, Serialize};
use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use crate::error::{AppError, Result};

#[derive(Debug, Clone, Serialize, sqlx::FromRow, utoipa::ToSchema)]
pub struct Trial {
    pub id: i64,
    pub subject_id: i64,
    /// Position in the subject's schedule (0 = practice).
    pub slot: i64,
    /// 1 for the first attempt; a redo adds the next.
    pub attempt: i64,
    #[sqlx(try_from = "String")]
    pub phase: TestPhase,
    #[sqlx(rename = "station", try_from = "String")]
    #[serde(rename = "station")]
    pub seat: Seat,
    pub block: i64,
    pub position: i64,
    /// The compensator this test runs (never shown to the subject).
    #[sqlx(rename = "controller", try_from = "String")]
    #[serde(rename = "controller")]
    pub compensator: CompensatorKind,
    pub blinded_label: String,
    /// The full design (`CompensatorSpec`) as recorded at enrolment, or the subject's own
    /// (`personalized`).
    pub compensator_json: String,
    /// What the test cancels with on the machine (`off` at the desk and without the factor).
    #[sqlx(try_from = "String")]
    pub cancellation: CancellationArm,
    /// The model a cancelling test runs (`CancellationModel`), set once the subject's
    /// identification is filed and the model passed the check against their body; none
    /// until then, and for an uncancelled test.
    pub cancellation_json: Option<String>,
    /// When cancellation's guard turned it off for the rest of the test (s into it).
    pub cancellation_off_at_s: Option<f64>,
    /// The design is the one tuned to the subject's identified body (a personalized study's
    /// LQR designs, once their identification test is filed).
    #[sqlx(try_from = "crate::store::db::Flag")]
    pub personalized: bool,
    pub k_bf: f64,
    pub duration_s: f64,
    pub target_seed: i64,
    pub target_levels_json: String,
    pub target_mean_mm: f64,
    pub target_std_mm: f64,
    /// Realized mean-squared step change of the target (mm²; none before migration 0013).
    pub target_ms_step_mm2: Option<f64>,
    #[sqlx(try_from = "String")]
    pub status: TrialStatus,
    pub status_reason: Option<String>,
    pub protocol_hash: Option<String>,
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
    pub mse_tracking_mm2: Option<f64>,
    pub ms_cab_accel: Option<f64>,
    pub timing_json: Option<String>,
    pub client_timing_json: Option<String>,
    /// Where the attempt stands in its block's queue (a re-queued test goes to the end).
    pub queue_order: i64,
    /// Why the server found a running test invalid (its result is filed so).
    pub invalid_reason: Option<String>,
    /// The experimenter accepted this attempt's test as incomplete, for this reason.
    pub accepted_reason: Option<String>,
    /// ISO 2631-1 W_d-weighted r.m.s. of the cab acceleration over the record (m/s²; none
    /// for a test filed before migration 0024 or without a result).
    pub cab_aw_m_s2: Option<f64>,
    /// Its vibration dose value (m/s^1.75).
    pub cab_vdv_m_s175: Option<f64>,
    /// The length of the record those are over (s).
    pub exposure_s: Option<f64>,
    /// The site whose machine ran it (`serve --site`), recorded as it started; none for a
    /// test not started yet or started before sites existed.
    pub site: Option<String>,
    /// The machine's condition the test runs under (`MachineCondition`; migration 0032): the
    /// study's, or the subject's level of its condition factor.
    pub condition: String,
}

impl Trial {
    /// Whether the test has ended one way or another (it can be redone).
    pub fn finished(&self) -> bool {
        self.status == TrialStatus::Complete || self.status.failed()
    }

    /// Whether nothing more is owed for this attempt's test: it counts, or the experimenter
    /// accepted it as incomplete.
    pub fn settled(&self) -> bool {
        self.status == TrialStatus::Complete || self.accepted_reason.is_some()
    }
}

/// The latest attempt of each slot of `trials` (every attempt of one subject).
pub fn latest_attempts(trials: &[Trial]) -> impl Iterator<Item = &Trial> {
    trials.iter().filter(move |t| {
        !trials
            .iter()
            .any(|u| u.slot == t.slot && u.attempt > t.attempt)
    })
}

pub async fn get<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<Trial> {
    sqlx::query_as("SELECT * FROM trials WHERE id = $1")
        .bind(id)
        .fetch_optional(db)
        .await?
        .ok_or(AppError::NotFound("trial"))
}

/// Every attempt of every test of a subject, in schedule order.
pub async fn of_subject<'c>(db: impl AnyExecutor<'c>, subject_id: i64) -> Result<Vec<Trial>> {
    Ok(
        sqlx::query_as("SELECT * FROM trials WHERE subject_id = $1 ORDER BY slot, attempt")
            .bind(subject_id)
            .fetch_all(db)
            .await?,
    )
}

/// The subject's next test: the first in the queue (block by block, the practice's first,
/// then in queue order) whose latest attempt is scheduled or running.
///
/// A person's practice that failed as often as it is repeated by itself holds the schedule:
/// nothing scored runs on someone who never completed the warm-up until the experimenter
/// redoes it or accepts it as incomplete with a reason. A synthetic subject's does not: a dry
/// run has no experimenter to decide, and reports the failed practice as it is.
pub async fn next<'c>(db: impl AnyExecutor<'c>, subject_id: i64) -> Result<Option<Trial>> {
    Ok(sqlx::query_as(
        "SELECT t.* FROM trials t WHERE t.subject_id = $1 AND t.status IN ('scheduled', 'running') \
         AND t.attempt = (SELECT MAX(attempt) FROM trials u WHERE u.subject_id = t.subject_id AND u.slot = t.slot) \
         AND NOT EXISTS (SELECT 1 FROM trials p JOIN subjects s ON s.id = p.subject_id \
           WHERE p.subject_id = t.subject_id AND s.synthetic = 0 AND p.phase = 'practice' \
           AND p.status IN ('aborted', 'incomplete', 'invalid') AND p.accepted_reason IS NULL \
           AND p.attempt = (SELECT MAX(attempt) FROM trials q WHERE q.subject_id = p.subject_id AND q.slot = p.slot)) \
         ORDER BY t.block, t.queue_order LIMIT 1",
    )
    .bind(subject_id)
    .fetch_optional(db)
    .await?)
}

/// The first completed test of the subject whose survey is still missing.
pub async fn pending_survey<'c>(
    db: impl AnyExecutor<'c>,
    subject_id: i64,
) -> Result<Option<Trial>> {
    Ok(sqlx::query_as(
        "SELECT t.* FROM trials t WHERE t.subject_id = $1 AND t.phase = 'test' AND t.status = 'complete' \
         AND NOT EXISTS (SELECT 1 FROM surveys v WHERE v.trial_id = t.id) \
         AND t.attempt = (SELECT MAX(attempt) FROM trials u WHERE u.subject_id = t.subject_id AND u.slot = t.slot) ORDER BY t.slot LIMIT 1",
    )
    .bind(subject_id)
    .fetch_optional(db)
    .await?)
}

/// One entry of a subject's schedule, as `engine::study::schedule` draws it (a function of
/// the study's parameters and seeds only) and enrolment stores it (`NewTrial`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScheduledTest {
    /// 0 = practice, then 1.. for the scored tests in order; an identification test comes
    /// after them (its place in the queue is `queue_order`).
    pub slot: u32,
    pub phase: TestPhase,
    pub seat: Seat,
    /// 0 for the practice, 1 for the starting seat, 2 for the other.
    pub block: u32,
    /// Position within the block, from 1 (0 for the practice and an identification test).
    pub position: u32,
    /// Where the test stands in its block's queue: its slot, but an identification test
    /// goes first in the block on the machine.
    pub queue_order: u32,
    pub compensator: CompensatorKind,
    /// What it cancels with (`off` but on the machine in a study with the factor).
    pub cancellation: CancellationArm,
    /// What the subject sees ("Controller 3", "Practice").
    pub blinded_label: String,
    pub duration_s: f64,
    pub target_seed: u64,
}

/// A scheduled test as enrolment stores it: the schedule's entry, and what the study and
/// its target add to it.
#[derive(Debug)]
pub struct NewTrial<'a> {
    pub subject_id: i64,
    pub test: &'a ScheduledTest,
    pub compensator_json: String,
    pub k_bf: f64,
    pub target_levels_json: String,
    pub target_mean_mm: f64,
    pub target_std_mm: f64,
    pub target_ms_step_mm2: f64,
    pub protocol_hash: &'a str,
    /// The machine's condition the test runs under (`MachineCondition`, as its name).
    pub condition: String,
}

/// Stores a scheduled test; it is queued in schedule order.
pub async fn insert(db: &mut AnyConnection, new: &NewTrial<'_>) -> Result<i64> {
    let t = new.test;
    Ok(sqlx::query_scalar::<_, i64>(
        "INSERT INTO trials (subject_id, slot, phase, station, block, position, controller, blinded_label, compensator_json, k_bf, duration_s, target_seed, target_levels_json, target_mean_mm, target_std_mm, target_ms_step_mm2, protocol_hash, queue_order, cancellation, condition) \
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16, $17, $18, $19, $20) RETURNING id",
    )
    .bind(new.subject_id)
    .bind(i64::from(t.slot))
    .bind(t.phase.as_str())
    .bind(t.seat.as_str())
    .bind(i64::from(t.block))
    .bind(i64::from(t.position))
    .bind(t.compensator.name())
    .bind(&t.blinded_label)
    .bind(&new.compensator_json)
    .bind(new.k_bf)
    .bind(t.duration_s)
    .bind(t.target_seed as i64)
    .bind(&new.target_levels_json)
    .bind(new.target_mean_mm)
    .bind(new.target_std_mm)
    .bind(new.target_ms_step_mm2)
    .bind(new.protocol_hash)
    .bind(i64::from(t.queue_order))
    .bind(t.cancellation.as_str())
    .bind(&new.condition)
    .fetch_one(db)
    .await?)
}

/// The highest attempt of `trial`'s slot.
pub async fn latest_attempt<'c>(db: impl AnyExecutor<'c>, trial: &Trial) -> Result<i64> {
    let (latest,): (i64,) =
        sqlx::query_as("SELECT MAX(attempt) FROM trials WHERE subject_id = $1 AND slot = $2")
            .bind(trial.subject_id)
            .bind(trial.slot)
            .fetch_one(db)
            .await?;
    Ok(latest)
}

/// A new scheduled attempt of `trial_id`'s test, with the same design and target, queued at
/// the end of its block — but an identification test keeps its place first in its block:
/// what follows it depends on what it measures (a personalized study's designs, every
/// cancelling test's model); returns its id. (The unique (subject, slot, attempt) makes a racing
/// second re-queue fail.)
pub async fn insert_next_attempt(db: &mut AnyConnection, trial_id: i64) -> Result<i64> {
    Ok(sqlx::query_scalar::<_, i64>(
        "INSERT INTO trials (subject_id, slot, attempt, phase, station, block, position, controller, blinded_label, compensator_json, personalized, k_bf, duration_s, target_seed, target_levels_json, target_mean_mm, target_std_mm, target_ms_step_mm2, protocol_hash, cancellation, cancellation_json, condition, queue_order) \
         SELECT subject_id, slot, attempt + 1, phase, station, block, position, controller, blinded_label, compensator_json, personalized, k_bf, duration_s, target_seed, target_levels_json, target_mean_mm, target_std_mm, target_ms_step_mm2, protocol_hash, cancellation, cancellation_json, condition, \
         CASE WHEN phase = 'identification' THEN queue_order ELSE (SELECT MAX(queue_order) + 1 FROM trials u WHERE u.subject_id = t.subject_id AND u.block = t.block) END \
         FROM trials t WHERE id = $1 RETURNING id",
    )
    .bind(trial_id)
    .fetch_one(db)
    .await?)
}

/// Puts `spec_json`, the subject's own design of `kind`, in place of the design of each of
/// their scored tests of that kind not yet run (every scheduled attempt); returns how many.
pub async fn personalize_scheduled(
    db: &mut AnyConnection,
    subject_id: i64,
    kind: CompensatorKind,
    spec_json: &str,
) -> Result<u64> {
    Ok(sqlx::query(
        "UPDATE trials SET compensator_json = $1, personalized = 1 \
         WHERE subject_id = $2 AND controller = $3 AND phase = 'test' AND status = 'scheduled'",
    )
    .bind(spec_json)
    .bind(subject_id)
    .bind(kind.name())
    .execute(db)
    .await?
    .rows_affected())
}

/// Sets `model_json` as the model of the subject's scheduled tests of `kind` cancelling
/// with `arm`; returns how many.
pub async fn set_cancellation_scheduled(
    db: &mut AnyConnection,
    subject_id: i64,
    kind: CompensatorKind,
    arm: CancellationArm,
    model_json: &str,
) -> Result<u64> {
    Ok(sqlx::query(
        "UPDATE trials SET cancellation_json = $1 \
         WHERE subject_id = $2 AND controller = $3 AND cancellation = $4 AND phase = 'test' AND status = 'scheduled'",
    )
    .bind(model_json)
    .bind(subject_id)
    .bind(kind.name())
    .bind(arm.as_str())
    .execute(db)
    .await?
    .rows_affected())
}

/// The subject's scheduled tests of `kind` cancelling with `arm`.
pub async fn scheduled_cancelling<'c>(
    db: impl AnyExecutor<'c>,
    subject_id: i64,
    kind: CompensatorKind,
    arm: CancellationArm,
) -> Result<Vec<i64>> {
    let ids: Vec<(i64,)> = sqlx::query_as(
        "SELECT id FROM trials WHERE subject_id = $1 AND controller = $2 AND cancellation = $3 \
         AND phase = 'test' AND status = 'scheduled' ORDER BY id",
    )
    .bind(subject_id)
    .bind(kind.name())
    .bind(arm.as_str())
    .fetch_all(db)
    .await?;
    Ok(ids.into_iter().map(|r| r.0).collect())
}

/// Marks a scheduled trial running at `site` (none: a dry run's own controller); fails if
/// it is not scheduled (two starts racing).
pub async fn mark_running(db: &mut AnyConnection, trial_id: i64, site: Option<&str>) -> Result<()> {
    let done = sqlx::query(
        "UPDATE trials SET status = 'running', started_at = $1, site = $2 WHERE id = $3 AND status = 'scheduled'",
    )
    .bind(now_ms())
    .bind(site)
    .bind(trial_id)
    .execute(db)
    .await?;
    if done.rows_affected() == 0 {
        return Err(AppError::Conflict(format!(
            "trial {trial_id} is not waiting to start"
        )));
    }
    Ok(())
}

/// Puts a trial that could not be started back in the queue; `false` when it was no longer
/// running (something filed it meanwhile).
pub async fn unmark_running(db: &mut AnyConnection, trial_id: i64) -> Result<bool> {
    let done = sqlx::query("UPDATE trials SET status = 'scheduled', started_at = NULL, site = NULL WHERE id = $1 AND status = 'running'")
        .bind(trial_id)
        .execute(db)
        .await?;
    Ok(done.rows_affected() == 1)
}

/// The experimenter accepts an attempt as incomplete with `reason`: a scheduled or
/// complete one is filed incomplete, a failed one keeps its status. Refused while it runs
/// or when it is not the latest attempt of its test.
pub async fn accept_incomplete(db: &mut AnyConnection, trial_id: i64, reason: &str) -> Result<()> {
    let done = sqlx::query(
        "UPDATE trials SET accepted_reason = $1, \
         status = CASE WHEN status IN ('scheduled', 'complete') THEN 'incomplete' ELSE status END, \
         status_reason = CASE WHEN status IN ('scheduled', 'complete') THEN $1 ELSE status_reason END \
         WHERE id = $2 AND status != 'running' AND accepted_reason IS NULL \
         AND attempt = (SELECT MAX(attempt) FROM trials u WHERE u.subject_id = trials.subject_id AND u.slot = trials.slot)",
    )
    .bind(reason)
    .bind(trial_id)
    .execute(&mut *db)
    .await?;
    if done.rows_affected() == 0 {
        let t = get(&mut *db, trial_id).await?;
        return Err(AppError::Conflict(if t.status == TrialStatus::Running {
            format!("trial {trial_id} is running: abort it first")
        } else if t.accepted_reason.is_some() {
            format!("trial {trial_id} is already accepted as incomplete")
        } else {
            format!("trial {trial_id} is not the latest attempt of its test")
        }));
    }
    Ok(())
}

/// The server found a running trial invalid: its result will be filed so. `false` when
/// it was not running or already found invalid.
pub async fn mark_invalid(db: &mut AnyConnection, trial_id: i64, reason: &str) -> Result<bool> {
    let done = sqlx::query(
        "UPDATE trials SET invalid_reason = $1 WHERE id = $2 AND status = 'running' AND invalid_reason IS NULL",
    )
    .bind(reason)
    .bind(trial_id)
    .execute(db)
    .await?;
    Ok(done.rows_affected() == 1)
}

/// The running trials of this server's controller, by id. A pilot process's trials
/// (`pilot_trials`) run on its own controller and are left to its heartbeat.
pub async fn running_ids<'c>(db: impl AnyExecutor<'c>) -> Result<Vec<i64>> {
    let ids: Vec<(i64,)> = sqlx::query_as(
        "SELECT id FROM trials WHERE status = 'running' AND id NOT IN (SELECT trial_id FROM pilot_trials) ORDER BY id",
    )
    .fetch_all(db)
    .await?;
    Ok(ids.into_iter().map(|r| r.0).collect())
}

/// The trials running on `site`'s machine (and any running with no site: started before
/// sites existed, so on whichever machine there was).
pub async fn running_ids_at<'c>(db: impl AnyExecutor<'c>, site: &str) -> Result<Vec<i64>> {
    let ids: Vec<(i64,)> = sqlx::query_as(
        "SELECT id FROM trials WHERE status = 'running' AND (site = $1 OR site IS NULL) AND id NOT IN (SELECT trial_id FROM pilot_trials) ORDER BY id",
    )
    .bind(site)
    .fetch_all(db)
    .await?;
    Ok(ids.into_iter().map(|r| r.0).collect())
}

/// Marks those of `ids` that still run incomplete with `reason` (after a server restart or a
/// controller death), or invalid when they were found so; returns the ids marked.
pub async fn interrupt(db: &mut AnyConnection, ids: &[i64], reason: &str) -> Result<Vec<i64>> {
    if ids.is_empty() {
        return Ok(Vec::new());
    }
    // The ids are this program's integers, written into the statement: the two stores
    // share no way to bind a list.
    let list = ids
        .iter()
        .map(i64::to_string)
        .collect::<Vec<_>>()
        .join(", ");
    let marked: Vec<(i64,)> = sqlx::query_as(&format!("UPDATE trials SET status = CASE WHEN invalid_reason IS NULL THEN 'incomplete' ELSE 'invalid' END, status_reason = COALESCE(invalid_reason, $1), finished_at = CASE WHEN COALESCE(started_at, 0) > $2 THEN COALESCE(started_at, 0) ELSE $2 END WHERE status = 'running' AND id IN ({list}) RETURNING id"))
        .bind(reason)
        .bind(now_ms())
        .fetch_all(db)
        .await?;
    Ok(marked.into_iter().map(|r| r.0).collect())
}

/// The station's figures of how the display kept up (JSON), kept with the trial.
pub async fn set_client_timing(db: &mut AnyConnection, trial_id: i64, json: &str) -> Result<()> {
    sqlx::query("UPDATE trials SET client_timing_json = $1 WHERE id = $2")
        .bind(json)
        .bind(trial_id)
        .execute(db)
        .await?;
    Ok(())
}

/// A survey's answers as stored (ratings in item order).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Survey {
    pub accuracy: i64,
    pub speed: i64,
    pub smoothness: i64,
    pub controllability: i64,
    pub comment: String,
}

/// Surveys of a subject's trials, by trial id.
pub async fn surveys_of_subject<'c>(
    db: impl AnyExecutor<'c>,
    subject_id: i64,
) -> Result<Vec<(i64, Survey)>> {
    let rows: Vec<(i64, i64, i64, i64, i64, String)> = sqlx::query_as(
        "SELECT v.trial_id, v.accuracy, v.speed, v.smoothness, v.controllability, v.comment FROM surveys v JOIN trials t ON t.id = v.trial_id WHERE t.subject_id = $1",
    )
    .bind(subject_id)
    .fetch_all(db)
    .await?;
    Ok(rows
        .into_iter()
        .map(
            |(id, accuracy, speed, smoothness, controllability, comment)| {
                (
                    id,
                    Survey {
                        accuracy,
                        speed,
                        smoothness,
                        controllability,
                        comment,
                    },
                )
            },
        )
        .collect())
}

/// Stores a survey's validated ratings; a second answer to the same test is refused.
pub async fn insert_survey(
    db: &mut AnyConnection,
    trial_id: i64,
    ratings: [u8; 4],
    answer: &SurveyAnswer,
) -> Result<()> {
    let done = sqlx::query("INSERT INTO surveys (trial_id, accuracy, speed, smoothness, controllability, comment, submitted_at) VALUES ($1, $2, $3, $4, $5, $6, $7) ON CONFLICT (trial_id) DO NOTHING")
        .bind(trial_id)
        .bind(i64::from(ratings[0]))
        .bind(i64::from(ratings[1]))
        .bind(i64::from(ratings[2]))
        .bind(i64::from(ratings[3]))
        .bind(&answer.comment)
        .bind(now_ms())
        .execute(db)
        .await?;
    if done.rows_affected() == 0 {
        return Err(AppError::Conflict(
            "this test's survey has already been answered".into(),
        ));
    }
    Ok(())
}
