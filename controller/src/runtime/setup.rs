//! Turns a `StartTrial` message into a ready slot: validates it, designs the compensator,
//! builds the rig loop (with its canceller, if the test cancels) and the operator, and reserves the record. Runs on the I/O side,
//! where allocating and taking milliseconds is fine.

use std::sync::Arc;

use bdft_protocol::params::LoopParams;
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::{InputSource, TargetSpec};

use super::handoff::InputCell;
use super::slot::{ExternalLoop, SlotLoop, TrialSlot};
use crate::cancellation::Canceller;
use crate::closed_loop::{ClosedLoop, LoopSetup};
use crate::compensator::Compensator;
use crate::operator::SyntheticOperator;
use crate::runner::{HandSource, TrialRunner};
use crate::signals::Signal;

/// A built trial and, for input fed from outside, the cell to write it into.
#[derive(Debug)]
pub struct Built {
    pub slot: Box<TrialSlot>,
    pub input: Option<Arc<InputCell>>,
}

/// Builds the slot; the error says what is wrong with the request.
pub fn build_slot(st: &StartTrial, dt: f64, real_rig: bool) -> Result<Built, String> {
    let (runner, input) = build_runner(st, dt, real_rig)?;
    let stale_ticks = (st.stale_input_ms * 1e-3 / dt).round() as u64;
    let live_every = (1.0 / (st.live_rate_hz * dt)).round().max(1.0) as u64;
    let slot = Box::new(TrialSlot::new(
        st.trial_id,
        runner,
        input.clone(),
        stale_ticks,
        live_every,
    ));
    Ok(Built { slot, input })
}

/// The trial's runner — rig loop, operator, target and interlock — and, for input fed from
/// outside, the cell to write it into.
pub fn build_runner(
    st: &StartTrial,
    dt: f64,
    real_rig: bool,
) -> Result<(TrialRunner<SlotLoop>, Option<Arc<InputCell>>), String> {
    st.validate().map_err(|e| e.to_string())?;
    let setup = LoopSetup {
        plant: st.plant,
        body: st.body,
        loop_params: LoopParams { dt, k_bf: st.k_bf },
        seat: st.seat,
        compensator: st.compensator.clone(),
    };
    // The same cancellation on either rig (`closed_loop::reference_from_device`).
    let canceller = st
        .cancellation
        .map(|m| Canceller::new(&m, dt))
        .transpose()
        .map_err(|e| e.to_string())?;
    let lp = if real_rig {
        let comp = Compensator::build(&st.compensator, &st.plant, dt).map_err(|e| e.to_string())?;
        let mut rig = ExternalLoop::new(comp, st.k_bf, st.plant.v_max);
        rig.canceller = canceller;
        SlotLoop::Rig(rig)
    } else {
        // The compensator designed for the study's rig, run on the rig under its condition.
        let rig = st.condition.apply(&st.plant).map_err(|e| e.to_string())?;
        let mut sim = ClosedLoop::new(&setup, st.noise_seed)
            .and_then(|lp| lp.with_rig(rig, st.noise_seed))
            .map_err(|e| e.to_string())?;
        sim.set_canceller(canceller);
        SlotLoop::Sim(sim)
    };
    let (hand, input) = match st.input {
        InputSource::Server | InputSource::Udp { .. } => {
            (HandSource::External, Some(Arc::new(InputCell::default())))
        }
        InputSource::Synthetic { operator, seed } => {
            let mut op = SyntheticOperator::new(operator, dt, st.k_bf.max(1e-3), seed)
                .map_err(|e| e.to_string())?;
            if let TargetSpec::Identification { task, .. } = st.target {
                op = op.holding(task);
            }
            (HandSource::Synthetic(op), None)
        }
        InputSource::Reference => (HandSource::Reference, None),
    };
    let runner = TrialRunner::new(
        Signal::from_spec(&st.target, st.duration_s, dt).map_err(|e| e.to_string())?,
        lp,
        hand,
        dt,
        st.duration_s,
    )
    .with_interlock(st.max_cab_rms_mm_s2)
    .with_exposure_allowance(st.exposure_allowance);
    Ok((runner, input))
}
