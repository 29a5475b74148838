//! The `StartTrial` messages the controller tests send: a synthetic operator's trial that
//! reproduces `simulate` with the same settings, and a trial whose input the server sends.

use bdft_controller::compensator::default_spec;
use bdft_controller::rng::Rng;
use bdft_protocol::params::{
    BodyModel, CompensatorKind, OperatorParams, PlantParams, Seat, StepParams,
};
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::{InputSource, TargetSpec};

/// The StartTrial that reproduces `simulate` with these settings (same target, same noise,
/// same synthetic operator seeds).
pub(crate) fn synthetic_trial(
    trial_id: u64,
    kind: CompensatorKind,
    seat: Seat,
    k_bf: f64,
    duration_s: f64,
    seed: u64,
) -> StartTrial {
    let plant = PlantParams::default();
    let target = bdft_controller::signals::StepTarget::generate(
        &StepParams::default(),
        duration_s.max(4.0),
        seed,
    )
    .unwrap();
    StartTrial {
        trial_id,
        compensator: default_spec(kind, &plant),
        seat,
        k_bf,
        target: TargetSpec::Steps {
            interval_s: target.interval_s,
            levels_mm: target.levels_mm,
        },
        duration_s,
        input: InputSource::Synthetic {
            operator: OperatorParams::default(),
            seed,
        },
        plant,
        body: BodyModel::default(),
        noise_seed: Rng::derive(seed, Rng::ACCEL_NOISE).next_u64(),
        live_rate_hz: 100.0,
        stale_input_ms: 100.0,
        max_cab_rms_mm_s2: bdft_protocol::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2,
        exposure_allowance: None,
        cancellation: None,
        condition: Default::default(),
    }
}

pub(crate) fn server_input_trial(trial_id: u64, duration_s: f64) -> StartTrial {
    StartTrial {
        input: InputSource::Server,
        ..synthetic_trial(
            trial_id,
            CompensatorKind::Lqr,
            Seat::Off,
            0.6,
            duration_s,
            1,
        )
    }
}
