//! Input shapers, designed on the sample grid: zero-vibration (ZV) and the robust ZVD, EI
//! and two-hump EI.
//!
//! A continuous ZV shaper for a mode (ω, ζ) is two impulses, 1/(1+K) at 0 and K/(1+K) at
//! t = π/ω_d, K = exp(−ζπ/√(1−ζ²)) (0.5/0.5 when ζ = 0). At 1 kHz, π/ω_d is not a whole number
//! of samples (125.2 ms and 80.7 ms for the backhoe's modes), and rounding the delay leaves
//! residual vibration. Instead each mode's shaper is solved exactly on the grid: impulses at
//! 0, n and n+1 samples (n = ⌊t/dt⌋) whose amplitudes sum to one and cancel the mode's
//! response exactly — the discrete shaper's zeros sit on the sampled mode's poles. The
//! multi-mode shaper is the convolution of the single-mode ones.
//!
//! The robust shapers are the textbook impulse sequences at multiples of the half damped
//! period (Singer & Seering 1990; Singhose, Seering & Singer 1994 for the two-hump EI), their
//! undamped amplitudes aᵢ made exact for the mode's damping by weighting them Kⁱ
//! (K = e^{−ζπ/√(1−ζ²)}, as from ZV to damped ZV). Their impulse times fall between samples;
//! each is split linearly between its two neighbouring samples, which moves the residual by
//! O((ω·dt)²) — 10⁻⁴ at the structure modes, far inside any tolerance these shapers have.

use crate::state::LinearState;
pub use bdft_protocol::params::{Mode, ShaperMethod, ShaperParams};

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

/// The continuous shaper of one mode for a robust `method` (not ZV: [`zv_continuous`]);
/// `tolerance` is the EI methods' allowed residual V.
pub fn robust_continuous(mode: Mode, method: ShaperMethod, tolerance: f64) -> Vec<Impulse> {
    let v = tolerance;
    let undamped: Vec<f64> = match method {
        ShaperMethod::Zv => unreachable!("ZV is solved exactly on the grid"),
        ShaperMethod::Zvd => vec![0.25, 0.5, 0.25],
        ShaperMethod::Ei => vec![(1.0 + v) / 4.0, (1.0 - v) / 2.0, (1.0 + v) / 4.0],
        ShaperMethod::TwoHumpEi => {
            let x = (v * v * ((1.0 - v * v).sqrt() + 1.0)).cbrt();
            let a1 = (3.0 * x * x + 2.0 * x + 3.0 * v * v) / (16.0 * x);
            vec![a1, 0.5 - a1, 0.5 - a1, a1]
        }
    };
    let (_, wd) = mode.omegas();
    let k = (-mode.zeta * std::f64::consts::PI / (1.0 - mode.zeta * mode.zeta).sqrt()).exp();
    let weighted: Vec<f64> = undamped
        .iter()
        .enumerate()
        .map(|(i, a)| a * k.powi(i as i32))
        .collect();
    let sum: f64 = weighted.iter().sum();
    weighted
        .iter()
        .enumerate()
        .map(|(i, a)| Impulse {
            t: i as f64 * std::f64::consts::PI / wd,
            amplitude: a / sum,
        })
        .collect()
}

/// Impulses on the sample grid: each split linearly between the samples either side of it.
fn on_grid(impulses: &[Impulse], dt: f64) -> Vec<(usize, f64)> {
    let split: Vec<(usize, f64)> = impulses
        .iter()
        .flat_map(|i| {
            let exact = i.t / dt;
            let n = (exact + 1e-9).floor();
            let frac = (exact - n).max(0.0);
            let n = n as usize;
            [(n, i.amplitude * (1.0 - frac)), (n + 1, i.amplitude * frac)]
        })
        .filter(|&(_, a)| a != 0.0)
        .collect();
    convolve(&[(0, 1.0)], &split)
}

/// The single-mode shaper of `params.method` on the sample grid.
pub fn mode_shaper(mode: Mode, params: &ShaperParams, dt: f64) -> Vec<(usize, f64)> {
    match params.method {
        ShaperMethod::Zv => zv_sampled(mode, dt),
        method => on_grid(&robust_continuous(mode, method, params.tolerance), dt),
    }
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
        .map(|&m| mode_shaper(m, params, dt))
        .fold(vec![(0, 1.0)], |acc, s| convolve(&acc, &s))
}

/// The past inputs of a shaper: a ring buffer sized once, newest at `head` while a tick
/// reads it. Shared by the fixed shaper and the adaptive one, whose tap sets all read one
/// history (so a retuned shaper's output is valid from its first tick).
#[derive(Debug, Clone)]
pub struct DelayLine {
    buf: Vec<f64>,
    head: usize,
}

impl DelayLine {
    /// A line long enough for delays of up to `max_delay` samples.
    pub fn new(max_delay: usize) -> Self {
        Self {
            buf: vec![0.0; max_delay + 1],
            head: 0,
        }
    }

    /// Stores this tick's input.
    #[inline]
    pub fn push(&mut self, r: f64) {
        self.buf[self.head] = r;
    }

    /// Σ aᵢ·r[k − dᵢ] over `taps` (delay in samples, amplitude) for this tick.
    #[inline]
    pub fn sum(&self, taps: &[(usize, f64)]) -> f64 {
        let len = self.buf.len();
        let mut out = 0.0;
        for &(d, a) in taps {
            out += a * self.buf[(self.head + len - d) % len];
        }
        out
    }

    /// Ends the tick.
    #[inline]
    pub fn advance(&mut self) {
        self.head = (self.head + 1) % self.buf.len();
    }

    pub fn reset(&mut self) {
        self.buf.fill(0.0);
        self.head = 0;
    }
}

impl LinearState for DelayLine {
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

/// The shaper running on a reference signal.
#[derive(Debug, Clone)]
pub struct Shaper {
    taps: Vec<(usize, f64)>,
    line: DelayLine,
}

impl Shaper {
    pub fn new(params: &ShaperParams, dt: f64) -> Self {
        let taps = design(params, dt);
        let line = DelayLine::new(taps.last().map_or(0, |t| t.0));
        Self { taps, line }
    }

    /// (delay in samples, amplitude) of each impulse.
    pub fn taps(&self) -> &[(usize, f64)] {
        &self.taps
    }

    /// The delay the shaper adds: the time of its last impulse (s).
    pub fn duration(&self, dt: f64) -> f64 {
        self.taps.last().map_or(0.0, |t| t.0 as f64 * dt)
    }

    #[inline]
    pub fn step(&mut self, r: f64) -> f64 {
        self.line.push(r);
        let out = self.line.sum(&self.taps);
        self.line.advance();
        out
    }

    pub fn reset(&mut self) {
        self.line.reset();
    }
}

impl LinearState for Shaper {
    fn state_len(&self) -> usize {
        self.line.state_len()
    }
    fn read_state(&self, out: &mut [f64]) {
        self.line.read_state(out);
    }
    fn write_state(&mut self, s: &[f64]) {
        self.line.write_state(s);
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

    /// Percentage residual vibration (Singer & Seering) of a mode (ω, ζ) after a sequence of
    /// impulses (delay s, amplitude), written here apart from the module's own formula:
    /// V = e^{−ζωt_N}·|Σ Aᵢ e^{(ζω + jω_d)tᵢ}|.
    fn percentage_vibration(taps: &[(f64, f64)], w: f64, zeta: f64) -> f64 {
        let s = nalgebra::Complex::new(zeta * w, w * (1.0 - zeta * zeta).sqrt());
        let t_n = taps.iter().map(|t| t.0).fold(0.0, f64::max);
        let sum: nalgebra::Complex<f64> = taps.iter().map(|&(t, a)| (s * t).exp() * a).sum();
        (-zeta * w * t_n).exp() * sum.norm()
    }

    fn grid_taps(method: ShaperMethod) -> (ShaperParams, Vec<(f64, f64)>) {
        let p = ShaperParams::between_modes(method);
        let taps = design(&p, DT)
            .iter()
            .map(|&(d, a)| (d as f64 * DT, a))
            .collect();
        (p, taps)
    }

    /// Largest residual over ω/ω_m in [lo, hi], at the design damping.
    fn worst_in(taps: &[(f64, f64)], m: Mode, lo: f64, hi: f64) -> f64 {
        let (w, _) = m.omegas();
        (0..=400)
            .map(|i| lo + (hi - lo) * i as f64 / 400.0)
            .map(|r| percentage_vibration(taps, r * w, m.zeta))
            .fold(0.0, f64::max)
    }

    #[test]
    fn robust_shapers_stay_within_tolerance_over_their_insensitivity_bands() {
        // Bands at 5 % from the literature (Singhose et al.: insensitivity ZVD ≈ 0.28,
        // EI ≈ 0.40, two-hump EI ≈ 0.73 of the mode frequency), centred on the mode.
        for (method, half_band) in [
            (ShaperMethod::Zvd, 0.14),
            (ShaperMethod::Ei, 0.20),
            (ShaperMethod::TwoHumpEi, 0.36),
        ] {
            let (p, taps) = grid_taps(method);
            let m = p.modes[0];
            let worst = worst_in(&taps, m, 1.0 - half_band, 1.0 + half_band);
            assert!(worst <= p.tolerance + 1e-3, "{method:?}: {worst}");
            let sum: f64 = taps.iter().map(|t| t.1).sum();
            assert!((sum - 1.0).abs() < 1e-12, "{method:?}: unit gain");
            assert!(
                taps.iter().all(|t| t.1 > 0.0),
                "{method:?}: positive impulses"
            );
        }
        // ZV cancels its mode exactly but not over ZVD's band; the EI allows the tolerance
        // at the mode itself.
        let (_, zv) = grid_taps(ShaperMethod::Zv);
        let m = ShaperParams::between_modes(ShaperMethod::Zv).modes[0];
        assert!(worst_in(&zv, m, 1.0, 1.0) < 1e-12);
        assert!(worst_in(&zv, m, 0.86, 1.14) > 0.2);
        let (_, ei) = grid_taps(ShaperMethod::Ei);
        assert!(worst_in(&ei, m, 1.0, 1.0) > 0.02);
    }

    #[test]
    fn robust_shapers_cost_delay_a_half_period_at_a_time() {
        let m = ShaperParams::between_modes(ShaperMethod::Zv).modes[0];
        let (_, wd) = m.omegas();
        let half = std::f64::consts::PI / wd;
        for (method, halves) in [
            (ShaperMethod::Zv, 1.0),
            (ShaperMethod::Zvd, 2.0),
            (ShaperMethod::Ei, 2.0),
            (ShaperMethod::TwoHumpEi, 3.0),
        ] {
            let s = Shaper::new(&ShaperParams::between_modes(method), DT);
            let d = s.duration(DT);
            assert!(
                d >= halves * half - 1e-12 && d <= halves * half + DT + 1e-12,
                "{method:?}: {d} vs {}",
                halves * half
            );
        }
    }

    #[test]
    fn per_mode_robust_shapers_cancel_both_structure_modes() {
        for method in [ShaperMethod::Zvd, ShaperMethod::TwoHumpEi] {
            let p = ShaperParams {
                method,
                ..ShaperParams::default()
            };
            let taps: Vec<(f64, f64)> = design(&p, DT)
                .iter()
                .map(|&(d, a)| (d as f64 * DT, a))
                .collect();
            for m in &p.modes {
                // Only the grid split separates these from exact zeros.
                let (w, _) = m.omegas();
                let r = percentage_vibration(&taps, w, m.zeta);
                assert!(r < 1e-3, "{method:?} at {} Hz: {r}", m.f_hz);
            }
        }
    }
}
