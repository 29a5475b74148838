//! A synthetic operator: a simulated subject for automated end-to-end tests, pilot runs and
//! the power planner.
//!
//! A pursuit model, as in the manual-control literature: the operator sees the target T and
//! the cylinder position y on the display after a reaction delay τ, moves the device to
//! where the target maps to (T/K_BF), adds an error-correcting term on the seen error
//! e = T − y (proportional plus a slow integral, which removes a steady offset), and the arm
//! follows through a second-order neuromuscular lag ω_nm²/(s² + 2ζω_nm s + ω_nm²). Remnant
//! — the part of human output not explained by the model — is white noise through the same
//! lag.
//!
//! Two adaptations follow McRuer's crossover model and the feedthrough literature rather
//! than being imposed on the outcome:
//! - **Gain on an oscillatory element.** The operator watches how much the cylinder shakes
//!   on the display (seen y above 3 Hz, RMS over about a second) and lowers the error gain
//!   by 1/(1 + shake_aversion·shake): a shaky loop is corrected more gently.
//! - **Grip under vibration.** On the machine the operator feels the cab's acceleration
//!   (RMS over about a second) and grips harder: the arm's frequency rises by
//!   grip_stiffening per m/s² (`grip`, which the runner hands to a seated body), and its
//!   remnant grows by vibration_remnant per m/s² (whole-body vibration makes manual control
//!   noisier), the arm's neuromuscular corner falls by 1/(1 + vibration_slowing per m/s²)
//!   (Lewis & Griffin's vibration-induced phase lag), and the whole correction's gain falls
//!   by 1/(1 + vibration_regression per m/s²) (McRuer's crossover regression when the task
//!   turns disturbing): the effects that make riding cost accuracy at every step. The two
//!   differ where it matters for feedthrough: a slower arm also filters the operator's own
//!   4–6 Hz output, which excites the cab modes; a lower gain leaves that filtering as it
//!   was, so the riding cost grows with the felt vibration a controller lets through.
//!
//! What the operator can correct follows from the delay and the lag: slow feedthrough is
//! seen on the display and corrected, feedthrough near the cab modes (4–6 Hz) is far above
//! the operator's bandwidth and passes through uncorrected.

pub use bdft_protocol::identification::IdentificationTask;
pub use bdft_protocol::params::{MAX_VIBRATION_DELAY_S, MOTOR_NOISE_CORNER_HZ, OperatorParams};

use crate::error::ParamError;
use crate::filters::{Biquad, FirstOrder};
use crate::params::check;
use crate::rng::Rng;

/// Corner of the high-pass that separates seen shake from tracking motion (rad/s): above
/// the cylinder's following of a step (its closed loops reach 1–2 Hz), below the cab's
/// modes (4 and 6.2 Hz).
const SHAKE_CORNER: f64 = 2.0 * std::f64::consts::PI * 3.0;

/// The filter that takes the shake out of a seen cylinder position: a second-order
/// Butterworth high-pass at 3 Hz. The operator's gain and the survey's smoothness both see
/// the cylinder through it.
pub fn shake_filter(dt: f64) -> Biquad {
    let w = SHAKE_CORNER;
    Biquad::tustin(
        [1.0, 0.0, 0.0],
        [1.0, std::f64::consts::SQRT_2 * w, w * w],
        dt,
        Some(w),
    )
}
/// The operator's neuromuscular lag ω²/(s² + 2ζωs + ω²) at corner `w` (rad/s).
pub(crate) fn neuromuscular_lag(w: f64, zeta: f64, dt: f64) -> Biquad {
    Biquad::tustin([0.0, 0.0, w * w], [1.0, 2.0 * zeta * w, w * w], dt, None)
}

/// The motor noise's first-order lag ω/(s + ω) at `MOTOR_NOISE_CORNER_HZ`.
pub(crate) fn motor_lag(dt: f64) -> FirstOrder {
    let w = 2.0 * std::f64::consts::PI * MOTOR_NOISE_CORNER_HZ;
    FirstOrder::tustin([0.0, w], [1.0, w], dt, None)
}

/// The ticks of reaction delay `per_m_s2` (s per m/s²) adds at `felt` m/s² RMS, at most
/// `MAX_VIBRATION_DELAY_S`.
#[inline]
pub(crate) fn added_delay(per_m_s2: f64, felt: f64, dt: f64) -> usize {
    ((per_m_s2 * felt).min(MAX_VIBRATION_DELAY_S) / dt).round() as usize
}

/// Time constant of the operator's running impressions of shake and vibration (s).
const IMPRESSION_S: f64 = 1.0;
/// The grip is re-evaluated every this many ticks: it changes over seconds, and retuning
/// the arm's filter costs a tangent.
pub(crate) const GRIP_EVERY: u32 = 50;

#[derive(Debug, Clone)]
pub struct SyntheticOperator {
    pub(crate) params: OperatorParams,
    pub(crate) dt: f64,
    pub(crate) k_bf: f64,
    /// Ring buffers of what the display showed: target and cylinder position, long enough
    /// for the reaction delay and the most felt vibration can add to it.
    pub(crate) seen_target: Vec<f64>,
    seen_y: Vec<f64>,
    head: usize,
    /// The reaction delay in ticks, and the lag the operator reads the display with now
    /// (the delay plus what felt vibration adds, re-evaluated with the grip).
    pub(crate) delay: usize,
    lag: usize,
    integral: f64,
    /// The neuromuscular lag.
    pub(crate) arm: Biquad,
    /// Seen y above `SHAKE_CORNER`, and the running mean squares of it and of the felt cab
    /// acceleration (exponential, `IMPRESSION_S`).
    pub(crate) shake_filter: Biquad,
    shake_ms: f64,
    felt_ms: f64,
    pub(crate) impression_a: f64,
    grip: f64,
    /// Relaxed in an identification test (`holding`): the grip stays 1 whatever is felt.
    relaxed: bool,
    /// The remnant's factor from felt vibration, re-evaluated with the grip.
    shaken: f64,
    /// The factor by which felt vibration has slowed the arm (1 = calm), re-evaluated with
    /// the grip.
    slowed: f64,
    /// The fraction of the correction that felt vibration withholds (crossover regression;
    /// 0 = calm), re-evaluated with the grip.
    withheld: f64,
    grip_countdown: u32,
    /// White-noise standard deviation before the lag that gives remnant_std_mm after it.
    pub(crate) remnant_in_std: f64,
    /// The motor noise's lag (`motor_lag`), and the standard deviation before it that gives
    /// motor_noise_mm after it. The motor noise is the remnant's own white deviate, shaped
    /// a second way: one noise source whose spectrum has the arm's slow part and a part flat
    /// to the tremor band.
    pub(crate) motor: FirstOrder,
    pub(crate) motor_in_std: f64,
    pub(crate) rng: Rng,
}

/// Σh² of a discrete lag's impulse response (`step` the lag's tick from rest): the fraction
/// of a white input's variance it passes.
fn variance_gain(mut step: impl FnMut(f64) -> f64) -> f64 {
    let mut sum = step(1.0).powi(2);
    // The response decays as e^(−ζω t); 60 time constants leave less than 1e-50 of it.
    for _ in 0..200_000 {
        let h = step(0.0);
        sum += h * h;
        if h.abs() < 1e-30 && sum > 0.0 {
            break;
        }
    }
    sum
}

/// The arm's lag from rest, as a tick.
fn from_rest(mut lag: Biquad) -> impl FnMut(f64) -> f64 {
    lag.reset();
    move |u| lag.step(u)
}

impl SyntheticOperator {
    pub fn new(params: OperatorParams, dt: f64, k_bf: f64, seed: u64) -> Result<Self, ParamError> {
        params.validate()?;
        check("kbf", k_bf, 1e-3, crate::params::MAX_KBF)?;
        let delay = (params.reaction_delay_s / dt).round() as usize;
        let most_added = if params.vibration_delay_s_per_m_s2 > 0.0 {
            (MAX_VIBRATION_DELAY_S / dt).round() as usize
        } else {
            0
        };
        let (w, z) = (params.neuromuscular_w, params.neuromuscular_zeta);
        let arm = neuromuscular_lag(w, z, dt);
        let motor = motor_lag(dt);
        Ok(Self {
            params,
            dt,
            k_bf,
            seen_target: vec![0.0; delay + most_added + 1],
            seen_y: vec![0.0; delay + most_added + 1],
            head: 0,
            delay,
            lag: delay,
            integral: 0.0,
            arm,
            shake_filter: shake_filter(dt),
            shake_ms: 0.0,
            felt_ms: 0.0,
            impression_a: 1.0 - (-dt / IMPRESSION_S).exp(),
            grip: 1.0,
            relaxed: false,
            shaken: 1.0,
            slowed: 1.0,
            withheld: 0.0,
            grip_countdown: GRIP_EVERY,
            remnant_in_std: params.remnant_std_mm / variance_gain(from_rest(arm)).sqrt(),
            motor,
            motor_in_std: params.motor_noise_mm
                / variance_gain({
                    let mut m = motor;
                    m.reset();
                    move |u| m.step(u)
                })
                .sqrt(),
            rng: Rng::derive(seed, Rng::OPERATOR),
        })
    }

    /// One tick: the display shows `target` and `y` now and the seat carries `felt_accel`
    /// (mm/s²; 0 at the desk); returns the intended hand position.
    #[inline]
    pub fn step(&mut self, target: f64, y: f64, felt_accel: f64) -> f64 {
        let len = self.seen_target.len();
        self.seen_target[self.head] = target;
        self.seen_y[self.head] = y;
        // What the display showed `lag` ticks ago is what the operator reacts to now.
        let at = (self.head + len - self.lag) % len;
        let (t_seen, y_seen) = (self.seen_target[at], self.seen_y[at]);
        self.head = (self.head + 1) % len;

        let shake = self.shake_filter.step(y_seen);
        self.shake_ms += self.impression_a * (shake * shake - self.shake_ms);
        self.feel(felt_accel);

        let e = t_seen - y_seen;
        let gain = self.params.error_gain
            / (1.0 + self.params.shake_aversion_per_mm * self.shake_ms.sqrt());
        self.integral += self.params.error_integral_gain * e * self.dt;
        // Of the correction t_seen − y_seen + gain·e, vibration withholds a fraction;
        // calm (withheld = 0), the command is exactly the pursuit t_seen + gain·e.
        let command =
            (t_seen + gain * e - self.withheld * (1.0 + gain) * e + self.integral) / self.k_bf;
        let d = self.deviate();
        let noise = self.shaken * self.remnant_in_std * d;
        let motor = self.shaken * self.motor.step(self.motor_in_std * d);
        self.arm.step(command + noise) + motor
    }

    /// Whether the operator draws a noise deviate each tick.
    pub(crate) fn noisy(&self) -> bool {
        self.remnant_in_std > 0.0 || self.motor_in_std > 0.0
    }

    /// One tick of the identification test (`holding`): the operator tracks nothing and
    /// holds the device at its centre, so the intended hand position is the remnant alone,
    /// through the neuromuscular lag — no motor noise, which is the noise of active
    /// corrections (signal-dependent: Harris & Wolpert). Felt vibration still grows the
    /// remnant, slows the arm and — holding still — stiffens the grip as in tracking;
    /// relaxed, the grip stays 1.
    #[inline]
    pub fn hold(&mut self, felt_accel: f64) -> f64 {
        self.feel(felt_accel);
        let d = self.deviate();
        self.arm.step(self.shaken * self.remnant_in_std * d)
    }

    /// Sets the task of an identification test (what `hold` does with the grip).
    pub fn holding(mut self, task: IdentificationTask) -> Self {
        self.relaxed = task == IdentificationTask::Relax;
        self
    }

    /// The felt cab acceleration's running impression, and every `GRIP_EVERY` ticks the
    /// grip, remnant and arm it sets.
    #[inline]
    fn feel(&mut self, felt_accel: f64) {
        self.felt_ms += self.impression_a * (felt_accel * felt_accel - self.felt_ms);
        self.grip_countdown -= 1;
        if self.grip_countdown == 0 {
            self.grip_countdown = GRIP_EVERY;
            // mm/s² → m/s².
            let felt = self.felt_ms.sqrt() * 1e-3;
            if !self.relaxed {
                self.grip = 1.0 + self.params.grip_stiffening_per_m_s2 * felt;
            }
            self.shaken = 1.0 + self.params.vibration_remnant_per_m_s2 * felt;
            let regression = self.params.vibration_regression_per_m_s2 * felt;
            self.withheld = regression / (1.0 + regression);
            self.lag =
                self.delay + added_delay(self.params.vibration_delay_s_per_m_s2, felt, self.dt);
            let slowed = 1.0 + self.params.vibration_slowing_per_m_s2 * felt;
            if slowed != self.slowed {
                self.slowed = slowed;
                self.arm.retune(&neuromuscular_lag(
                    self.params.neuromuscular_w / slowed,
                    self.params.neuromuscular_zeta,
                    self.dt,
                ));
            }
        }
    }

    /// This tick's standard-normal noise deviate (0 for an operator without noise, which
    /// draws none).
    #[inline]
    fn deviate(&mut self) -> f64 {
        if self.noisy() { self.rng.normal() } else { 0.0 }
    }

    /// How hard the operator grips now: the factor on a seated body's arm frequency.
    pub fn grip(&self) -> f64 {
        self.grip
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quiet() -> OperatorParams {
        OperatorParams {
            remnant_std_mm: 0.0,
            error_gain: 0.0,
            error_integral_gain: 0.0,
            shake_aversion_per_mm: 0.0,
            vibration_remnant_per_m_s2: 0.0,
            ..OperatorParams::default()
        }
    }

    #[test]
    fn reacts_after_the_delay_and_settles_through_the_second_order_lag() {
        let p = OperatorParams {
            neuromuscular_zeta: 1.0,
            ..quiet()
        };
        let dt = 1e-3;
        let mut op = SyntheticOperator::new(p, dt, 0.5, 1).unwrap();
        // A 10 mm target step at t = 0 with the cylinder held at the target: pure pursuit,
        // so the hand goes to 10/K_BF = 20 mm through the lag after τ.
        let out: Vec<f64> = (0..3000).map(|_| op.step(10.0, 10.0, 0.0)).collect();
        assert!(
            out[..250].iter().all(|&h| h == 0.0),
            "moved before the reaction delay"
        );
        assert!(out[252] > 0.0);
        // Critically damped: the step response is 1 − (1 + ωt)e^(−ωt); at ωt = 2, 0.594.
        let k = 250 + (2.0 / 12.0 / dt).round() as usize;
        let want = 1.0 - 3.0 * (-2.0f64).exp();
        assert!((out[k] / 20.0 - want).abs() < 0.01, "{} vs {want}", out[k]);
        assert!((out[2999] - 20.0).abs() < 1e-3);
    }

    #[test]
    fn remnant_has_the_requested_spread_and_is_seeded() {
        let p = OperatorParams {
            remnant_std_mm: 2.0,
            ..quiet()
        };
        let run = |seed| {
            let mut op = SyntheticOperator::new(p, 1e-3, 1.0, seed).unwrap();
            (0..400_000)
                .map(|_| op.step(0.0, 0.0, 0.0))
                .collect::<Vec<f64>>()
        };
        let a = run(3);
        assert_eq!(a, run(3));
        assert_ne!(a, run(4));
        let (_, std) = crate::signals::mean_std(&a[10_000..]);
        assert!((std - 2.0).abs() < 0.15, "{std}");
    }

    #[test]
    fn motor_noise_has_its_spread_and_the_first_order_lags_correlation() {
        // Motor noise alone: white noise through the Tustin first-order lag ω/(s + ω) at
        // 8 Hz. Its impulse response is b, b(1 + a)a^(k−1) with a = (c − ω)/(c + ω),
        // c = 2/dt, so the lag-one autocorrelation is (1 + a)/2 (γ₁/γ₀ summed in closed
        // form); the remnant's second-order lag at 12 rad/s would give nearly 1.
        let p = OperatorParams {
            motor_noise_mm: 0.7,
            ..quiet()
        };
        let dt = 1e-3;
        let mut op = SyntheticOperator::new(p, dt, 1.0, 5).unwrap();
        let out: Vec<f64> = (0..400_000).map(|_| op.step(0.0, 0.0, 0.0)).collect();
        let x = &out[1_000..];
        let (mean, std) = crate::signals::mean_std(x);
        assert!((std - 0.7).abs() < 0.02, "{std}");
        let lag1 = x
            .windows(2)
            .map(|w| (w[0] - mean) * (w[1] - mean))
            .sum::<f64>()
            / (x.len() - 1) as f64
            / (std * std);
        let (c, w) = (2.0 / dt, 2.0 * std::f64::consts::PI * 8.0);
        let a = (c - w) / (c + w);
        assert!((lag1 - (1.0 + a) / 2.0).abs() < 0.003, "{lag1}");
        // Holding still (the identification test), there is no motor noise.
        let mut held = SyntheticOperator::new(p, dt, 1.0, 5).unwrap();
        assert!((0..10_000).all(|_| held.hold(0.0) == 0.0));
    }

    /// sin(2π·f·t).
    fn sine(f_hz: f64, t: f64) -> f64 {
        (2.0 * std::f64::consts::PI * f_hz * t).sin()
    }

    /// The operator's mean hand position over the second 10 s of 20 s at 1 kHz, the target
    /// held at 10 mm and `at(t)` giving the seen cylinder (mm) and the felt cab acceleration
    /// (mm/s²) at time t.
    fn settled_hand(p: OperatorParams, at: impl Fn(f64) -> (f64, f64)) -> f64 {
        let dt = 1e-3;
        let mut op = SyntheticOperator::new(p, dt, 1.0, 1).unwrap();
        let mut sum = 0.0;
        for k in 0..20_000 {
            let (y, felt) = at(k as f64 * dt);
            let hand = op.step(10.0, y, felt);
            if k >= 10_000 {
                sum += hand;
            }
        }
        sum / 10_000.0
    }

    #[test]
    fn a_shaking_cylinder_lowers_the_error_correction() {
        // The seen error is the same constant offset in both runs; in one the cylinder also
        // shakes at 5 Hz. The proportional correction shrinks by 1/(1 + a·RMS shake).
        let p = OperatorParams {
            error_gain: 1.0,
            shake_aversion_per_mm: 0.5,
            neuromuscular_zeta: 1.0,
            ..quiet()
        };
        let settle = |amp: f64| settled_hand(p, |t| (amp * sine(5.0, t), 0.0));
        // Without shake: 10 + 1.0·10 = 20 mm. With a 2 mm sine (RMS √2, times the 3 Hz
        // Butterworth high-pass's gain at 5 Hz, r²/√((1 − r²)² + 2r²) with r = 5/3):
        // gain 1/(1 + 0.5·RMS seen).
        let calm = settle(0.0);
        assert!((calm - 20.0).abs() < 1e-6, "{calm}");
        let shaken = settle(2.0);
        let r2 = (5.0f64 / 3.0).powi(2);
        let hp = r2 / ((1.0 - r2).powi(2) + 2.0 * r2).sqrt();
        let want = 10.0 + 10.0 / (1.0 + 0.5 * 2.0 * hp / 2f64.sqrt());
        assert!((shaken - want).abs() < 0.05, "{shaken} vs {want}");
    }

    #[test]
    fn felt_vibration_withholds_part_of_the_whole_correction() {
        // The cylinder rests at 0 and the target at 10 mm. Calm, the operator commands the
        // pursuit plus the error gain's part: 10 + 1.0·10 = 20 mm. Feeling 3 m/s² RMS with a
        // regression of 0.5 per m/s², the correction's gain falls by 1/(1 + 0.5·3): 8 mm.
        let p = OperatorParams {
            error_gain: 1.0,
            vibration_regression_per_m_s2: 0.5,
            neuromuscular_zeta: 1.0,
            ..quiet()
        };
        let settle =
            |rms_m_s2: f64| settled_hand(p, |t| (0.0, rms_m_s2 * 1e3 * 2f64.sqrt() * sine(4.0, t)));
        let calm = settle(0.0);
        assert!((calm - 20.0).abs() < 1e-6, "{calm}");
        let shaken = settle(3.0);
        assert!((shaken - 8.0).abs() < 0.1, "{shaken}");
    }

    #[test]
    fn felt_vibration_delays_the_reaction_up_to_its_cap() {
        // 10 s of a 4 Hz sine felt at `rms` m/s² with the target at 0, then a 10 mm target
        // step: pure pursuit, so the hand leaves 0 when the step has been seen, τ + the
        // added delay (0.2 s per m/s², at most `MAX_VIBRATION_DELAY_S`) after it.
        let p = OperatorParams {
            vibration_delay_s_per_m_s2: 0.2,
            ..quiet()
        };
        let dt = 1e-3;
        let reaction = |rms: f64| {
            let mut op = SyntheticOperator::new(p, dt, 1.0, 1).unwrap();
            let felt = |k: usize| rms * 1e3 * 2f64.sqrt() * sine(4.0, k as f64 * dt);
            for k in 0..10_000 {
                op.step(0.0, 0.0, felt(k));
            }
            (0..2_000)
                .position(|k| op.step(10.0, 0.0, felt(10_000 + k)) != 0.0)
                .expect("the hand moves") as f64
                * dt
        };
        // Calm: τ = 0.25 s (Tustin's lag passes a step on the tick it arrives).
        let calm = reaction(0.0);
        assert!((calm - 0.25).abs() < 1e-9, "{calm}");
        // 0.5 m/s²: 0.1 s later (the felt RMS's ripple may move it by a tick).
        let shaken = reaction(0.5) - calm;
        assert!((shaken - 0.1).abs() <= 0.002, "{shaken}");
        // 3 m/s² would add 0.6 s: the cap's 0.3.
        let capped = reaction(3.0) - calm;
        assert!((capped - MAX_VIBRATION_DELAY_S).abs() <= 0.002, "{capped}");
    }

    #[test]
    fn vibration_stiffens_the_grip_in_proportion_to_its_rms() {
        let p = OperatorParams {
            grip_stiffening_per_m_s2: 0.2,
            ..quiet()
        };
        let mut op = SyntheticOperator::new(p, 1e-3, 1.0, 1).unwrap();
        assert_eq!(op.grip(), 1.0);
        // 3 m/s² RMS: a sine of amplitude 3√2 m/s².
        for k in 0..10_000 {
            let a =
                3000.0 * 2f64.sqrt() * (2.0 * std::f64::consts::PI * 4.0 * k as f64 * 1e-3).sin();
            op.step(0.0, 0.0, a);
        }
        assert!((op.grip() - 1.6).abs() < 0.02, "{}", op.grip());
    }
}
