//! Running a trial to its end in the calling thread, as fast as the CPU allows: the same
//! slot code as the real-time loop, without the clock. The server's pilot mode uses it to
//! dry-run whole studies with synthetic subjects, and `bdft-server replay` to run a stored
//! test again (a person's from its recorded hand).

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::{InputSource, Metrics, TimingSummary};

use super::setup::{build_runner, build_slot};
use super::slot::SlotTick;

fn offline(start: &StartTrial) -> Result<(), String> {
    if matches!(start.input, InputSource::Server | InputSource::Udp { .. }) {
        return Err("a trial run offline needs a synthetic operator or a reference input".into());
    }
    Ok(())
}

/// Runs `start` (which must not need outside input) on the simulated rig; returns the result
/// and the record channel by channel.
pub fn run(start: &StartTrial, dt: f64) -> Result<(TrialResult, Vec<Vec<f32>>), String> {
    offline(start)?;
    let mut slot = build_slot(start, dt, false)?.slot;
    let mut tick = 0;
    while !matches!(slot.tick(tick, 0, 0.0), SlotTick::Ended) {
        tick += 1;
    }
    Ok(finish(start, dt, &slot, tick + 1))
}

/// Replays a test of `start` whose input came from outside (a person's), tick by tick from
/// its recorded `hand` channel, on the simulated rig: the record it gives is the stored one,
/// bit for bit, but for the wake latencies (`latency_us`, the stored channel, copied: a
/// replay has no clock). At most as many ticks as `hand` holds.
pub fn replay(
    start: &StartTrial,
    dt: f64,
    hand: &[f32],
    latency_us: &[f32],
) -> Result<(TrialResult, Vec<Vec<f32>>), String> {
    if !matches!(start.input, InputSource::Server | InputSource::Udp { .. }) {
        return Err("a replay from the hand is for a test whose input came from outside".into());
    }
    let mut slot = build_slot(start, dt, false)?.slot;
    let mut ticks = 0;
    for (h, l) in hand.iter().zip(latency_us) {
        ticks += 1;
        if matches!(slot.replay_tick(f64::from(*h), *l), SlotTick::Ended) {
            break;
        }
    }
    Ok(finish(start, dt, &slot, ticks))
}

/// The result and record of a slot run offline for `ticks` ticks.
fn finish(
    start: &StartTrial,
    dt: f64,
    slot: &super::slot::TrialSlot,
    ticks: u64,
) -> (TrialResult, Vec<Vec<f32>>) {
    let result = TrialResult {
        trial_id: start.trial_id,
        outcome: slot.outcome(dt, None),
        metrics: slot.runner.metrics(),
        timing: TimingSummary {
            ticks,
            ..TimingSummary::default()
        },
        dt,
        record_chunks: 0,
        exposure: Some(slot.runner.exposure().0),
        cancellation_off_at_s: slot.runner.cancellation_off_at_s(),
        adaptation: slot.adaptation(),
    };
    (result, slot.record_channels(0, slot.record.len()))
}

/// Runs `start` like `run` but keeps no record: its metrics, if it ran to its end (None when
/// the cab-vibration interlock stopped it). A trial here ticks exactly as in `run`, so its
/// metrics are `run`'s; the batched planner trials (`batch`) are held to it.
pub fn metrics(start: &StartTrial, dt: f64) -> Result<Option<Metrics>, String> {
    offline(start)?;
    let (mut runner, _) = build_runner(start, dt, false)?;
    while !runner.done() {
        runner.tick(0.0);
        if runner.tripped() {
            return Ok(None);
        }
    }
    Ok(Some(runner.metrics()))
}
