//! The online estimate of the structure's first mode from the seat accelerometer, with the
//! cylinder position as the structure's known input.
//!
//! Signal chain, the same for both signals so the relation between them is kept: a notch at
//! the engine's frequency (a tone of 480 mm/s² RMS at 30 Hz in the simulated rig; its
//! frequency is a rig parameter), a 4th-order Butterworth low-pass at 1.25× the highest
//! second-mode frequency in range (the anti-alias filter), every `DECIMATION`-th sample kept
//! (100 Hz: the modes are 0.18–0.5 rad a sample there, against 0.02–0.05 rad at 1 kHz), and a
//! 2nd-order Butterworth high-pass at half the lowest first-mode frequency in range (the cab
//! acceleration that follows the boom's own slow motion, K_S·ÿ, and the offset).
//!
//! Model: a bank of the structure's transmissibility a/y = s²·K_S·N(s)/D(s) with both mode
//! frequencies scaled by r, on a grid of r over the range (`BANK_STEP`), each driven by the
//! filtered cylinder position; for each, the mean square of the filtered acceleration left
//! unexplained after the best gain (so K_S, the chain's gain and the accelerometer's scale
//! need not be known), with exponential forgetting (memory `memory_s`). The estimate is the
//! vertex of the parabola through the smallest residual and its neighbours. Why this and not
//! an autoregression of the accelerometer alone: the cab's acceleration is the structure's
//! response to the cylinder's motion, and that motion carries the position loop's own poles
//! (3–4 Hz, ζ 0.1–0.15 for the bench PID) right in the band; an output-only AR(4) read 3.9 Hz
//! for a 5.2 Hz mode on the bench steps, and the swept sine's forcing for any mode. With
//! the position as a regressor (an ARX fitted by recursive least squares) the accelerometer's
//! noise sits in the regressors and biases the poles (−15 % at r = 1.3, measured); the output
//! error of a model driven by the clean position is unbiased for that noise. The cost is
//! that the mode's shape is the design's: both modes move together by r (the field
//! variation the schedule follows), and the damping reported is the design's: the bank does
//! not estimate damping.
//!
//! Updates (the residual sums) are made only while the filtered acceleration's energy (mean
//! square over half a second) exceeds `EXCITATION_RATIO` times what the accelerometer's white
//! noise and engine tone put into the band (known from the rig's sensor parameters). Without
//! excitation the forgetting would empty the sums, and the estimate would rest on noise.
//!
//! Confidence: near its minimum the residual is J(r) ≈ J* + ½J″(r − r*)², and for least
//! squares var(r*) = σ²/(½J″) with σ² = J*/n, n the independent samples in the memory (the
//! forgetting's 1/(1 − λ), at most the updates made, times 2·corner·T for the band-limited
//! noise's correlation). Confident when √var/r* ≤ `max_rel_std` and at least a tenth of a
//! memory of updates was made. Noise alone does not open the gate (the floor errs high; no
//! update in 30 s of it, tested); an unexcited cab keeps the last estimate.

use crate::filters::Biquad;
use bdft_protocol::params::{AdaptParams, PlantParams};

/// 1 kHz ticks per estimator sample.
pub const DECIMATION: usize = 10;
/// The bank's spacing in r: the modes' half-power bandwidths are 2ζ = 8–12 %, so the
/// residual is smooth over 5 % steps and its parabola locates the minimum between them.
pub const BANK_STEP: f64 = 0.05;
/// The band must hold this many times the sensor's noise energy for an update.
pub const EXCITATION_RATIO: f64 = 2.0;
/// Time constant of the band's energy measure (s).
const ENERGY_TAU_S: f64 = 0.5;
/// Most models in the bank (a range of ±0.5 at `BANK_STEP`, and one beyond each end).
const MAX_MODELS: usize = 23;

/// The first mode as estimated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModeEstimate {
    /// Natural frequency (Hz).
    pub f_hz: f64,
    /// Damping ratio (the design's: see the module doc).
    pub zeta: f64,
    /// Mode-frequency ratio r (estimate / design).
    pub ratio: f64,
    /// Standard deviation of the frequency relative to it.
    pub rel_std: f64,
}

/// One signal's filters (see the module doc).
#[derive(Debug, Clone)]
struct Chain {
    engine_notch: Biquad,
    anti_alias: [Biquad; 2],
    high_pass: Biquad,
}

impl Chain {
    /// At the loop rate; only every `DECIMATION`-th value goes on to the high-pass.
    #[inline]
    fn fast(&mut self, x: f64) -> f64 {
        let x = self.engine_notch.step(x);
        let x = self.anti_alias[0].step(x);
        self.anti_alias[1].step(x)
    }

    fn reset(&mut self) {
        self.engine_notch.reset();
        self.anti_alias.iter_mut().for_each(Biquad::reset);
        self.high_pass.reset();
    }
}

/// The structure at one r and its residual sums.
#[derive(Debug, Clone)]
struct Model {
    modes: [Biquad; 2],
    /// Σ a·â, Σ â² (forgetting sums; Σ a² is shared).
    cross: f64,
    power: f64,
}

/// The estimator of the first structure mode (see the module doc).
#[derive(Debug, Clone)]
pub struct ModeEstimator {
    chains: [Chain; 2],
    models: Vec<Model>,
    ratios: Vec<f64>,
    /// The range the estimate is clamped to.
    bounds: (f64, f64),
    /// Σ a² with forgetting.
    signal: f64,
    phase: usize,
    lambda: f64,
    energy: f64,
    energy_alpha: f64,
    /// The energy the sensor's noise and engine tone put into the band.
    noise_floor: f64,
    /// Independent noise samples per sample (the band-limited noise's correlation).
    independence: f64,
    updates: u64,
    min_updates: u64,
    max_rel_std: f64,
    design_f1_hz: f64,
    design_zeta: f64,
    mode: Option<ModeEstimate>,
}

fn butterworth_low_pass(f_hz: f64, q: f64, dt: f64) -> Biquad {
    let w = std::f64::consts::TAU * f_hz;
    Biquad::tustin([0.0, 0.0, w * w], [1.0, w / q, w * w], dt, Some(w))
}

/// One mode's factor of the transmissibility from cylinder position to cab acceleration,
/// s·(2ζωs + ω²)/(s² + 2ζωs + ω²): the product of both is s²·N(s)/D(s).
fn mode_factor(f_hz: f64, zeta: f64, ts: f64) -> Biquad {
    let w = std::f64::consts::TAU * f_hz;
    let c = 2.0 * zeta * w;
    Biquad::tustin([c, w * w, 0.0], [1.0, c, w * w], ts, Some(w))
}

impl ModeEstimator {
    /// The estimator for modes near those of `design` (the plant the compensator is designed
    /// for, whose accelerometer noise and engine tone set the excitation gate), within the
    /// ratio range of `adapt`, at loop period `dt`.
    pub fn new(design: &PlantParams, adapt: &AdaptParams, dt: f64) -> Self {
        let (lo, hi) = adapt.ratio_bounds();
        let ts = dt * DECIMATION as f64;
        let corner = (1.25 * design.f2_hz.max(design.f1_hz) * hi).min(0.25 / ts);
        let w_hp = std::f64::consts::TAU * 0.5 * design.f1_hz.min(design.f2_hz) * lo;
        let we = std::f64::consts::TAU * design.engine_hz;
        let chain = Chain {
            engine_notch: Biquad::tustin(
                [1.0, 0.0, we * we],
                [1.0, 0.2 * we, we * we],
                dt,
                Some(we),
            ),
            // Butterworth 4th order: Q = 1/(2 cos(π/8)), 1/(2 cos(3π/8)).
            anti_alias: [0.541_196_1, 1.306_563].map(|q| butterworth_low_pass(corner, q, dt)),
            high_pass: Biquad::tustin(
                [1.0, 0.0, 0.0],
                [1.0, std::f64::consts::SQRT_2 * w_hp, w_hp * w_hp],
                ts,
                Some(w_hp),
            ),
        };
        // One model beyond each end, so a mode at an end of the range has neighbours on
        // both sides of its minimum.
        let half = ((adapt.range / BANK_STEP).ceil() as usize).min(MAX_MODELS / 2 - 1);
        let step = adapt.range / half as f64;
        let ratios: Vec<f64> = (0..=2 * half + 2)
            .map(|i| 1.0 + (i as f64 - half as f64 - 1.0) * step)
            .collect();
        let models = ratios
            .iter()
            .map(|&r| Model {
                modes: [
                    mode_factor(design.f1_hz * r, design.z1, ts),
                    mode_factor(design.f2_hz * r, design.z2, ts),
                ],
                cross: 0.0,
                power: 0.0,
            })
            .collect();
        let samples_per_memory = adapt.memory_s / ts;
        Self {
            noise_floor: Self::floor(design, &chain, dt).max(1.0),
            chains: [chain.clone(), chain],
            models,
            ratios,
            bounds: (lo, hi),
            signal: 0.0,
            phase: 0,
            lambda: (-1.0 / samples_per_memory).exp(),
            energy: 0.0,
            energy_alpha: 1.0 - (-ts / ENERGY_TAU_S).exp(),
            independence: (2.0 * corner * ts).min(1.0),
            updates: 0,
            min_updates: (0.1 * samples_per_memory).ceil() as u64,
            max_rel_std: adapt.max_rel_std,
            design_f1_hz: design.f1_hz,
            design_zeta: design.z1,
            mode: None,
        }
    }

    /// The energy the rig's white accelerometer noise (σ) leaves after the chain's fast part,
    /// plus its engine tone's through the anti-alias filter alone (the notch removes most
    /// of it; the high-pass removes a little of both): so this errs high.
    fn floor(design: &PlantParams, chain: &Chain, dt: f64) -> f64 {
        let mut c = chain.clone();
        let sum_sq: f64 = (0..20_000)
            .map(|k| c.fast(f64::from(u8::from(k == 0))).powi(2))
            .sum();
        let w = std::f64::consts::TAU * design.engine_hz;
        let tone: f64 = chain
            .anti_alias
            .iter()
            .map(|f| f.response(w, dt).norm())
            .product();
        design.accel_noise_std.powi(2) * sum_sq + (design.engine_vibration_rms * tone).powi(2)
    }

    /// One loop tick's accelerometer reading (mm/s²) and cylinder position (mm); a
    /// non-finite one is read as 0.
    #[inline]
    pub fn step(&mut self, cab_accel: f64, y: f64) {
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        let a = self.chains[0].fast(finite(cab_accel));
        let y = self.chains[1].fast(finite(y));
        self.phase += 1;
        if self.phase < DECIMATION {
            return;
        }
        self.phase = 0;
        let a = self.chains[0].high_pass.step(a);
        let y = self.chains[1].high_pass.step(y);
        self.sample(a, y);
    }

    /// One decimated, band-limited sample of the acceleration and the position.
    fn sample(&mut self, a: f64, y: f64) {
        self.energy += self.energy_alpha * (a * a - self.energy);
        let update = self.energy > EXCITATION_RATIO * self.noise_floor;
        let l = self.lambda;
        for m in &mut self.models {
            // Every model runs on every sample (its state must follow the position); only
            // the sums wait for excitation.
            let u = m.modes[0].step(y);
            let predicted = m.modes[1].step(u);
            if update {
                m.cross = l * m.cross + a * predicted;
                m.power = l * m.power + predicted * predicted;
            }
        }
        if update {
            self.signal = l * self.signal + a * a;
            self.updates += 1;
            self.mode = self.minimum();
        }
    }

    /// Residual with the best gain: Σa² − (Σa·â)²/Σâ².
    fn residual(&self, i: usize) -> f64 {
        let m = &self.models[i];
        if m.power > 0.0 {
            self.signal - m.cross * m.cross / m.power
        } else {
            self.signal
        }
    }

    /// The parabola's vertex through the smallest residual and its neighbours.
    fn minimum(&self) -> Option<ModeEstimate> {
        let n = self.models.len();
        let best = (0..n).min_by(|&i, &j| self.residual(i).total_cmp(&self.residual(j)))?;
        // At an end of the range the neighbours are the two inside it.
        let mid = best.clamp(1, n - 2);
        let (j0, j1, j2) = (
            self.residual(mid - 1),
            self.residual(mid),
            self.residual(mid + 1),
        );
        let h = self.ratios[1] - self.ratios[0];
        let curvature = (j0 - 2.0 * j1 + j2) / (h * h);
        // Flat or concave (no minimum between the neighbours), or not a number.
        if curvature.is_nan() || curvature <= 0.0 {
            return None;
        }
        let offset = ((j0 - j2) / (2.0 * curvature * h)).clamp(-h, h);
        let ratio = (self.ratios[mid] + offset).clamp(self.bounds.0, self.bounds.1);
        // The smallest residual computed, not the vertex's extrapolation (which can dip
        // below zero where the parabola only approximates J): σ² errs high.
        let floor_residual = self.residual(best).max(0.0);
        let memory = 1.0 / (1.0 - self.lambda);
        let independent = (self.updates as f64).min(memory) * self.independence;
        let var = (floor_residual / independent) / (0.5 * curvature);
        Some(ModeEstimate {
            f_hz: self.design_f1_hz * ratio,
            zeta: self.design_zeta,
            ratio,
            rel_std: var.sqrt() / ratio,
        })
    }

    /// Back to the state at construction.
    pub fn reset(&mut self) {
        self.chains.iter_mut().for_each(Chain::reset);
        for m in &mut self.models {
            m.modes.iter_mut().for_each(Biquad::reset);
            m.cross = 0.0;
            m.power = 0.0;
        }
        self.signal = 0.0;
        self.phase = 0;
        self.energy = 0.0;
        self.updates = 0;
        self.mode = None;
    }

    /// The latest estimate of the first mode, confident or not.
    pub fn estimate(&self) -> Option<ModeEstimate> {
        self.mode
    }

    /// The estimate is trusted: see the module doc.
    pub fn confident(&self) -> bool {
        self.updates >= self.min_updates && self.mode.is_some_and(|m| m.rel_std <= self.max_rel_std)
    }

    /// Updates made (decimated samples with enough excitation).
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// The band's energy relative to the sensor's noise floor in it (updates from
    /// `EXCITATION_RATIO` on).
    pub fn excitation(&self) -> f64 {
        self.energy / self.noise_floor
    }
}
