//! From a scheduled trial to the controller's `StartTrial` and back to the database: the one
//! path that live tests, pilot runs and the power planner's simulated studies share.

use bdft_controller::rng::Rng;
use bdft_protocol::cancellation::CancellationModel;
use bdft_protocol::params::{CompensatorSpec, MachineCondition, ParamError, Seat, SubjectDraw};
use bdft_protocol::records::TestPhase;
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::study::StudyParams;
use bdft_protocol::trial::{InputSource, TargetSpec};

use sqlx::AnyConnection;

use crate::engine::study::exposure::allowance_for;
use crate::engine::study::schedule::identification_target;
use crate::engine::study::synthetic::operator_and_body;
use crate::error::{AppError, Result};
use crate::store::studies::Study;
use crate::store::subjects::Subject;
use crate::store::trials::Trial;

/// Who moves the input device in a trial.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Operator {
    /// A person at a station (browser input through the server).
    Person,
    /// A synthetic subject (pilot runs, automated tests) with its drawn parameters, or
    /// none for one enrolled before populations existed.
    Synthetic(Option<SubjectDraw>),
}

/// One test as the protocol scheduled it, in the terms a `StartTrial` needs.
#[derive(Debug, Clone)]
pub struct TestRun {
    pub trial_id: u64,
    pub compensator: CompensatorSpec,
    pub seat: Seat,
    /// Place in the subject's schedule (0 = practice): how far they have learned.
    pub slot: u32,
    pub k_bf: f64,
    pub target: TargetSpec,
    pub duration_s: f64,
    pub target_seed: u64,
    /// The model the test cancels with (none: uncancelled).
    pub cancellation: Option<CancellationModel>,
    /// The machine's condition the test runs under (the study's, or the subject's level of
    /// its condition factor).
    pub condition: MachineCondition,
}

/// The controller message that runs `trial` of `study`.
pub fn start_message(study: &Study, trial: &Trial, operator: Operator) -> Result<StartTrial> {
    let bad = |what: &str, e: serde_json::Error| {
        AppError::Internal(anyhow::anyhow!("stored {what} of trial {}: {e}", trial.id))
    };
    let run = TestRun {
        trial_id: trial.id as u64,
        compensator: serde_json::from_str(&trial.compensator_json)
            .map_err(|e| bad("compensator", e))?,
        seat: trial.seat,
        // How far the subject has learned: an identification test comes after as many
        // tests as its queue order says (its slot is after every scored test).
        slot: u32::try_from(match trial.phase {
            TestPhase::Identification => trial.queue_order,
            _ => trial.slot,
        })
        .unwrap_or(0),
        k_bf: trial.k_bf,
        target: match trial.phase {
            TestPhase::Identification => {
                identification_target(&study.params, trial.target_seed as u64).ok_or_else(|| {
                    AppError::Internal(anyhow::anyhow!(
                        "trial {} is an identification test of a study without identification",
                        trial.id
                    ))
                })?
            }
            _ => TargetSpec::Steps {
                interval_s: study.params.step_interval_s,
                levels_mm: serde_json::from_str(&trial.target_levels_json)
                    .map_err(|e| bad("target", e))?,
            },
        },
        duration_s: trial.duration_s,
        target_seed: trial.target_seed as u64,
        cancellation: super::cancellation::model_of(trial)?,
        condition: trial.condition.parse().map_err(|e: ParamError| {
            AppError::Internal(anyhow::anyhow!(
                "stored condition of trial {}: {e}",
                trial.id
            ))
        })?,
    };
    Ok(start(&study.params, run, operator))
}

/// The controller message that starts `trial` of `subject` now: with the exposure allowance
/// its subject's day has left, read on `db` — the change that marks the trial running, so
/// no other test of the subject slips in between —, or the 409 when nothing is left.
pub async fn start_now(
    db: &mut AnyConnection,
    study: &Study,
    trial: &Trial,
    subject: &Subject,
    operator: Operator,
) -> Result<StartTrial> {
    let mut msg = start_message(study, trial, operator)?;
    msg.exposure_allowance =
        allowance_for(db, &study.params, subject, trial.seat, trial.duration_s).await?;
    Ok(msg)
}

/// The controller message that runs `run` of a study with `params`.
pub fn start(params: &StudyParams, run: TestRun, operator: Operator) -> StartTrial {
    let seed = run.target_seed;
    let (input, body) = match operator {
        Operator::Person => (InputSource::Server, params.body),
        Operator::Synthetic(draw) => {
            let (operator, body) = operator_and_body(params, run.slot, draw.as_ref());
            let seed = Rng::derive(seed, Rng::OPERATOR).next_u64();
            (InputSource::Synthetic { operator, seed }, body)
        }
    };
    StartTrial {
        trial_id: run.trial_id,
        compensator: run.compensator,
        seat: run.seat,
        k_bf: run.k_bf,
        target: run.target,
        duration_s: run.duration_s,
        input,
        plant: params.plant,
        body,
        noise_seed: Rng::derive(seed, Rng::ACCEL_NOISE).next_u64(),
        live_rate_hz: 100.0,
        stale_input_ms: params.stale_input_ms,
        max_cab_rms_mm_s2: params.max_cab_rms_mm_s2,
        // Set by the start policy from the subject's day (`procedure::exposure`).
        exposure_allowance: None,
        cancellation: run.cancellation,
        condition: run.condition,
    }
}
