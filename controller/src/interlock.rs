//! The cab-vibration interlock: the RMS of the cab acceleration over a sliding window, and a
//! trip when it exceeds the limit. A design that limit-cycles on the machine (the bench PID
//! at the study's K_BF shakes the cab at about 1.7 g RMS) is stopped within a window
//! instead of shaking a person for the whole test.
//!
//! The window is a ring of squared samples allocated when the trial is built; `update` is
//! the per-tick part and never allocates, and costs the same few operations every tick.

/// Length of the sliding window (s).
pub const WINDOW_S: f64 = 1.0;

/// Default limit (mm/s² RMS over the window): 6 m/s², about twice the largest 1 s RMS of any
/// study design's step transients on the identified rig (plain LQR reaches 3.0 m/s² on its
/// largest steps) and a third of the bench PID's limit cycle (17 m/s²). Far above ISO
/// 2631-1's "extremely uncomfortable" (> 2.5 m/s²): it is a trip for a runaway loop, not a
/// comfort limit.
pub const DEFAULT_LIMIT_MM_S2: f64 = bdft_protocol::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2;

#[derive(Debug, Clone)]
pub struct VibrationInterlock {
    pub(crate) squares: Vec<f64>,
    next: usize,
    filled: bool,
    sum: f64,
    /// Sum of the squares written since the ring last wrapped, added in ring order: at the
    /// wrap it equals the ring's sum added from scratch, bit for bit.
    pass_sum: f64,
    pub(crate) limit_sq: f64,
}

impl VibrationInterlock {
    /// An interlock tripping above `limit_mm_s2` RMS over `window_ticks` samples.
    pub fn new(limit_mm_s2: f64, window_ticks: usize) -> Self {
        Self {
            squares: vec![0.0; window_ticks.max(1)],
            next: 0,
            filled: false,
            sum: 0.0,
            pass_sum: 0.0,
            limit_sq: limit_mm_s2 * limit_mm_s2,
        }
    }

    /// Adds one sample; `true` when the RMS over the last full window exceeds the limit.
    #[inline]
    pub fn update(&mut self, accel_mm_s2: f64) -> bool {
        let sq = if accel_mm_s2.is_finite() {
            accel_mm_s2 * accel_mm_s2
        } else {
            f64::INFINITY
        };
        self.sum += sq - self.squares[self.next];
        self.squares[self.next] = sq;
        self.pass_sum += sq;
        self.next += 1;
        if self.next == self.squares.len() {
            self.next = 0;
            self.filled = true;
            // Restart from a fresh sum once a window (running sums drift by rounding). The
            // pass sum is that fresh sum, kept as the samples came: re-adding the whole ring
            // here would cost a window's worth of additions in one tick, for every trial on
            // the same tick.
            self.sum = self.pass_sum;
            self.pass_sum = 0.0;
        }
        // A non-finite reading trips at once; otherwise only a full window is judged.
        sq.is_infinite() || (self.filled && self.mean_square() > self.limit_sq)
    }

    fn mean_square(&self) -> f64 {
        self.sum.max(0.0) / self.squares.len() as f64
    }

    /// RMS over the window so far (mm/s²).
    pub fn rms(&self) -> f64 {
        self.mean_square().sqrt()
    }

    pub fn limit(&self) -> f64 {
        self.limit_sq.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trips_on_a_sine_whose_rms_exceeds_the_limit_and_not_below() {
        // A sine of amplitude A has RMS A/√2 over whole periods (4 Hz: 250 samples a
        // period at 1 kHz; the 1000-sample window holds exactly four).
        let window = 1000;
        let sine =
            |a: f64, k: usize| a * (2.0 * std::f64::consts::PI * 4.0 * k as f64 / 1000.0).sin();
        let limit = 3000.0;
        let below = limit * std::f64::consts::SQRT_2 * 0.99;
        let above = limit * std::f64::consts::SQRT_2 * 1.01;
        let mut quiet = VibrationInterlock::new(limit, window);
        assert!((0..5000).all(|k| !quiet.update(sine(below, k))));
        assert!((quiet.rms() - below / std::f64::consts::SQRT_2).abs() < 1.0);
        let mut loud = VibrationInterlock::new(limit, window);
        let trip = (0..5000).position(|k| loud.update(sine(above, k)));
        assert_eq!(trip, Some(window - 1), "judged on the first full window");
        let mut broken = VibrationInterlock::new(limit, window);
        assert!(
            broken.update(f64::NAN),
            "a non-finite reading trips at once"
        );
    }

    #[test]
    fn the_running_pass_sum_is_the_ring_added_from_scratch_bit_for_bit() {
        // Values of very different sizes, so that the order of the additions shows in the
        // rounding.
        let mut il = VibrationInterlock::new(1e9, 97);
        let mut x = 0.123_456_789_f64;
        for k in 0..1000 {
            x = (x * 3.987).fract();
            il.update(x * 10f64.powi(k % 7));
            if il.next == 0 {
                let fresh: f64 = il.squares.iter().sum();
                assert_eq!(il.sum.to_bits(), fresh.to_bits(), "after tick {k}");
            }
        }
    }
}
