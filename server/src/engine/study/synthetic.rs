//! The synthetic subjects of a dry run, as the protocol meets them: each draws its own
//! parameters at enrolment from the study's population (stored with the subject), becomes
//! the operator and body of each of its tests (learning over positions, tiring over time on
//! task), and answers the survey after each completed test from what it perceived.

use bdft_controller::rng::Rng;
use bdft_controller::{perception, population};
use bdft_protocol::params::{BodyModel, OperatorParams, SubjectDraw};
use bdft_protocol::records::TrialStatus;
use bdft_protocol::study::{StudyParams, SurveyAnswer};
use serde::Serialize;
use sqlx::AnyPool;

use crate::error::{AppError, Result};
use crate::store::records::Record;
use crate::store::studies::Study;
use crate::store::subjects::Subject;
use crate::store::trials::Trial;
use crate::store::{self, Change};

/// The seed of the subject enrolled `enrol_index`-th in a study seeded `study_seed`: the
/// draw is a function of (population, study seed, enrolment index) only, like the schedule.
pub fn subject_seed(study_seed: u64, enrol_index: u32) -> u64 {
    Rng::derive(
        study_seed ^ u64::from(enrol_index).wrapping_mul(0x9e37_79b9_7f4a_7c15),
        Rng::POPULATION,
    )
    .next_u64()
}

/// The parameters of the synthetic subject enrolled `enrol_index`-th.
pub fn draw(params: &StudyParams, study_seed: u64, enrol_index: u32) -> SubjectDraw {
    population::draw(&params.population, subject_seed(study_seed, enrol_index))
}

/// Hours of tracking before the test in `slot` of a subject's schedule (the practice, then
/// the scored tests one after another): what fatigue is counted in. Synthetic subjects run
/// faster than real time, so this is the protocol's time on task, not the clock's.
pub fn hours_on_task(params: &StudyParams, slot: u32) -> f64 {
    if slot == 0 {
        return 0.0;
    }
    (params.practice_s + f64::from(slot - 1) * params.trial_s) / 3600.0
}

/// The operator and body of a synthetic subject's test in `slot` of its schedule. A subject
/// enrolled before populations existed has no draw: the default operator with the study's
/// body, as then.
pub fn operator_and_body(
    params: &StudyParams,
    slot: u32,
    draw: Option<&SubjectDraw>,
) -> (OperatorParams, BodyModel) {
    match draw {
        None => (OperatorParams::default(), params.body),
        Some(d) => (
            population::operator(d, slot, hours_on_task(params, slot)),
            population::body(d, params.body),
        ),
    }
}

/// What a synthetic subject's `survey.submit` records: its ratings in item order, and what it
/// perceived of the test (the ratings' cause).
#[derive(Debug, Serialize)]
struct SyntheticAnswer {
    ratings: [u8; 4],
    synthetic: bool,
    perceived: Perceived,
}

/// `perception::Perception` as the audit log names it.
#[derive(Debug, Serialize)]
struct Perceived {
    rms_error_mm: f64,
    felt_rms_m_s2: f64,
    response_time_s: f64,
    seen_shake_mm: f64,
}

/// Files the survey a synthetic subject gives after its completed test `trial`, from the
/// test's record, through the same store and audit as a person's answers. Nothing for a
/// practice, an unfinished test or a subject without a draw.
pub async fn answer_survey(
    pool: &AnyPool,
    actor: &str,
    study: &Study,
    subject: &Subject,
    trial: &Trial,
    record: &Record,
) -> Result<()> {
    let Some(d) = &subject.drawn else {
        return Ok(());
    };
    let trial = store::trials::get(pool, trial.id).await?;
    if !trial.phase.scored() || trial.status != TrialStatus::Complete {
        return Ok(());
    }
    let perceived = perception::perceive_record(&record.channels, trial.seat, record.dt);
    let (ratings, comment) = perception::answer_test(
        d,
        &perceived,
        trial.seat,
        study.params.survey.scale_points,
        trial.target_seed as u64,
    );
    let answer = SurveyAnswer {
        accuracy: Some(i64::from(ratings[0])),
        speed: Some(i64::from(ratings[1])),
        smoothness: Some(i64::from(ratings[2])),
        controllability: Some(i64::from(ratings[3])),
        comment,
    };
    // The same check as a person's answers: a model that left the scale is a bug to see.
    let ratings = answer
        .validate(study.params.survey.scale_points)
        .map_err(AppError::Fields)?;
    let mut change = Change::begin(pool, actor).await?;
    store::trials::insert_survey(change.db(), trial.id, ratings, &answer).await?;
    change
        .commit(
            "survey.submit",
            Some(format!("trial:{}", trial.id)),
            SyntheticAnswer {
                ratings,
                synthetic: true,
                perceived: Perceived {
                    rms_error_mm: perceived.rms_error_mm,
                    felt_rms_m_s2: perceived.felt_rms_m_s2,
                    response_time_s: perceived.response_time_s,
                    seen_shake_mm: perceived.seen_shake_mm,
                },
            },
        )
        .await
}
