//! Zero-vibration (ZV) input shapers, designed on the sample grid.
//!
//! A continuous ZV shaper for a mode (ω, ζ) is two impulses, 1/(1+K) at 0 and K/(1+K) at
//! t = π/ω_d, K = exp(−ζπ/√(1−ζ²)) (0.5/0.5 when ζ = 0). At 1 kHz, π/ω_d is not a whole number
//! of samples (125.2 ms and 80.7 ms for the backhoe's modes), and rounding the delay leaves
//! residual vibration. Instead each mode's shaper is solved exactly on the grid: impulses at
//! 0, n and n+1 samples (n = ⌊t/dt⌋) whose amplitudes sum to one and cancel the mode's
//! response exactly — the discrete shaper's zeros sit on the sampled mode's poles. The
//! multi-mode shaper is the convolution of the single-mode ones.

use crate::state::LinearState;
pub use bdft_protocol::params::{Mode, ShaperParams};

/// An impulse of the shaper: delay in seconds and amplitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Impulse {
    pub t: f64,
    pub amplitude: f64,
}

/// The textbook continuous ZV shaper of one mode.
pub fn zv_continuous(mode: Mode) -> [Impulse; 2] {
    let (_, wd) = mode.omegas();
    let k = (-mode.zeta * std::f64::consts::PI / (1.0 - mode.zeta * mode.zeta).sqrt()).exp();
    [
        Impulse {
            t: 0.0,
            amplitude: 1.0 / (1.0 + k),
        },
        Impulse {
            t: std::f64::consts::PI / wd,
            amplitude: k / (1.0 + k),
        },
    ]
}

/// Residual vibration of the mode after the last impulse, relative to an unshaped unit step
/// (1 = no reduction, 0 = none left): e^{−ζωt_N}·|Σ Aᵢ e^{ζωtᵢ} e^{jω_d tᵢ}|.
pub fn residual_vibration(impulses: &[Impulse], mode: Mode) -> f64 {
    let (w, wd) = mode.omegas();
    let sigma = mode.zeta * w;
    let t_last = impulses.iter().map(|i| i.t).fold(0.0, f64::max);
    let (mut c, mut s) = (0.0, 0.0);
    for i in impulses {
        let e = (sigma * i.t).exp();
        c += i.amplitude * e * (wd * i.t).cos();
        s += i.amplitude * e * (wd * i.t).sin();
    }
    (-sigma * t_last).exp() * c.hypot(s)
}

/// Single-mode ZV shaper with every impulse on a sample instant, as (delay in samples,
/// amplitude).
pub fn zv_sampled(mode: Mode, dt: f64) -> Vec<(usize, f64)> {
    let [_, second] = zv_continuous(mode);
    let exact = second.t / dt;
    let n = (exact + 1e-9).floor();
    if (exact - n).abs() < 1e-9 {
        return vec![(0, 1.0 - second.amplitude), (n as usize, second.amplitude)];
    }
    // Unknowns A0, A1, A2 at 0, n·dt, (n+1)·dt:
    //   A0 + A1 + A2 = 1
    //   A0 + A1 c1 + A2 c2 = 0,   A1 s1 + A2 s2 = 0   (cᵢ + j sᵢ = e^{σtᵢ} e^{jω_d tᵢ})
    let (w, wd) = mode.omegas();
    let sigma = mode.zeta * w;
    let cs = |t: f64| {
        (
            (sigma * t).exp() * (wd * t).cos(),
            (sigma * t).exp() * (wd * t).sin(),
        )
    };
    let (c1, s1) = cs(n * dt);
    let (c2, s2) = cs((n + 1.0) * dt);
    let m = nalgebra::Matrix3::new(1.0, 1.0, 1.0, 1.0, c1, c2, 0.0, s1, s2);
    let a = m
        .lu()
        .solve(&nalgebra::Vector3::new(1.0, 0.0, 0.0))
        .expect("the ZV equations are regular for 0 < n·dt < π/ω_d < (n+1)·dt");
    vec![(0, a[0]), (n as usize, a[1]), ((n as usize) + 1, a[2])]
}

/// Convolution of two impulse sequences (delays add, amplitudes multiply), merged by delay.
fn convolve(a: &[(usize, f64)], b: &[(usize, f64)]) -> Vec<(usize, f64)> {
    let mut out: Vec<(usize, f64)> = Vec::with_capacity(a.len() * b.len());
    for &(da, aa) in a {
        for &(db, ab) in b {
            match out.iter_mut().find(|(d, _)| *d == da + db) {
                Some((_, amp)) => *amp += aa * ab,
                None => out.push((da + db, aa * ab)),
            }
        }
    }
    out.sort_by_key(|&(d, _)| d);
    out
}

/// The multi-mode shaper on the sample grid.
pub fn design(params: &ShaperParams, dt: f64) -> Vec<(usize, f64)> {
    params
        .modes
        .iter()
        .map(|&m| zv_sampled(m, dt))
        .fold(vec![(0, 1.0)], |acc, s| convolve(&acc, &s))
}

/// The shaper running on a reference signal: a ring buffer of past inputs, sized once.
#[derive(Debug, Clone)]
pub struct Shaper {
    taps: Vec<(usize, f64)>,
    buf: Vec<f64>,
    head: usize,
}

impl Shaper {
    pub fn new(params: &ShaperParams, dt: f64) -> Self {
        let taps = design(params, dt);
        let len = taps.last().map_or(0, |t| t.0) + 1;
        Self {
            taps,
            buf: vec![0.0; len],
            head: 0,
        }
    }

    /// (delay in samples, amplitude) of each impulse.
    pub fn taps(&self) -> &[(usize, f64)] {
        &self.taps
    }

    #[inline]
    pub fn step(&mut self, r: f64) -> f64 {
        let len = self.buf.len();
        self.buf[self.head] = r;
        let mut out = 0.0;
        for &(d, a) in &self.taps {
            out += a * self.buf[(self.head + len - d) % len];
        }
        self.head = (self.head + 1) % len;
        out
    }

    pub fn reset(&mut self) {
        self.buf.fill(0.0);
        self.head = 0;
    }
}

impl LinearState for Shaper {
    /// The state is the last `len − 1` inputs, newest first.
    fn state_len(&self) -> usize {
        self.buf.len() - 1
    }
    fn read_state(&self, out: &mut [f64]) {
        let len = self.buf.len();
        for (j, o) in out[..len - 1].iter_mut().enumerate() {
            *o = self.buf[(self.head + len - 1 - j) % len];
        }
    }
    fn write_state(&mut self, s: &[f64]) {
        let len = self.buf.len();
        for (j, v) in s[..len - 1].iter().enumerate() {
            self.buf[(self.head + len - 1 - j) % len] = *v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 1e-3;

    fn as_impulses(taps: &[(usize, f64)]) -> Vec<Impulse> {
        taps.iter()
            .map(|&(d, a)| Impulse {
                t: d as f64 * DT,
                amplitude: a,
            })
            .collect()
    }

    #[test]
    fn continuous_zv_cancels_its_mode_and_is_half_half_without_damping() {
        let undamped = zv_continuous(Mode {
            f_hz: 4.0,
            zeta: 0.0,
        });
        assert!((undamped[0].amplitude - 0.5).abs() < 1e-15);
        assert!((undamped[1].t - 0.125).abs() < 1e-15);
        let m = Mode {
            f_hz: 4.0,
            zeta: 0.06,
        };
        assert!(residual_vibration(&zv_continuous(m), m) < 1e-14);
    }

    #[test]
    fn sampled_two_mode_shaper_leaves_no_residual_vibration_at_either_mode() {
        let p = ShaperParams::default();
        let taps = design(&p, DT);
        let imp = as_impulses(&taps);
        for &m in &p.modes {
            let r = residual_vibration(&imp, m);
            assert!(r < 1e-12, "residual {r} at {} Hz", m.f_hz);
        }
        // Unit DC gain, positive impulses (no overshoot of the shaped step), about 0.2 s.
        let sum: f64 = taps.iter().map(|t| t.1).sum();
        assert!((sum - 1.0).abs() < 1e-12);
        assert!(taps.iter().all(|t| t.1 > 0.0));
        let total = taps.last().unwrap().0 as f64 * DT;
        let ideal: f64 = p.modes.iter().map(|&m| zv_continuous(m)[1].t).sum();
        assert!(
            total >= ideal && total <= ideal + 2.0 * DT,
            "{total} vs {ideal}"
        );
        // Rounding the delays to whole samples instead would leave measurable vibration.
        let rounded: Vec<Impulse> = p
            .modes
            .iter()
            .map(|&m| {
                let [a, b] = zv_continuous(m);
                [
                    a,
                    Impulse {
                        t: (b.t / DT).round() * DT,
                        ..b
                    },
                ]
            })
            .fold(
                vec![Impulse {
                    t: 0.0,
                    amplitude: 1.0,
                }],
                |acc, s| {
                    acc.iter()
                        .flat_map(|x| {
                            s.iter().map(move |y| Impulse {
                                t: x.t + y.t,
                                amplitude: x.amplitude * y.amplitude,
                            })
                        })
                        .collect()
                },
            );
        assert!(residual_vibration(&rounded, p.modes[0]) > 1e-3);
    }

    #[test]
    fn whole_sample_delay_reduces_to_the_continuous_shaper() {
        // f such that π/ω_d is exactly 100 samples.
        let zeta: f64 = 0.05;
        let f = 1.0 / (2.0 * 0.1 * (1.0 - zeta * zeta).sqrt());
        let taps = zv_sampled(Mode { f_hz: f, zeta }, DT);
        let c = zv_continuous(Mode { f_hz: f, zeta });
        assert_eq!(taps.len(), 2);
        assert_eq!(taps[1].0, 100);
        assert!((taps[1].1 - c[1].amplitude).abs() < 1e-12);
    }

    #[test]
    fn running_shaper_equals_the_impulse_sum_and_round_trips_its_state() {
        let p = ShaperParams::default();
        let mut s = Shaper::new(&p, DT);
        let input: Vec<f64> = (0..600).map(|k| ((k / 37) % 5) as f64 - 2.0).collect();
        let out: Vec<f64> = input.iter().map(|&r| s.step(r)).collect();
        for k in [0, 1, 124, 126, 300, 599] {
            let want: f64 = s
                .taps()
                .iter()
                .filter(|t| t.0 <= k)
                .map(|&(d, a)| a * input[k - d])
                .sum();
            assert!((out[k] - want).abs() < 1e-12);
        }
        let mut state = vec![0.0; s.state_len()];
        s.read_state(&mut state);
        assert_eq!(state[0], input[599]);
        let mut t = Shaper::new(&p, DT);
        t.write_state(&state);
        assert_eq!(t.step(1.0), s.step(1.0));
    }
}
