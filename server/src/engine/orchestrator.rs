//! From a scheduled trial to the controller's `StartTrial` and back to the database: the one
//! path that live tests and pilot runs share.

use bdft_controller::rng::Rng;
use bdft_protocol::params::{CompensatorSpec, SubjectDraw};
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::{InputSource, TargetSpec};

use super::synthetic::operator_and_body;
use crate::error::{AppError, Result};
use crate::store::studies::Study;
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

/// The controller message that runs `trial` of `study`.
pub fn start_message(study: &Study, trial: &Trial, operator: Operator) -> Result<StartTrial> {
    let bad = |what: &str, e: serde_json::Error| {
        AppError::Internal(anyhow::anyhow!("stored {what} of trial {}: {e}", trial.id))
    };
    let compensator: CompensatorSpec =
        serde_json::from_str(&trial.compensator_json).map_err(|e| bad("compensator", e))?;
    let levels_mm: Vec<f64> =
        serde_json::from_str(&trial.target_levels_json).map_err(|e| bad("target", e))?;
    let seed = trial.target_seed as u64;
    let (input, body) = match operator {
        Operator::Person => (InputSource::Server, study.params.body),
        Operator::Synthetic(draw) => {
            let (operator, body) = operator_and_body(&study.params, trial, draw.as_ref());
            let seed = Rng::derive(seed, Rng::OPERATOR).next_u64();
            (InputSource::Synthetic { operator, seed }, body)
        }
    };
    Ok(StartTrial {
        trial_id: trial.id as u64,
        compensator,
        station: trial.seat,
        k_bf: trial.k_bf,
        target: TargetSpec::Steps {
            interval_s: study.params.step_interval_s,
            levels_mm,
        },
        duration_s: trial.duration_s,
        input,
        plant: study.params.plant,
        body,
        noise_seed: Rng::derive(seed, Rng::ACCEL_NOISE).next_u64(),
        live_rate_hz: 100.0,
        stale_input_ms: study.params.stale_input_ms,
        max_cab_rms_mm_s2: study.params.max_cab_rms_mm_s2,
    })
}
