//! A synthetic operator: a simulated subject for automated end-to-end tests and pilot runs.
//!
//! A pursuit model, as in the manual-control literature: the operator sees the target T and
//! the cylinder position y on the display after a reaction delay τ, moves the device to
//! where the target maps to (T/K_BF), adds an error-correcting term on the seen error
//! e = T − y (proportional plus a slow integral, which removes the steady offset the
//! feedthrough causes), and the arm follows through a first-order neuromuscular lag. Remnant
//! — the part of human output not explained by the model — is white noise through the same
//! lag.

pub use bdft_protocol::params::OperatorParams;

use crate::error::ParamError;
use crate::params::check;
use crate::rng::Rng;

#[derive(Debug, Clone)]
pub struct SyntheticOperator {
    params: OperatorParams,
    dt: f64,
    k_bf: f64,
    /// Ring buffers of what the display showed: target and cylinder position.
    seen_target: Vec<f64>,
    seen_y: Vec<f64>,
    head: usize,
    integral: f64,
    /// Discrete lag y[k+1] = a·y[k] + (1 − a)·u[k] (zero-order hold of ω/(s + ω)).
    lag_a: f64,
    hand: f64,
    /// White-noise standard deviation before the lag that gives remnant_std_mm after it:
    /// the lag passes a variance fraction (1 − a)/(1 + a).
    remnant_in_std: f64,
    rng: Rng,
}

impl SyntheticOperator {
    pub fn new(params: OperatorParams, dt: f64, k_bf: f64, seed: u64) -> Result<Self, ParamError> {
        params.validate()?;
        check("kbf", k_bf, 1e-3, crate::params::MAX_KBF)?;
        let delay = (params.reaction_delay_s / dt).round() as usize;
        let lag_a = (-params.neuromuscular_w * dt).exp();
        Ok(Self {
            params,
            dt,
            k_bf,
            seen_target: vec![0.0; delay + 1],
            seen_y: vec![0.0; delay + 1],
            head: 0,
            integral: 0.0,
            lag_a,
            hand: 0.0,
            remnant_in_std: params.remnant_std_mm * ((1.0 + lag_a) / (1.0 - lag_a)).sqrt(),
            rng: Rng::derive(seed, Rng::OPERATOR),
        })
    }

    /// One tick: the display shows `target` and `y` now; returns the intended hand position.
    #[inline]
    pub fn step(&mut self, target: f64, y: f64) -> f64 {
        let len = self.seen_target.len();
        self.seen_target[self.head] = target;
        self.seen_y[self.head] = y;
        // The oldest entry is what the operator reacts to now.
        let oldest = (self.head + 1) % len;
        let (t_seen, y_seen) = (self.seen_target[oldest], self.seen_y[oldest]);
        self.head = oldest;
        let e = t_seen - y_seen;
        self.integral += self.params.error_integral_gain * e * self.dt;
        let command = (t_seen + self.params.error_gain * e + self.integral) / self.k_bf;
        let noise = if self.remnant_in_std > 0.0 {
            self.remnant_in_std * self.rng.normal()
        } else {
            0.0
        };
        let out = self.hand;
        self.hand = self.lag_a * self.hand + (1.0 - self.lag_a) * (command + noise);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reacts_after_the_delay_and_settles_through_the_lag() {
        let p = OperatorParams {
            remnant_std_mm: 0.0,
            error_gain: 0.0,
            error_integral_gain: 0.0,
            ..OperatorParams::default()
        };
        let dt = 1e-3;
        let mut op = SyntheticOperator::new(p, dt, 0.5, 1).unwrap();
        // A 10 mm target step at t = 0 with the cylinder held at the target: pure pursuit,
        // so the hand goes to 10/K_BF = 20 mm with the lag's time constant after τ.
        let out: Vec<f64> = (0..2000).map(|_| op.step(10.0, 10.0)).collect();
        assert!(
            out[..250].iter().all(|&h| h == 0.0),
            "moved before the reaction delay"
        );
        assert!(out[252] > 0.0);
        // One time constant (1/12 s) after the delay: 1 − e⁻¹ of the way.
        let k = 250 + (1000.0 / 12.0f64).round() as usize + 1;
        assert!(
            (out[k] / 20.0 - (1.0 - (-1.0f64).exp())).abs() < 0.01,
            "{}",
            out[k]
        );
        assert!((out[1999] - 20.0).abs() < 1e-3);
    }

    #[test]
    fn remnant_has_the_requested_spread_and_is_seeded() {
        let p = OperatorParams {
            remnant_std_mm: 2.0,
            error_gain: 0.0,
            error_integral_gain: 0.0,
            ..OperatorParams::default()
        };
        let run = |seed| {
            let mut op = SyntheticOperator::new(p, 1e-3, 1.0, seed).unwrap();
            (0..400_000)
                .map(|_| op.step(0.0, 0.0))
                .collect::<Vec<f64>>()
        };
        let a = run(3);
        assert_eq!(a, run(3));
        assert_ne!(a, run(4));
        let (_, std) = crate::signals::mean_std(&a[10_000..]);
        assert!((std - 2.0).abs() < 0.15, "{std}");
    }
}
