//! Adaptive compensation (issue 41): designs that follow the structure's first mode when it
//! moves in the field (load, tires or outriggers, arm configuration, wear: up to ±30 %), where
//! a fixed notch or shaper loses part of its reduction and margin (how much, and where the
//! adaptive ones do better or worse: docs/machine-conditions.md).
//!
//! Files: `estimator`: the online estimate of the mode (frequency, damping, confidence) from
//! the seat accelerometer, with the cylinder position as the structure's known input —
//! engine notch, anti-alias, decimation to 100 Hz, high-pass, a bank of the structure's
//! model over the ratio range and their residuals with forgetting, gated on excitation (its
//! doc says why each). `schedule`: the grid
//! of ratios r = estimate / design frequency the designs are prepared for, over the retune
//! range [1 − range, 1 + range_up] (`AdaptParams::retune_bounds`: the notch and the shaper
//! are not retuned upward by default, the LQR is — docs/machine-conditions.md says why), the
//! decision once a retune period (a confident estimate → the nearest design; none → the
//! fixed design, r = 1, counted as a fallback), and the crossfade. `designs`: the prepared
//! designs — notch filters and shaper tap sets on a 1 % grid, the scheduled LQRs on a 0.1
//! grid (seven by default) — each built by
//! `Compensator::build` from `CompensatorSpec::frozen_at(r)`, so a design at r is exactly the
//! fixed design frozen there, and the step that runs the active one (and, while blending,
//! the one it replaces).
//!
//! *Invariant:* `step` never allocates, locks, blocks or logs: every design is prepared at
//! build, the shaper's delay line is sized for the lowest ratio in range, a switch copies
//! state between prepared designs. *Invariant:* a switch never jumps the command: the old and
//! the new design run side by side on the same inputs and their outputs are crossfaded over
//! the blend time (the reference for the PID family, the valve command for the LQR, whose
//! new design starts from the old one's state: the same 7-state meaning).

mod designs;
pub mod estimator;
pub mod schedule;
#[cfg(test)]
mod tests;

pub use estimator::{ModeEstimate, ModeEstimator};

use bdft_protocol::params::{AdaptationStatus, CompensatorSpec, PlantParams};

use crate::error::DesignError;
use crate::model::Measurement;
use crate::state::LinearState;
use designs::Designs;
use schedule::Schedule;

/// An adaptive compensator: estimator, schedule and prepared designs.
#[derive(Debug, Clone)]
pub struct Adaptive {
    estimator: ModeEstimator,
    schedule: Schedule,
    designs: Designs,
    dt: f64,
    ticks: u64,
    confident_since_s: Option<f64>,
}

impl Adaptive {
    /// Prepares the designs of an adaptive `spec` for `plant` at loop period `dt`; None for
    /// a fixed spec.
    pub fn new(
        spec: &CompensatorSpec,
        plant: &PlantParams,
        dt: f64,
    ) -> Result<Option<Self>, DesignError> {
        let Some(adapt) = spec.adapt() else {
            return Ok(None);
        };
        let bounds = adapt.retune_bounds(spec.kind());
        let schedule = Schedule::new(adapt, bounds, designs::grid_half(spec.kind(), adapt), dt);
        Ok(Some(Self {
            estimator: ModeEstimator::new(plant, adapt, dt),
            designs: Designs::new(spec, plant, dt, schedule.ratios())?,
            schedule,
            dt,
            ticks: 0,
            confident_since_s: None,
        }))
    }

    /// One tick: the estimator sees the accelerometer, the schedule may start a switch, the
    /// active design (crossfaded with the old one while blending) gives the valve command.
    #[inline]
    pub fn step(&mut self, r_c: f64, m: Measurement) -> f64 {
        self.estimator.step(m.cab_accel, m.y);
        self.ticks += 1;
        let confident = self.estimator.confident();
        if confident && self.confident_since_s.is_none() {
            self.confident_since_s = Some(self.ticks as f64 * self.dt);
        }
        let ratio = self
            .estimator
            .estimate()
            .filter(|_| confident)
            .map(|e| e.ratio);
        if let Some(switch) = self.schedule.tick(ratio) {
            self.designs.hand_over(switch);
        }
        self.designs
            .step(self.schedule.active(), self.schedule.blend(), r_c, m)
    }

    /// Starts a retune to the design nearest ratio `r` now, as a confident decision would
    /// (experiments and tests: a retune at a known time). The next decision is taken as
    /// usual.
    pub fn retune_to(&mut self, r: f64) {
        if let Some(switch) = self.schedule.switch_to(self.schedule.nearest(r)) {
            self.designs.hand_over(switch);
        }
    }

    pub fn reset(&mut self) {
        self.estimator.reset();
        self.schedule.reset();
        self.designs.reset();
        self.ticks = 0;
        self.confident_since_s = None;
    }

    pub fn estimator(&self) -> &ModeEstimator {
        &self.estimator
    }

    /// The mode-frequency ratio of the design running now.
    pub fn ratio(&self) -> f64 {
        self.schedule.ratio()
    }

    pub fn status(&self) -> AdaptationStatus {
        let e = self.estimator.estimate();
        AdaptationStatus {
            f_hz: e.map(|e| e.f_hz),
            zeta: e.map(|e| e.zeta),
            confident: self.estimator.confident(),
            confident_since_s: self.confident_since_s,
            ratio: self.schedule.ratio(),
            retunes: self.schedule.retunes(),
            fallbacks: self.schedule.fallbacks(),
        }
    }

    /// True for the shaper family (its reference path holds pure delays).
    pub fn has_delays(&self) -> bool {
        self.designs
            .shaper_duration(self.schedule.active(), self.dt)
            .is_some()
    }

    /// The delay the active shaper adds (s), for the shaper family.
    pub fn shaper_duration(&self) -> Option<f64> {
        self.designs
            .shaper_duration(self.schedule.active(), self.dt)
    }
}

/// The active fixed design's state (what the analysis of a design frozen there reads).
impl LinearState for Adaptive {
    fn state_len(&self) -> usize {
        self.designs.state_len(self.schedule.active())
    }
    fn read_state(&self, out: &mut [f64]) {
        self.designs.read_state(self.schedule.active(), out);
    }
    fn write_state(&mut self, s: &[f64]) {
        self.designs.write_state(self.schedule.active(), s);
    }
}
