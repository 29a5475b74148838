//! Model-based cancellation of biodynamic feedthrough (issue 38): the device's reading less
//! what a fitted body predicts the cab's acceleration adds to it, u = device − Ĥ(z)·a_cab,
//! Ĥ fixed for a test (Gillespie & Sövényi's per-subject cancellation; Venrooij's warning
//! that a model not the person's can make things worse is why a guard stops it).
//!
//! Ĥ is the seated body's feedthrough as the identification measures it, device position
//! over cab acceleration. The body moves the hand by h = k_h(1 − T·A)·x_c (`model::body`);
//! with T = 1 − s²/D_t and A = 1 − s²/D_a (D = s² + 2ζωs + ω²), (1 − T·A)/s² =
//! N/(D_t·D_a), N = s² + 2(ζ_tω_t + ζ_aω_a)s + ω_t² + ω_a²: a proper, stable fourth-order
//! filter of the acceleration, so nothing is integrated twice and nothing drifts. The device
//! reads −h, so Ĥ = −k_h·N/(D_t·D_a), run as two Tustin biquads, 1/D_t then N/D_a, each
//! pre-warped at its resonance.
//!
//! A deliberately wrong model (the robustness arm) is the same body with a gain factor and a
//! phase lag at a stated frequency, the lag a first-order all-pass (a − s)/(a + s) with
//! a = ω_ref / tan(φ/2): exactly φ at f_ref, less below, more above, unit gain everywhere.
//!
//! The guard turns cancellation off for the rest of the test when its output passes
//! `limit_mm`: a model far from the person, or a cab shaken far past what it was fitted at.
//! It does not tell a model that is merely wrong (a phase error) from a right one: the cab's
//! motion follows the person's own commands, so the cancelled input correlates with the
//! prediction whatever the model (measured: a correlation test tripped on the exact model;
//! `docs/cancellation.md`). The tick is allocation- and lock-free.

use std::f64::consts::PI;

pub use bdft_protocol::cancellation::CancellationModel;
use bdft_protocol::params::ParamError;

use crate::filters::{Biquad, FirstOrder};
use crate::state::LinearState;

/// Ĥ(z) at the loop's rate with its guard; one per test.
#[derive(Debug, Clone)]
pub struct Canceller {
    torso: Biquad,
    arm: Biquad,
    lag: Option<FirstOrder>,
    gain: f64,
    limit_mm: f64,
    /// Set by the guard: cancellation is off for the rest of the test.
    tripped: bool,
}

/// One tick's cancellation: what was subtracted from the device (mm), and whether the
/// guard tripped this tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Cancelled {
    pub output_mm: f64,
    pub tripped_now: bool,
}

impl Canceller {
    pub fn new(model: &CancellationModel, dt: f64) -> Result<Self, ParamError> {
        model.validate()?;
        let (wt, wa) = (2.0 * PI * model.torso_f_hz, 2.0 * PI * model.arm_f_hz);
        let (zt, za) = (model.torso_zeta, model.arm_zeta);
        let torso = Biquad::tustin([0.0, 0.0, 1.0], [1.0, 2.0 * zt * wt, wt * wt], dt, Some(wt));
        let arm = Biquad::tustin(
            [1.0, 2.0 * (zt * wt + za * wa), wt * wt + wa * wa],
            [1.0, 2.0 * za * wa, wa * wa],
            dt,
            Some(wa),
        );
        let lag = (model.phase_lag_deg > 0.0).then(|| {
            let w_ref = 2.0 * PI * model.phase_ref_hz;
            let a = w_ref / (model.phase_lag_deg.to_radians() / 2.0).tan();
            FirstOrder::tustin([-1.0, a], [1.0, a], dt, Some(w_ref))
        });
        Ok(Self {
            torso,
            arm,
            lag,
            gain: -model.k_h * model.gain,
            limit_mm: model.limit_mm,
            tripped: false,
        })
    }

    /// The device feedthrough predicted from this tick's cab acceleration (mm/s²), to be
    /// subtracted from the device's reading; 0 once the guard has tripped.
    #[inline]
    pub fn step(&mut self, cab_accel_mm_s2: f64) -> Cancelled {
        if self.tripped {
            return Cancelled::default();
        }
        let mut y = self.arm.step(self.torso.step(cab_accel_mm_s2));
        if let Some(lag) = &mut self.lag {
            y = lag.step(y);
        }
        let out = self.gain * y;
        // A NaN (a broken accelerometer) trips too.
        if out.is_nan() || out.abs() > self.limit_mm {
            self.tripped = true;
            return Cancelled {
                output_mm: 0.0,
                tripped_now: true,
            };
        }
        Cancelled {
            output_mm: out,
            tripped_now: false,
        }
    }

    /// Whether the guard has turned cancellation off.
    pub fn tripped(&self) -> bool {
        self.tripped
    }

    /// Back to rest, the guard re-armed: the start of another test.
    pub fn reset(&mut self) {
        self.torso.reset();
        self.arm.reset();
        if let Some(lag) = &mut self.lag {
            lag.reset();
        }
        self.tripped = false;
    }

    /// Ĥ at `f_hz` for the sample period `dt` (mm of device per mm/s² of cab acceleration).
    pub fn response(&self, f_hz: f64, dt: f64) -> nalgebra::Complex<f64> {
        let w = 2.0 * PI * f_hz;
        let lag = self
            .lag
            .map_or(nalgebra::Complex::from(1.0), |l| l.response(w, dt));
        self.torso.response(w, dt) * self.arm.response(w, dt) * lag * self.gain
    }
}

/// The filters' states, for the analysis that reads the loop's map off its tick (the guard
/// is not a state: the analysis reads off a canceller that has not tripped).
impl LinearState for Canceller {
    fn state_len(&self) -> usize {
        4 + usize::from(self.lag.is_some())
    }
    fn read_state(&self, out: &mut [f64]) {
        self.torso.read_state(&mut out[..2]);
        self.arm.read_state(&mut out[2..4]);
        if let Some(lag) = &self.lag {
            lag.read_state(&mut out[4..5]);
        }
    }
    fn write_state(&mut self, s: &[f64]) {
        self.torso.write_state(&s[..2]);
        self.arm.write_state(&s[2..4]);
        if let Some(lag) = &mut self.lag {
            lag.write_state(&s[4..5]);
        }
    }
}

pub mod check;
pub mod offline;
#[cfg(test)]
mod tests;
