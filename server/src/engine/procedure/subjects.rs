//! What a subject does and what is known of them: consent, surveys, the station's timing
//! figures, withdrawal, progress, and the views of a subject for the experimenter and for
//! the subject's own page.

use bdft_protocol::browser_to_server::{RttPercentiles, SurveySubmission, TimingReport};
use bdft_protocol::records::{ConsentDecision, TestPhase, TrialStatus};
use bdft_protocol::server_to_browser::HeldTest;
use bdft_protocol::server_to_controller::ServerToController;
use serde::Serialize;
use sqlx::AnyPool;

use super::lsl::{self, Marker};
use super::queue;
use super::stations::consent_form;
use super::trials::site_of_trial;
use crate::engine::machine::sites::Sites;
use crate::engine::study::exposure::{self, SubjectExposure};
use crate::error::{AppError, Result};
use crate::store::subjects::{Note, Subject};
use crate::store::trials::{Survey, Trial, latest_attempts};
use crate::store::{self, Change};

/// What `consent` records: the decision, on which version of the form, at which station.
#[derive(Debug, Serialize)]
struct Consented<'a> {
    decision: ConsentDecision,
    version: &'a str,
    /// SHA-256 of the form's text the decision was made on.
    text_sha256: &'a str,
    station: &'a str,
}

/// Records the subject's consent decision on the study's current form.
pub async fn consent(
    pool: &AnyPool,
    subject_id: i64,
    decision: ConsentDecision,
    station_name: &str,
) -> Result<()> {
    let subject = store::subjects::get(pool, subject_id).await?;
    let study = store::studies::get(pool, subject.study_id).await?;
    let form = consent_form(&study);
    let version = &form.version;
    let text_sha256 = &bdft_protocol::hex::sha256(form.text.as_bytes());
    let mut change = Change::begin(pool, format!("subject:{}", subject.code)).await?;
    store::subjects::record_consent(change.db(), subject_id, version, text_sha256, decision)
        .await?;
    change
        .commit(
            "consent",
            Some(format!("subject:{subject_id}")),
            Consented {
                decision,
                version,
                text_sha256,
                station: station_name,
            },
        )
        .await
}

/// What a person's `survey.submit` records: the ratings in item order, and how long the
/// comment is (not what it says).
#[derive(Debug, Serialize)]
struct Answered {
    ratings: [u8; 4],
    comment_chars: usize,
}

/// Stores the survey of a completed test of the subject; every bad field is reported and
/// nothing is stored unless all are right.
pub async fn answer_survey(pool: &AnyPool, trial: &Trial, answer: &SurveySubmission) -> Result<()> {
    if !trial.phase.scored() || trial.status != TrialStatus::Complete {
        return Err(AppError::Conflict(
            "only a completed test has a survey".into(),
        ));
    }
    let subject = store::subjects::get(pool, trial.subject_id).await?;
    let study = store::studies::get(pool, subject.study_id).await?;
    let ratings = answer
        .answer
        .validate(study.params.survey.scale_points)
        .map_err(AppError::Fields)?;
    let mut change = Change::begin(pool, format!("subject:{}", subject.code)).await?;
    store::trials::insert_survey(change.db(), trial.id, ratings, &answer.answer).await?;
    change
        .commit(
            "survey.submit",
            Some(format!("trial:{}", trial.id)),
            Answered {
                ratings,
                comment_chars: answer.answer.comment.chars().count(),
            },
        )
        .await?;
    lsl::mark_trial(pool, trial.id, Marker::Survey { trial_id: trial.id }).await;
    Ok(())
}

/// The station's figures of how its display kept up during a test, as the trial keeps them
/// (`client_timing_json`) and `trial.timing` records them: the report without its trial.
#[derive(Debug, Serialize)]
struct StationTiming<'a> {
    frames: u64,
    long_frames: u64,
    longest_gap_ms: f64,
    hidden_ms: f64,
    input_hz: f64,
    rtt_ms: &'a RttPercentiles,
}

/// Keeps the station's figures of how its display kept up during a test.
pub async fn report_timing(
    pool: &AnyPool,
    station_name: &str,
    report: &TimingReport,
) -> Result<()> {
    report.validate().map_err(AppError::BadRequest)?;
    let timing = StationTiming {
        frames: report.frames,
        long_frames: report.long_frames,
        longest_gap_ms: report.longest_gap_ms,
        hidden_ms: report.hidden_ms,
        input_hz: report.input_hz,
        rtt_ms: &report.rtt_ms,
    };
    let mut change = Change::begin(pool, format!("station:{station_name}")).await?;
    store::trials::set_client_timing(change.db(), report.trial_id, &store::json_text(&timing)?)
        .await?;
    change
        .commit(
            "trial.timing",
            Some(format!("trial:{}", report.trial_id)),
            timing,
        )
        .await
}

/// What `subject.withdraw` records: why, the test that was running, and whether its stop
/// reached the controller.
#[derive(Debug, Serialize)]
struct Withdrawn<'a> {
    reason: &'a str,
    running_trial: Option<i64>,
    stop_sent: Option<bool>,
}

/// Records the withdrawal and stops the subject's running test at once (the controller
/// files it aborted); returns the stopped trial, if one was running.
pub async fn withdraw(
    pool: &AnyPool,
    sites: &Sites,
    actor: &str,
    subject_id: i64,
    reason: &str,
) -> Result<Option<i64>> {
    crate::engine::check_reason(reason)?;
    let mut change = Change::begin(pool, actor).await?;
    store::subjects::withdraw(change.db(), subject_id, reason).await?;
    let running = store::trials::next(change.db(), subject_id)
        .await?
        .filter(|t| t.status == TrialStatus::Running);
    // Stopped before the commit is acknowledged, on its site's machine: a withdrawn person
    // is never driven on.
    let stopped = running.as_ref().map(|t| {
        site_of_trial(sites, t).is_ok_and(|link| {
            link.send(&ServerToController::AbortTrial {
                trial_id: t.id as u64,
                reason: format!("the subject withdrew: {reason}"),
            })
            .is_ok()
        })
    });
    let running = running.map(|t| t.id);
    change
        .commit(
            "subject.withdraw",
            Some(format!("subject:{subject_id}")),
            Withdrawn {
                reason,
                running_trial: running,
                stop_sent: stopped,
            },
        )
        .await?;
    Ok(running)
}

/// What the audit log and the experimenter see when a subject withdrew on their own page
/// without saying why (they owe no reason).
const NO_REASON: &str = "withdrawn by the subject on their own page (no reason given)";

/// The subject withdraws on their own page; the reason is optional.
pub async fn withdraw_own(
    pool: &AnyPool,
    sites: &Sites,
    subject: &Subject,
    reason: Option<&str>,
) -> Result<Option<i64>> {
    let reason = match reason.map(str::trim) {
        Some(r) if !r.is_empty() => r,
        _ => NO_REASON,
    };
    let actor = format!("subject:{}", subject.code);
    withdraw(pool, sites, &actor, subject.id, reason).await
}

/// A subject in the experimenter's list, with how far they are.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct SubjectProgress {
    pub subject: Subject,
    /// Scored tests whose latest attempt is complete.
    pub tests_complete: usize,
    /// Scored tests in the schedule.
    pub tests: usize,
}

pub async fn progress_of_study(pool: &AnyPool, study_id: i64) -> Result<Vec<SubjectProgress>> {
    store::studies::get(pool, study_id).await?;
    let mut out = Vec::new();
    for subject in store::subjects::of_study(pool, study_id).await? {
        let trials = store::trials::of_subject(pool, subject.id).await?;
        let scored = || latest_attempts(&trials).filter(|t| t.phase.scored());
        out.push(SubjectProgress {
            tests_complete: scored()
                .filter(|t| t.status == TrialStatus::Complete)
                .count(),
            tests: scored().count(),
            subject,
        });
    }
    Ok(out)
}

/// One attempt with its survey, for the experimenter.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct TrialWithSurvey {
    pub trial: Trial,
    pub survey: Option<Survey>,
}

/// Everything about one subject, for the experimenter (with real compensator names).
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct SubjectDetail {
    pub subject: Subject,
    pub trials: Vec<TrialWithSurvey>,
    pub notes: Vec<Note>,
    /// Vibration exposure (ISO 2631-1) day by day against the study's budget.
    pub exposure: SubjectExposure,
    /// The test a station would run next (none while the schedule is held or finished).
    pub next_trial_id: Option<i64>,
    /// The failed test the schedule waits on until the experimenter redoes it or accepts
    /// it as incomplete (a practice never completed holds every scored test).
    pub held: Option<HeldTest>,
}

pub async fn detail(pool: &AnyPool, subject_id: i64) -> Result<SubjectDetail> {
    let subject = store::subjects::get(pool, subject_id).await?;
    let mut surveys = store::trials::surveys_of_subject(pool, subject_id).await?;
    let attempts = store::trials::of_subject(pool, subject_id).await?;
    let next_trial_id = store::trials::next(pool, subject_id).await?.map(|t| t.id);
    let held = if next_trial_id.is_none() && queue::anything_missing(&attempts) {
        queue::held_test(&attempts)
    } else {
        None
    };
    let trials = attempts
        .into_iter()
        .map(|trial| {
            let survey = surveys
                .iter()
                .position(|(id, _)| *id == trial.id)
                .map(|i| surveys.swap_remove(i).1);
            TrialWithSurvey { trial, survey }
        })
        .collect();
    let study = store::studies::get(pool, subject.study_id).await?;
    let exposure = exposure::days(&mut *pool.acquire().await?, &study.params, subject.id).await?;
    Ok(SubjectDetail {
        subject,
        trials,
        notes: store::subjects::notes(pool, subject_id).await?,
        exposure,
        next_trial_id,
        held,
    })
}

/// One test as the subject's own page shows it: blinded.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct OwnTest {
    pub label: String,
    /// The seat (the page's key: `station`).
    #[serde(rename = "station")]
    pub seat: bdft_protocol::params::Seat,
    pub status: TrialStatus,
    pub phase: TestPhase,
}

/// The subject's own page: their progress, blinded (no compensator names, no metrics).
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct OwnProgress {
    pub code: String,
    pub consent: Option<ConsentDecision>,
    pub withdrawn: bool,
    /// Scored tests whose latest attempt is complete.
    pub tests_complete: usize,
    /// Scored tests in the schedule.
    pub tests_total: usize,
    pub tests: Vec<OwnTest>,
}

pub async fn own_progress(pool: &AnyPool, subject: Subject) -> Result<OwnProgress> {
    let trials = store::trials::of_subject(pool, subject.id).await?;
    let scored = || latest_attempts(&trials).filter(|t| t.phase.scored());
    Ok(OwnProgress {
        tests_complete: scored()
            .filter(|t| t.status == TrialStatus::Complete)
            .count(),
        tests_total: scored().count(),
        tests: latest_attempts(&trials)
            .map(|t| OwnTest {
                label: t.blinded_label.clone(),
                seat: t.seat,
                status: t.status,
                phase: t.phase,
            })
            .collect(),
        code: subject.code,
        consent: subject.consent_decision,
        withdrawn: subject.withdrawn_at.is_some(),
    })
}
