//! A trial as the real-time loop holds it: built (and allocated) on the I/O side, moved into
//! the loop by pointer, ticked without allocating, and moved back when it ends.

use std::sync::Arc;

use bdft_protocol::controller_to_server::LiveSample;
use bdft_protocol::trial::{FaultKind, Outcome, RECORD_CHANNELS, TrialId};

use super::handoff::InputCell;
use super::histogram::Histogram;
use super::rig_udp::Implausible;
use crate::cancellation::{Cancelled, Canceller};
use crate::closed_loop::{ClosedLoop, Drive, TickRecord, reference_from_device};
use crate::compensator::{AdaptationStatus, Compensator};
use crate::interlock::WINDOW_S;
use crate::model::{Measurement, saturate};
use crate::runner::{Loop, Sample, TrialRunner};

/// The loop of a trial on a real rig: the compensator alone. The rig's sensors are copied in
/// before the tick and the command out after it; the body is real, so no feedthrough is
/// simulated.
#[derive(Debug)]
pub struct ExternalLoop {
    compensator: Compensator,
    k_bf: f64,
    v_max: f64,
    /// Model-based cancellation, when the test has it (`StartTrial::cancellation`).
    pub canceller: Option<Canceller>,
    pub measurement: Measurement,
    pub command: f64,
}

impl ExternalLoop {
    pub fn new(compensator: Compensator, k_bf: f64, v_max: f64) -> Self {
        Self {
            compensator,
            k_bf,
            v_max,
            canceller: None,
            measurement: Measurement::default(),
            command: 0.0,
        }
    }
}

impl Loop for ExternalLoop {
    #[inline]
    fn tick(&mut self, drive: Drive) -> TickRecord {
        let m = self.measurement;
        // The device is the person's hand, feedthrough and all.
        let (hand, r_c, cancelled) = match drive {
            Drive::Hand(p) => {
                let (r_c, c) =
                    reference_from_device(self.k_bf, p, m.cab_accel, &mut self.canceller);
                (p, r_c, c)
            }
            Drive::Reference(r) => (0.0, r, Cancelled::default()),
            Drive::Excited { hand, r_c } => (hand, r_c, Cancelled::default()),
        };
        self.command = saturate(self.compensator.step(r_c, m), self.v_max);
        TickRecord {
            hand,
            feedthrough: 0.0,
            r_c,
            valve: self.command,
            y: m.y,
            cab_accel: m.cab_accel,
            cancellation: cancelled.output_mm,
            cancellation_tripped: cancelled.tripped_now,
        }
    }
    fn displayed_y(&self) -> f64 {
        self.measurement.y
    }
}

#[derive(Debug)]
// The slot is boxed as a whole and one variant is used per process, so the size difference
// costs nothing; boxing the variant would add a pointer chase to every tick.
#[allow(clippy::large_enum_variant)]
pub enum SlotLoop {
    Sim(ClosedLoop),
    Rig(ExternalLoop),
}

impl Loop for SlotLoop {
    #[inline]
    fn tick(&mut self, drive: Drive) -> TickRecord {
        match self {
            Self::Sim(l) => Loop::tick(l, drive),
            Self::Rig(l) => l.tick(drive),
        }
    }
    fn displayed_y(&self) -> f64 {
        match self {
            Self::Sim(l) => l.displayed_y(),
            Self::Rig(l) => l.displayed_y(),
        }
    }
    fn felt_accel(&self) -> f64 {
        match self {
            Self::Sim(l) => Loop::felt_accel(l),
            Self::Rig(l) => l.felt_accel(),
        }
    }
    fn set_grip(&mut self, grip: f64) {
        match self {
            Self::Sim(l) => Loop::set_grip(l, grip),
            Self::Rig(l) => l.set_grip(grip),
        }
    }
}

/// Why a trial ended (strings are added on the I/O side; the loop does not allocate).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndReason {
    Complete,
    Aborted,
    Faulted(FaultKind),
}

/// One record row: the channels of `RECORD_CHANNELS`.
pub type RecordRow = [f32; RECORD_CHANNELS.len()];

/// A trial in the loop. The fields the tick reads come first and the timing histograms
/// (30 KB, recorded after the tick's work is timed) last, in this order (`repr(C)`): the
/// per-tick state is then some 20 consecutive cache lines on one or two pages, not lines
/// spread over the eight pages of the whole slot (the loop's sleeps leave its caches and
/// TLB cold, so every line and page it touches costs a miss).
#[derive(Debug)]
#[repr(C)]
pub struct TrialSlot {
    pub runner: TrialRunner<SlotLoop>,
    /// Full-rate record, capacity reserved for the whole trial.
    pub record: Vec<RecordRow>,
    /// Operator input for an external hand source.
    pub input: Option<Arc<InputCell>>,
    pub start_tick: Option<u64>,
    pub end: Option<EndReason>,
    pub trial_id: TrialId,
    pub stale_ticks: u64,
    pub live_every: u64,
    /// Offset of this trial's live samples within each `live_every` ticks, set by the loop
    /// from the trial's place: trials started together then send theirs on different ticks,
    /// not all on one tick in `live_every`, which would be the slowest tick of the loop.
    pub live_phase: u64,
    pub last_input_seq: u64,
    /// Trial tick of the last live sample sent for new input (`u64::MAX` before the first).
    pub last_echo: u64,
    /// `seq` of the newest input a live sample has carried back.
    pub echoed_seq: u64,
    pub overruns_at_start: u64,
    pub overruns: u64,
    /// What was wrong with the rig reading that ended the trial.
    pub rig_fault: Option<Implausible>,
    pub wake: Histogram,
    pub compute: Histogram,
}

/// An empty record with room for the whole trial, its pages already touched: otherwise the
/// tick would take a page fault every ~110 samples when memory is not locked. The rows are
/// filled with −0.0, not 0.0: `vec!` of all-zero bits asks the allocator for zeroed memory,
/// which for a large buffer is fresh pages from the kernel that nothing has touched yet.
fn prefaulted(rows: usize) -> Vec<RecordRow> {
    let mut v = vec![[-0.0; RECORD_CHANNELS.len()]; rows];
    v.clear();
    v
}

/// Fewest ticks between two live samples sent for new input: 2 ms, so input up to 500 Hz
/// (the stations' limit) is echoed at once — at 4 ms, 250 Hz input with jitter drifted
/// into echoes up to 3 ms late —, and the live samples of a trial stay below 600 a second
/// (these and the regular 100 Hz) whatever the input rate.
const ECHO_SPACING: u64 = 2;

/// What one tick of a slot produced.
#[derive(Debug)]
pub enum SlotTick {
    Running,
    Live(LiveSample),
    Ended,
}

impl TrialSlot {
    pub fn new(
        trial_id: TrialId,
        runner: TrialRunner<SlotLoop>,
        input: Option<Arc<InputCell>>,
        stale_ticks: u64,
        live_every: u64,
    ) -> Self {
        let (_, total) = runner.progress();
        Self {
            trial_id,
            runner,
            input,
            stale_ticks,
            live_every: live_every.max(1),
            live_phase: 0,
            start_tick: None,
            last_input_seq: 0,
            last_echo: u64::MAX,
            echoed_seq: 0,
            record: prefaulted(total as usize),
            wake: Histogram::default(),
            compute: Histogram::default(),
            overruns_at_start: 0,
            overruns: 0,
            end: None,
            rig_fault: None,
        }
    }

    /// What the trial's adaptive compensator did (None for a fixed design).
    pub fn adaptation(&self) -> Option<AdaptationStatus> {
        match self.runner.loop_ref() {
            SlotLoop::Sim(l) => l.compensator().adaptation(),
            SlotLoop::Rig(l) => l.compensator.adaptation(),
        }
    }

    pub fn uses_rig(&self) -> bool {
        matches!(self.runner.loop_ref(), SlotLoop::Rig(_))
    }

    /// Ends the trial now (the caller stops ticking it; the valve gets no further command).
    pub fn end(&mut self, reason: EndReason) {
        if self.end.is_none() {
            self.end = Some(reason);
        }
    }

    /// One tick at loop tick `now`, woken at `wake_ns` (CLOCK_MONOTONIC); `latency_us` is
    /// this tick's wake latency.
    #[inline]
    pub fn tick(&mut self, now: u64, wake_ns: u64, latency_us: f32) -> SlotTick {
        let start = *self.start_tick.get_or_insert(now);
        let mut hand = 0.0;
        if let Some(cell) = &self.input {
            match cell.read() {
                Some(s) if now.saturating_sub(s.arrival_tick) <= self.stale_ticks => {
                    // As the record stores it (f32: 0.01 µm at 100 mm), so a replay from
                    // the record ticks with the very hand this tick used.
                    hand = f64::from(s.position_mm as f32);
                    self.last_input_seq = s.seq;
                }
                None if now - start <= self.stale_ticks => {}
                _ => {
                    self.end(EndReason::Faulted(FaultKind::StaleInput));
                    return SlotTick::Ended;
                }
            }
        }
        self.step(hand, wake_ns, latency_us)
    }

    /// One tick with `hand` as the outside input (the replay of a recorded test: the hand
    /// channel tick by tick, no clock, no staleness).
    pub fn replay_tick(&mut self, hand: f64, latency_us: f32) -> SlotTick {
        self.step(hand, 0, latency_us)
    }

    /// The tick's work once its input is known.
    #[inline]
    fn step(&mut self, hand: f64, wake_ns: u64, latency_us: f32) -> SlotTick {
        let (k, _) = self.runner.progress();
        let s: Sample = self.runner.tick(hand);
        self.record
            .push(s.record_row(f64::from(latency_us)).map(|v| v as f32));
        if self.runner.tripped() {
            self.end(EndReason::Faulted(FaultKind::CabVibration));
            return SlotTick::Ended;
        }
        if self.runner.exposure_used_up() {
            self.end(EndReason::Faulted(FaultKind::ExposureBudget));
            return SlotTick::Ended;
        }
        if self.runner.done() {
            self.end(EndReason::Complete);
            return SlotTick::Ended;
        }
        // Besides the regular live samples, one as soon as a tick has used input no live
        // sample has carried back yet: the station sees its input's effect within a tick
        // instead of up to a live period later (input → display within one frame). At most
        // one per ECHO_SPACING ticks, so a 1 kHz input source cannot turn every tick into a
        // live sample; input that arrives sooner is echoed when the spacing allows.
        let echo = self.last_input_seq != self.echoed_seq
            && k.wrapping_sub(self.last_echo) >= ECHO_SPACING;
        if echo {
            self.last_echo = k;
        }
        if echo || (k + self.live_phase) % self.live_every == 0 {
            self.echoed_seq = self.last_input_seq;
            return SlotTick::Live(LiveSample {
                trial_id: self.trial_id,
                t: s.t,
                target_mm: s.target,
                device_mm: s.device(),
                cylinder_mm: s.y,
                cab_accel_mm_s2: s.cab_accel,
                input_seq: self.last_input_seq,
                stamp_us: wake_ns / 1000,
            });
        }
        SlotTick::Running
    }
}

impl TrialSlot {
    /// How the trial ended, with the words a person reads; `abort_reason` is the server's.
    pub fn outcome(&self, dt: f64, abort_reason: Option<String>) -> Outcome {
        match self.end.unwrap_or(EndReason::Faulted(FaultKind::Internal)) {
            EndReason::Complete => Outcome::Complete,
            EndReason::Aborted => Outcome::Aborted {
                reason: abort_reason.unwrap_or_else(|| "aborted".into()),
            },
            EndReason::Faulted(fault) => Outcome::Faulted {
                fault,
                message: self.fault_message(fault, dt),
            },
        }
    }

    pub fn fault_message(&self, kind: FaultKind, dt: f64) -> String {
        let at = self.runner.progress().0 as f64 * dt;
        match kind {
            FaultKind::StaleInput => format!(
                "no operator input for more than {:.0} ms at t = {at:.3} s; valve set to zero",
                self.stale_ticks as f64 * dt * 1e3
            ),
            FaultKind::RigImplausible => match self.rig_fault {
                Some(why) => format!("the rig reported {why} at t = {at:.3} s; valve set to zero"),
                None => format!(
                    "the rig reported an implausible reading at t = {at:.3} s; valve set to zero"
                ),
            },
            FaultKind::RigTimeout => {
                format!("the rig stopped answering at t = {at:.3} s; valve set to zero")
            }
            FaultKind::EStop => "e-stop pressed".into(),
            FaultKind::LinkLost => "server link lost".into(),
            FaultKind::CabVibration => {
                let (rms, limit) = self
                    .runner
                    .interlock()
                    .map_or((0.0, 0.0), |il| (il.rms(), il.limit()));
                format!(
                    "cab vibration {rms:.0} mm/s² RMS over {WINDOW_S} s exceeded the limit of {limit:.0} at t = {at:.3} s; valve set to zero"
                )
            }
            FaultKind::ExposureBudget => {
                let (e, allowance) = self.runner.exposure();
                let left = allowance.map_or(0.0, |a| a.energy_m2_s3);
                let left_vdv = allowance.map_or(0.0, |a| a.vdv4_m4_s7.powf(0.25));
                format!(
                    "the subject's daily vibration budget is used up at t = {at:.3} s (this test: a_w {:.3} m/s² over {:.1} s = {:.2} m²/s³ of {left:.2} left, VDV {:.2} of {left_vdv:.2} m/s^1.75 left); valve set to zero",
                    e.aw_m_s2,
                    e.duration_s,
                    e.energy(),
                    e.vdv_m_s175
                )
            }
            FaultKind::Internal => {
                "the controller could not run this trial (no free slot or shutting down)".into()
            }
        }
    }

    /// The record channel by channel (`RECORD_CHANNELS` order), rows `from..to`.
    pub fn record_channels(&self, from: usize, to: usize) -> Vec<Vec<f32>> {
        let rows = &self.record[from..to];
        (0..RECORD_CHANNELS.len())
            .map(|c| rows.iter().map(|r| r[c]).collect())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recording_a_whole_trial_takes_no_page_fault() {
        // A 1,000 s trial: 36 MB, more than glibc ever serves from its heap, so the buffer is
        // always fresh pages from the kernel (8,800 of them).
        let rows = 1_000_000;
        let mut record = prefaulted(rows);
        let before = crate::runtime::os::minor_faults();
        for k in 0..rows {
            record.push([k as f32; RECORD_CHANNELS.len()]);
        }
        let faults = crate::runtime::os::minor_faults() - before;
        assert!(faults < 10, "{faults} page faults while recording");
        assert_eq!(record.capacity(), rows, "never grown");
    }
}
