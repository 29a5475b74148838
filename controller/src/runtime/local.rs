//! Running a trial to its end in the calling thread, as fast as the CPU allows: the same
//! slot code as the real-time loop, without the clock. The server's pilot mode uses it to
//! dry-run whole studies with synthetic subjects.

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::{InputSource, TimingSummary};

use super::setup::build_slot;
use super::slot::SlotTick;

/// Runs `start` (which must not need outside input) on the simulated rig; returns the result
/// and the record channel by channel.
pub fn run(start: &StartTrial, dt: f64) -> Result<(TrialResult, Vec<Vec<f32>>), String> {
    if matches!(start.input, InputSource::Server | InputSource::Udp { .. }) {
        return Err("a trial run offline needs a synthetic operator or a reference input".into());
    }
    let mut slot = build_slot(start, dt, false)?.slot;
    let mut tick = 0;
    while !matches!(slot.tick(tick, 0, 0.0), SlotTick::Ended) {
        tick += 1;
    }
    let result = TrialResult {
        trial_id: start.trial_id,
        outcome: slot.outcome(dt, None),
        metrics: slot.runner.metrics(),
        timing: TimingSummary {
            ticks: tick + 1,
            ..TimingSummary::default()
        },
        dt,
        record_chunks: 0,
    };
    Ok((result, slot.record_channels(0, slot.record.len())))
}
