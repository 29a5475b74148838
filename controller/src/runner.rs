//! One trial, tick by tick: target → operator (synthetic, external or none) → closed loop →
//! metrics. The offline simulation and the real-time process both run trials through this,
//! so a trial in the controller process reproduces `simulate` exactly for the same seeds.

use bdft_protocol::trial::{Metrics, RECORD_CHANNELS};

use bdft_protocol::exposure::{ExposureAllowance, TrialExposure};

use crate::closed_loop::{ClosedLoop, Drive, TickRecord};
use crate::exposure::ExposureMeter;
use crate::interlock::{VibrationInterlock, WINDOW_S};
use crate::operator::SyntheticOperator;
use crate::signals::Signal;

/// A loop that can be ticked: the simulated rig (`ClosedLoop`) or a real rig's.
pub trait Loop {
    fn tick(&mut self, drive: Drive) -> TickRecord;
    /// Cylinder position shown on the pursuit display now (last measurement).
    fn displayed_y(&self) -> f64;
    /// Cab acceleration the operator's seat carries now (mm/s²): 0 at the desk, or where the
    /// loop does not simulate the cab (a real rig).
    fn felt_accel(&self) -> f64 {
        0.0
    }
    /// The operator's grip: a simulated seated body's arm-frequency factor
    /// (`Body::set_grip`); a loop without a simulated body has none to change.
    fn set_grip(&mut self, _grip: f64) {}
}

impl Loop for ClosedLoop {
    #[inline]
    fn tick(&mut self, drive: Drive) -> TickRecord {
        ClosedLoop::tick(self, drive)
    }
    fn displayed_y(&self) -> f64 {
        self.last_measurement().y
    }
    fn felt_accel(&self) -> f64 {
        ClosedLoop::felt_accel(self)
    }
    fn set_grip(&mut self, grip: f64) {
        ClosedLoop::set_grip(self, grip)
    }
}

/// Where the intended hand position comes from.
#[derive(Debug, Clone)]
// A trial holds one for its whole life inside a slot the loop keeps on the heap already;
// boxing the operator would add a pointer chase to every tick of a synthetic trial.
#[allow(clippy::large_enum_variant)]
pub enum HandSource {
    Synthetic(SyntheticOperator),
    /// Supplied each tick by the caller (a browser, a haptic device).
    External,
    /// No operator: the target is the cylinder reference.
    Reference,
}

/// One sample of a trial's full-rate record.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    pub t: f64,
    pub target: f64,
    pub hand: f64,
    pub feedthrough: f64,
    pub r_c: f64,
    pub valve: f64,
    pub y: f64,
    pub cab_accel: f64,
    /// What cancellation subtracted from the device's reading (mm; 0 without it): the
    /// cancelled signal is `device() − cancellation`.
    pub cancellation: f64,
}

impl Sample {
    /// This tick's row of the full-rate record, in `RECORD_CHANNELS` order (the controller's
    /// stored record and `simulate --out` both write it), with the tick's wake-up latency.
    pub fn record_row(&self, tick_latency_us: f64) -> [f64; RECORD_CHANNELS.len()] {
        [
            self.target,
            self.hand,
            self.feedthrough,
            self.r_c,
            self.valve,
            self.y,
            self.cab_accel,
            self.device(),
            tick_latency_us,
            self.cancellation,
        ]
    }

    /// What the input device reads: the intended hand position less the feedthrough.
    pub fn device(&self) -> f64 {
        self.hand - self.feedthrough
    }
}

/// Streaming accumulator of the trial metrics over the full-rate record.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MetricsAccumulator {
    ticks: u64,
    sum_sq_error: f64,
    sum_sq_accel: f64,
}

impl MetricsAccumulator {
    #[inline]
    pub fn add(&mut self, target: f64, y: f64, cab_accel: f64) {
        self.ticks += 1;
        self.sum_sq_error += (target - y) * (target - y);
        self.sum_sq_accel += cab_accel * cab_accel;
    }

    pub fn metrics(&self) -> Metrics {
        let n = self.ticks.max(1) as f64;
        Metrics {
            ticks: self.ticks,
            mse_tracking_mm2: self.sum_sq_error / n,
            ms_cab_accel: self.sum_sq_accel / n,
        }
    }
}

#[derive(Debug, Clone)]
pub struct TrialRunner<L> {
    pub(crate) signal: Signal,
    /// The signal is the identification test's excitation (`Signal::excites`), read once.
    excited: bool,
    pub(crate) lp: L,
    pub(crate) hand: HandSource,
    metrics: MetricsAccumulator,
    pub(crate) dt: f64,
    k: u64,
    pub(crate) total: u64,
    pub(crate) interlock: Option<VibrationInterlock>,
    tripped: bool,
    exposure: ExposureMeter,
    /// The tick cancellation's guard turned it off, if it did.
    cancellation_off: Option<u64>,
}

impl<L: Loop> TrialRunner<L> {
    pub fn new(signal: Signal, lp: L, hand: HandSource, dt: f64, duration_s: f64) -> Self {
        Self {
            excited: signal.excites(),
            signal,
            lp,
            hand,
            metrics: MetricsAccumulator::default(),
            dt,
            k: 0,
            total: (duration_s / dt).round() as u64,
            interlock: None,
            tripped: false,
            exposure: ExposureMeter::new(dt, None),
            cancellation_off: None,
        }
    }

    /// Guards the subject's daily vibration budget: the caller stops the trial once
    /// `exposure_used_up` (the W_d-weighted cab acceleration used up `allowance`).
    pub fn with_exposure_allowance(mut self, allowance: Option<ExposureAllowance>) -> Self {
        self.exposure = ExposureMeter::new(self.dt, allowance);
        self
    }

    /// Whether the exposure guard's allowance is used up.
    pub fn exposure_used_up(&self) -> bool {
        self.exposure.used_up()
    }

    /// The ISO 2631-1 figures of the cab acceleration so far, and the guard's allowance.
    pub fn exposure(&self) -> (TrialExposure, Option<ExposureAllowance>) {
        (self.exposure.exposure(), self.exposure.allowance())
    }

    /// Watches the cab acceleration with the vibration interlock (limit in mm/s² RMS over
    /// `interlock::WINDOW_S`); the caller stops the trial once `tripped`.
    pub fn with_interlock(mut self, limit_mm_s2: f64) -> Self {
        let window = (WINDOW_S / self.dt).round() as usize;
        self.interlock = Some(VibrationInterlock::new(limit_mm_s2, window));
        self
    }

    /// Whether the vibration interlock has tripped.
    pub fn tripped(&self) -> bool {
        self.tripped
    }

    pub fn interlock(&self) -> Option<&VibrationInterlock> {
        self.interlock.as_ref()
    }

    /// One tick; `external_hand` is used when the hand source is external.
    #[inline]
    pub fn tick(&mut self, external_hand: f64) -> Sample {
        let t = self.k as f64 * self.dt;
        let target = self.signal.at(t);
        let drive = match &mut self.hand {
            // The identification test: the target is the cylinder reference, the hand is
            // only recorded.
            HandSource::Synthetic(op) if self.excited => {
                let hand = op.hold(self.lp.felt_accel());
                self.lp.set_grip(op.grip());
                Drive::Excited { hand, r_c: target }
            }
            HandSource::External if self.excited => Drive::Excited {
                hand: external_hand,
                r_c: target,
            },
            HandSource::Synthetic(op) => {
                let hand = op.step(target, self.lp.displayed_y(), self.lp.felt_accel());
                self.lp.set_grip(op.grip());
                Drive::Hand(hand)
            }
            HandSource::External => Drive::Hand(external_hand),
            HandSource::Reference => Drive::Reference(target),
        };
        let r = self.lp.tick(drive);
        self.metrics.add(target, r.y, r.cab_accel);
        if let Some(il) = &mut self.interlock {
            self.tripped |= il.update(r.cab_accel);
        }
        self.exposure.add(r.cab_accel);
        if r.cancellation_tripped {
            self.cancellation_off = Some(self.k);
        }
        self.k += 1;
        Sample {
            t,
            target,
            hand: r.hand,
            feedthrough: r.feedthrough,
            r_c: r.r_c,
            valve: r.valve,
            y: r.y,
            cab_accel: r.cab_accel,
            cancellation: r.cancellation,
        }
    }

    pub fn done(&self) -> bool {
        self.k >= self.total
    }

    /// Ticks run so far and ticks in the whole trial.
    pub fn progress(&self) -> (u64, u64) {
        (self.k, self.total)
    }

    pub fn metrics(&self) -> Metrics {
        self.metrics.metrics()
    }

    /// When (s into the trial) cancellation's guard turned it off, if it did.
    pub fn cancellation_off_at_s(&self) -> Option<f64> {
        self.cancellation_off.map(|k| k as f64 * self.dt)
    }

    pub fn loop_mut(&mut self) -> &mut L {
        &mut self.lp
    }

    pub fn loop_ref(&self) -> &L {
        &self.lp
    }
}
