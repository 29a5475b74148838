//! The online estimate of the structure's modes from the seat accelerometer alone.
//!
//! Chain, per 1 kHz tick: a 4th-order Butterworth low-pass (the anti-alias filter, corner
//! 1.5× the highest second-mode frequency in range) so the engine tone (30 Hz, 480 mm/s²
//! RMS in the simulated rig) and the white noise above the band neither alias nor dominate;
//! every `DECIMATION`-th sample kept (100 Hz: the modes sit at 0.18–0.5 rad a sample there,
//! where an AR model is well conditioned, against 0.02–0.05 rad at 1 kHz); a 2nd-order
//! Butterworth high-pass at half the lowest first-mode frequency in range, which removes the
//! cab acceleration that follows the boom's own slow motion (K_S·ÿ) and the offset.
//!
//! Model: an AR(4) x[k] = θ₁x[k−1] + … + θ₄x[k−4] + e[k] fitted by recursive least squares
//! with exponential forgetting (λ = e^{−T/memory}). Four parameters, two pole pairs: the
//! cab response holds both structure modes (4.0 and 6.2 Hz nominally), and an AR(2) fitted to
//! it would settle on an energy-weighted frequency between them that moves with what the
//! compensator lets through; AR(4) separates them and the first is reported. Frequencies and
//! damping come from the poles z of z⁴ − θ₁z³ − … − θ₄ (s = ln z / T), solved at 10 Hz.
//!
//! The RLS only updates while the band's energy (mean square over about half a second)
//! exceeds `EXCITATION_RATIO` times what the accelerometer's noise and engine tone put into
//! it (known from the rig's sensor parameters): without excitation the covariance would grow
//! as λ⁻ⁿ (wind-up) and the fit would describe the filters' own poles shaping the noise. So
//! noise alone never produces an estimate, and a well-damped cab (the compensator doing
//! its job) holds the last one.
//!
//! Confidence: the standard deviation of the first mode's frequency from the parameter
//! covariance σₑ²·P (σₑ² the mean-square prediction error, same forgetting) mapped through
//! the root's sensitivity ∂z/∂θᵢ = z^{4−i}/p′(z), relative to the frequency; confident when at
//! most `max_rel_std`, the pole pair lightly damped (ζ < `MAX_MODE_ZETA`: a structure mode,
//! not a filter's shaping) and at least a tenth of a memory of updates made.

use nalgebra::{Complex, Matrix4, Vector4};

use crate::filters::Biquad;
use bdft_protocol::params::{AdaptParams, PlantParams};

/// 1 kHz ticks per estimator sample.
pub const DECIMATION: usize = 10;
/// Decimated samples between two root solutions (10 Hz).
const ROOTS_EVERY: u32 = 10;
/// The band must hold this many times the sensor's noise energy for an update.
pub const EXCITATION_RATIO: f64 = 4.0;
/// A pole pair damped more than this is not taken for a structure mode.
pub const MAX_MODE_ZETA: f64 = 0.3;
/// Time constant of the band's energy measure (s).
const ENERGY_TAU_S: f64 = 0.5;
/// Initial parameter covariance: the prior (the design's modes) is weak.
const P0: f64 = 10.0;

/// One mode as estimated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModeEstimate {
    /// Natural frequency (Hz).
    pub f_hz: f64,
    pub zeta: f64,
    /// Standard deviation of `f_hz` relative to it.
    pub rel_std: f64,
}

/// The estimator of the first structure mode (see the module doc).
#[derive(Debug, Clone)]
pub struct ModeEstimator {
    anti_alias: [Biquad; 2],
    high_pass: Biquad,
    phase: usize,
    /// Sample period after decimation (s).
    ts: f64,
    lambda: f64,
    /// Last four filtered samples, newest first.
    past: Vector4<f64>,
    theta: Vector4<f64>,
    p: Matrix4<f64>,
    prior: Vector4<f64>,
    /// Mean-square a-priori prediction error and band energy.
    err_ms: f64,
    energy: f64,
    energy_alpha: f64,
    /// The energy the sensor's noise and engine tone put into the band.
    noise_floor: f64,
    samples: u64,
    updates: u64,
    min_updates: u64,
    max_rel_std: f64,
    until_roots: u32,
    mode: Option<ModeEstimate>,
}

/// AR(4) coefficients [θ₁..θ₄] of two pole pairs (Hz, ζ) sampled at `ts`.
fn ar_of(modes: [(f64, f64); 2], ts: f64) -> Vector4<f64> {
    // (z² + a₁z + a₂)(z² + b₁z + b₂) = z⁴ − θ₁z³ − θ₂z² − θ₃z − θ₄.
    let pair = |(f, z): (f64, f64)| {
        let w = std::f64::consts::TAU * f;
        let r = (-z * w * ts).exp();
        (-2.0 * r * (w * ts * (1.0 - z * z).sqrt()).cos(), r * r)
    };
    let (a1, a2) = pair(modes[0]);
    let (b1, b2) = pair(modes[1]);
    -Vector4::new(a1 + b1, a2 + b2 + a1 * b1, a1 * b2 + a2 * b1, a2 * b2)
}

/// 2nd-order Butterworth sections: low-pass (quality factors of a 4th-order one) and high-pass.
fn low_pass(f_hz: f64, q: f64, dt: f64) -> Biquad {
    let w = std::f64::consts::TAU * f_hz;
    Biquad::tustin([0.0, 0.0, w * w], [1.0, w / q, w * w], dt, Some(w))
}

fn high_pass(f_hz: f64, dt: f64) -> Biquad {
    let w = std::f64::consts::TAU * f_hz;
    Biquad::tustin(
        [1.0, 0.0, 0.0],
        [1.0, std::f64::consts::SQRT_2 * w, w * w],
        dt,
        Some(w),
    )
}

impl ModeEstimator {
    /// The estimator for modes near those of `design` (the plant the compensator is designed
    /// for, whose accelerometer noise and engine tone set the excitation gate), within the
    /// ratio range of `adapt`, at loop period `dt`.
    pub fn new(design: &PlantParams, adapt: &AdaptParams, dt: f64) -> Self {
        let (lo, hi) = adapt.ratio_bounds();
        let ts = dt * DECIMATION as f64;
        let corner = (1.5 * design.f2_hz.max(design.f1_hz) * hi).min(0.25 / ts);
        // Butterworth 4th order: Q = 1/(2 cos(π/8)), 1/(2 cos(3π/8)).
        let anti_alias = [0.541_196_1, 1.306_563].map(|q| low_pass(corner, q, dt));
        let high_pass = high_pass(0.5 * design.f1_hz * lo, ts);
        // 1 (mm/s²)² at least: a noiseless simulated rig must not update on rounding.
        let noise_floor = Self::floor(design, &anti_alias, dt).max(1.0);
        let prior = ar_of([(design.f1_hz, design.z1), (design.f2_hz, design.z2)], ts);
        let samples_per_memory = adapt.memory_s / ts;
        Self {
            anti_alias,
            high_pass,
            phase: 0,
            ts,
            lambda: (-1.0 / samples_per_memory).exp(),
            past: Vector4::zeros(),
            theta: prior,
            p: Matrix4::identity() * P0,
            prior,
            err_ms: 0.0,
            energy: 0.0,
            energy_alpha: 1.0 - (-ts / ENERGY_TAU_S).exp(),
            noise_floor,
            samples: 0,
            updates: 0,
            min_updates: (0.1 * samples_per_memory).ceil() as u64,
            max_rel_std: adapt.max_rel_std,
            until_roots: ROOTS_EVERY,
            mode: None,
        }
    }

    /// The energy white noise of the rig's σ and its engine tone leave after the
    /// anti-alias filter (the high-pass removes little of it, so this errs high).
    fn floor(design: &PlantParams, anti_alias: &[Biquad; 2], dt: f64) -> f64 {
        let mut f = *anti_alias;
        let mut sum_sq = 0.0;
        for k in 0..20_000 {
            let x = f64::from(u8::from(k == 0));
            let u = f[0].step(x);
            let y = f[1].step(u);
            sum_sq += y * y;
        }
        let w = std::f64::consts::TAU * design.engine_hz;
        let tone = anti_alias[0].response(w, dt).norm() * anti_alias[1].response(w, dt).norm();
        design.accel_noise_std.powi(2) * sum_sq + (design.engine_vibration_rms * tone).powi(2)
    }

    /// One loop tick's accelerometer reading (mm/s²); a non-finite one is read as 0.
    #[inline]
    pub fn step(&mut self, cab_accel: f64) {
        let a = if cab_accel.is_finite() {
            cab_accel
        } else {
            0.0
        };
        let u = self.anti_alias[0].step(a);
        let x = self.anti_alias[1].step(u);
        self.phase += 1;
        if self.phase < DECIMATION {
            return;
        }
        self.phase = 0;
        let x = self.high_pass.step(x);
        self.sample(x);
    }

    /// One decimated, band-limited sample.
    fn sample(&mut self, x: f64) {
        self.samples += 1;
        self.energy += self.energy_alpha * (x * x - self.energy);
        let excited = self.energy > EXCITATION_RATIO * self.noise_floor;
        if excited && self.samples > 4 {
            // RLS with forgetting: gain k = Pφ/(λ + φᵀPφ), θ += k·e, P = (P − kφᵀP)/λ.
            let phi = self.past;
            let e = x - self.theta.dot(&phi);
            let p_phi = self.p * phi;
            let k = p_phi / (self.lambda + phi.dot(&p_phi));
            self.theta += k * e;
            self.p = (self.p - k * p_phi.transpose()) / self.lambda;
            // Symmetric by construction; rounding is not, and RLS diverges if it drifts.
            self.p = (self.p + self.p.transpose()) * 0.5;
            self.err_ms = self.lambda * self.err_ms + (1.0 - self.lambda) * e * e;
            self.updates += 1;
            if !self.theta.iter().all(|t| t.is_finite()) {
                self.restart();
            }
        }
        self.past = Vector4::new(x, self.past[0], self.past[1], self.past[2]);
        self.until_roots -= 1;
        if self.until_roots == 0 {
            self.until_roots = ROOTS_EVERY;
            if self.updates > 0 {
                self.mode = self.first_mode();
            }
        }
    }

    /// The lowest lightly damped pole pair of the fitted model, with its relative spread.
    fn first_mode(&self) -> Option<ModeEstimate> {
        let t = self.theta;
        let companion = Matrix4::new(
            t[0], t[1], t[2], t[3], 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
        );
        let roots = companion.try_schur(1e-12, 200)?.complex_eigenvalues();
        let (z, s) = roots
            .iter()
            .filter(|z| z.im > 1e-9 && z.norm() > 1e-9)
            .map(|&z| (z, z.ln() / self.ts))
            .filter(|(_, s)| -s.re / s.norm() < MAX_MODE_ZETA)
            .min_by(|a, b| a.1.norm().total_cmp(&b.1.norm()))?;
        let wn = s.norm();
        // ∂z/∂θᵢ = z^{4−i}/p′(z), p′(z) = 4z³ − 3θ₁z² − 2θ₂z − θ₃; ∂ωₙ = Re(s̄/|s|·∂z/(z·T)).
        let dp = z * z * z * 4.0 - z * z * (3.0 * t[0]) - z * (2.0 * t[1]) - Complex::from(t[2]);
        let lead = s.conj() / (wn * dp * z * self.ts);
        let g = Vector4::new(
            (lead * z * z * z).re,
            (lead * z * z).re,
            (lead * z).re,
            lead.re,
        );
        let var_w = self.err_ms * g.dot(&(self.p * g));
        Some(ModeEstimate {
            f_hz: wn / std::f64::consts::TAU,
            zeta: -s.re / wn,
            rel_std: var_w.max(0.0).sqrt() / wn,
        })
    }

    /// Back to the prior, as after `reset`, keeping the filters' state.
    fn restart(&mut self) {
        self.theta = self.prior;
        self.p = Matrix4::identity() * P0;
        self.err_ms = 0.0;
        self.updates = 0;
        self.mode = None;
    }

    /// Back to the state at construction.
    pub fn reset(&mut self) {
        self.restart();
        for f in &mut self.anti_alias {
            f.reset();
        }
        self.high_pass.reset();
        self.phase = 0;
        self.past = Vector4::zeros();
        self.energy = 0.0;
        self.samples = 0;
        self.until_roots = ROOTS_EVERY;
    }

    /// The latest estimate of the first mode, confident or not.
    pub fn estimate(&self) -> Option<ModeEstimate> {
        self.mode
    }

    /// The estimate is trusted: see the module doc.
    pub fn confident(&self) -> bool {
        self.updates >= self.min_updates && self.mode.is_some_and(|m| m.rel_std <= self.max_rel_std)
    }

    /// RLS updates made (decimated samples with enough excitation).
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// The band's energy relative to the sensor's noise floor in it (the gate opens at
    /// `EXCITATION_RATIO`).
    pub fn excitation(&self) -> f64 {
        self.energy / self.noise_floor
    }
}
