//! `SyntheticOperator` for every lane: each lane its own subject (delay, gains, lags,
//! remnant), stepped with the scalar operator's operations in its order.

use crate::operator::{GRIP_EVERY, SyntheticOperator, added_delay, neuromuscular_lag};

use super::rig::{BiquadLanes, FirstOrderLanes};
use super::{LANES, Lanes, ZERO};

#[derive(Debug, Clone)]
pub(crate) struct OperatorLanes {
    error_gain: Lanes,
    shake_aversion: Lanes,
    integral_gain: Lanes,
    grip_stiffening: Lanes,
    vibration_remnant: Lanes,
    vibration_slowing: Lanes,
    vibration_regression: Lanes,
    vibration_delay: Lanes,
    neuromuscular_w: Lanes,
    neuromuscular_zeta: Lanes,
    remnant_in_std: Lanes,
    motor_in_std: Lanes,
    motor: FirstOrderLanes,
    k_bf: Lanes,
    dt: f64,
    impression_a: f64,
    /// One ring of what the display showed for all lanes, as long as the longest delay
    /// (with what felt vibration can add) needs.
    /// Where each lane reads in the ring this tick: `lag[l]` entries behind the head,
    /// kept incrementally (an integer division per lane per tick costs more than the rest
    /// of the operator); `lag` is the lane's delay plus what felt vibration adds,
    /// re-evaluated with the grip.
    read: [usize; LANES],
    delay: [usize; LANES],
    lag: [usize; LANES],
    seen_target: Vec<Lanes>,
    seen_y: Vec<Lanes>,
    head: usize,
    integral: Lanes,
    arm: BiquadLanes,
    shake_filter: BiquadLanes,
    shake_ms: Lanes,
    felt_ms: Lanes,
    pub(crate) grip: Lanes,
    shaken: Lanes,
    slowed: Lanes,
    withheld: Lanes,
    grip_countdown: u32,
}

impl OperatorLanes {
    /// From fresh operators (nothing seen yet) built for one sample period.
    pub(crate) fn new(ops: &[&SyntheticOperator; LANES]) -> Self {
        let lanes =
            |f: fn(&SyntheticOperator) -> f64| -> Lanes { std::array::from_fn(|l| f(ops[l])) };
        let delay: [usize; LANES] = std::array::from_fn(|l| ops[l].delay);
        let ring = ops.iter().map(|o| o.seen_target.len()).max().unwrap_or(1);
        Self {
            error_gain: lanes(|o| o.params.error_gain),
            shake_aversion: lanes(|o| o.params.shake_aversion_per_mm),
            integral_gain: lanes(|o| o.params.error_integral_gain),
            grip_stiffening: lanes(|o| o.params.grip_stiffening_per_m_s2),
            vibration_remnant: lanes(|o| o.params.vibration_remnant_per_m_s2),
            vibration_slowing: lanes(|o| o.params.vibration_slowing_per_m_s2),
            vibration_regression: lanes(|o| o.params.vibration_regression_per_m_s2),
            vibration_delay: lanes(|o| o.params.vibration_delay_s_per_m_s2),
            neuromuscular_w: lanes(|o| o.params.neuromuscular_w),
            neuromuscular_zeta: lanes(|o| o.params.neuromuscular_zeta),
            remnant_in_std: lanes(|o| o.remnant_in_std),
            motor_in_std: lanes(|o| o.motor_in_std),
            motor: FirstOrderLanes::new(ops[0].motor),
            k_bf: lanes(|o| o.k_bf),
            dt: ops[0].dt,
            impression_a: ops[0].impression_a,
            read: std::array::from_fn(|l| (ring - delay[l]) % ring),
            delay,
            lag: delay,
            seen_target: vec![ZERO; ring],
            seen_y: vec![ZERO; ring],
            head: 0,
            integral: ZERO,
            arm: BiquadLanes::new(&std::array::from_fn(|l| ops[l].arm)),
            shake_filter: BiquadLanes::new(&std::array::from_fn(|l| ops[l].shake_filter)),
            shake_ms: ZERO,
            felt_ms: ZERO,
            grip: [1.0; LANES],
            shaken: [1.0; LANES],
            slowed: [1.0; LANES],
            withheld: ZERO,
            grip_countdown: GRIP_EVERY,
        }
    }

    /// `SyntheticOperator::step` for every lane, with this tick's remnant deviates; returns
    /// the intended hand positions and whether the grip was re-evaluated this tick.
    #[inline(always)]
    pub(crate) fn step(
        &mut self,
        target: &Lanes,
        y: &Lanes,
        felt_accel: &Lanes,
        deviates: &Lanes,
    ) -> (Lanes, bool) {
        let ring = self.seen_target.len();
        self.seen_target[self.head] = *target;
        self.seen_y[self.head] = *y;
        let (mut t_seen, mut y_seen) = (ZERO, ZERO);
        for l in 0..LANES {
            let at = self.read[l];
            t_seen[l] = self.seen_target[at][l];
            y_seen[l] = self.seen_y[at][l];
            self.read[l] = if at + 1 == ring { 0 } else { at + 1 };
        }
        self.head = if self.head + 1 == ring {
            0
        } else {
            self.head + 1
        };

        let shake = self.shake_filter.step(&y_seen);
        let a = self.impression_a;
        for l in 0..LANES {
            self.shake_ms[l] += a * (shake[l] * shake[l] - self.shake_ms[l]);
            self.felt_ms[l] += a * (felt_accel[l] * felt_accel[l] - self.felt_ms[l]);
        }
        self.grip_countdown -= 1;
        let regripped = self.grip_countdown == 0;
        if regripped {
            self.grip_countdown = GRIP_EVERY;
            for l in 0..LANES {
                let felt = self.felt_ms[l].sqrt() * 1e-3;
                self.grip[l] = 1.0 + self.grip_stiffening[l] * felt;
                self.shaken[l] = 1.0 + self.vibration_remnant[l] * felt;
                let regression = self.vibration_regression[l] * felt;
                self.withheld[l] = regression / (1.0 + regression);
                let lag = self.delay[l] + added_delay(self.vibration_delay[l], felt, self.dt);
                if lag != self.lag[l] {
                    // The head is where the next tick writes; it reads `lag` behind.
                    self.lag[l] = lag;
                    self.read[l] = (self.head + ring - lag) % ring;
                }
                let slowed = 1.0 + self.vibration_slowing[l] * felt;
                if slowed != self.slowed[l] {
                    self.slowed[l] = slowed;
                    self.arm.retune(
                        l,
                        &neuromuscular_lag(
                            self.neuromuscular_w[l] / slowed,
                            self.neuromuscular_zeta[l],
                            self.dt,
                        ),
                    );
                }
            }
        }

        let mut input = ZERO;
        let mut motor_in = ZERO;
        for l in 0..LANES {
            motor_in[l] = self.motor_in_std[l] * deviates[l];
        }
        let motor = self.motor.step(&motor_in);
        for l in 0..LANES {
            let e = t_seen[l] - y_seen[l];
            let gain =
                self.error_gain[l] / (1.0 + self.shake_aversion[l] * self.shake_ms[l].sqrt());
            self.integral[l] += self.integral_gain[l] * e * self.dt;
            let command = (t_seen[l] + gain * e - self.withheld[l] * (1.0 + gain) * e
                + self.integral[l])
                / self.k_bf[l];
            input[l] = command + self.shaken[l] * self.remnant_in_std[l] * deviates[l];
        }
        let mut hand = self.arm.step(&input);
        for l in 0..LANES {
            hand[l] += self.shaken[l] * motor[l];
        }
        (hand, regripped)
    }
}
