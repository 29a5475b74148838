//! The feedthrough loop opened: its loop gain on the unit circle, the Nyquist verdict and
//! the largest stable K_BF from the frequency response.
//!
//! Opened at the cylinder reference, the loop maps r_c to the hand motion h it causes; closed,
//! r_c = −K_BF·h, so the closed loop's characteristic polynomial is det(zI − A)·(1 + K_BF·G(z))
//! with G = h/r_c read off `ClosedLoop::tick` (driven by a reference, the feedthrough
//! computed but not fed back). With P open-loop eigenvalues outside the unit circle, the
//! closed loop has Z = P − N outside, N the counter-clockwise encirclements of −1 by
//! L = K_BF·G(e^{jωT}) as ω goes once round the circle (the argument principle on |z| = 1).
//! N is counted exactly from where G crosses the negative real axis (each crossing found by
//! bisection): a crossing at G = x encircles −1/K for every K > −1/x, so the same crossings
//! give the verdict at any K and the largest stable K_BF, min(−1/x), the first K at which a
//! closed-loop pole reaches the unit circle.
//!
//! The shaper is a pure FIR in series at the loop's input, S(z) = Σ aᵢ z^{−dᵢ}: the loop is
//! split into S, evaluated exactly as the polynomial, and the rest of the loop (the same
//! PID on the same rig), read off the running code with the shaper left out. The delay
//! line's ~210 states then never enter a matrix: this is what makes the robustness map of
//! the shaper designs fast, and it agrees with the eigenvalues of the whole sampled loop
//! (tested).

use nalgebra::Complex;
use serde::{Deserialize, Serialize};

use super::linear_setup;
use super::state_space::{StateSpace, probe};
use crate::closed_loop::{ClosedLoop, Drive, LoopSetup};
use crate::compensator::{Compensator, CompensatorSpec, Prefilter};
use crate::error::DesignError;
use crate::linalg::eigenvalues;
use crate::params::{MAX_KBF, PlantParams, check};

/// The loop with the feedthrough opened at the cylinder reference.
#[derive(Debug, Clone)]
pub struct OpenLoop {
    /// The shaper's impulses (delay in ticks, amplitude); [(0, 1)] for other designs.
    fir: Vec<(usize, f64)>,
    /// r_c (after the shaper) → h.
    rest: StateSpace,
    /// Open-loop eigenvalues on or outside the unit circle.
    unstable: usize,
    dt: f64,
}

/// The parts [`OpenLoop`] is built from: the shaper's impulses and the loop without them.
#[derive(Debug, Clone)]
pub struct LoopParts {
    fir: Vec<(usize, f64)>,
    rest: ClosedLoop,
    dt: f64,
}

impl LoopParts {
    /// Splits the setup's loop as the analysis linearizes it (station on, no noise, no
    /// dead-band).
    pub fn new(setup: &LoopSetup) -> Result<Self, DesignError> {
        let lin = linear_setup(setup);
        let dt = lin.loop_params.dt;
        let fir = match Compensator::build(&lin.compensator, &lin.plant, dt)? {
            Compensator::Pid {
                pre: Prefilter::Shaper(s),
                ..
            } => s.taps().to_vec(),
            _ => vec![(0, 1.0)],
        };
        let compensator = match &lin.compensator {
            CompensatorSpec::PidShaper { pid, .. } => CompensatorSpec::Pid { pid: *pid },
            other => other.clone(),
        };
        let rest = ClosedLoop::new(&LoopSetup { compensator, ..lin }, 0)?;
        Ok(Self { fir, rest, dt })
    }

    /// The open loop on `rig` (the design kept as made for the setup's plant).
    pub fn on_rig(&self, rig: PlantParams) -> Result<OpenLoop, DesignError> {
        OpenLoop::read_off(self.fir.clone(), self.rest.with_rig(rig, 0)?, self.dt)
    }
}

/// The Nyquist view of one design at one K_BF.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Nyquist {
    pub kbf: f64,
    /// L(e^{jωT}) = K_BF·G at these frequencies (0 up to where |L| could still reach −1 for
    /// K_BF up to the analysis limit; the curve's mirror image is the negative frequencies).
    pub freqs_hz: Vec<f64>,
    pub re: Vec<f64>,
    pub im: Vec<f64>,
    /// Open-loop eigenvalues outside the unit circle (the loop without feedthrough).
    pub open_loop_unstable: usize,
    /// Counter-clockwise encirclements of −1 over the whole circle of frequencies.
    pub encirclements: i64,
    /// Closed-loop poles outside the unit circle: open-loop unstable − encirclements.
    pub closed_loop_unstable: i64,
    pub stable: bool,
    /// Largest K_BF with the loop stable for every smaller one (null: stable up to the
    /// analysis limit), from the negative-real-axis crossings.
    pub max_stable_kbf: Option<f64>,
}

/// A crossing of the negative real axis by G at θ ∈ (0, π).
#[derive(Debug, Clone, Copy)]
struct Crossing {
    re: f64,
    /// +1 if Im G goes from negative to positive as θ increases.
    dir: i64,
}

/// G on the upper half of the unit circle, as far as it matters for K ≤ the sweep's limit.
#[derive(Debug, Clone)]
pub struct Sweep {
    /// (θ, G(e^{jθ})) from θ = 0, spaced so that G's phase moves less than 0.25 rad.
    samples: Vec<(f64, Complex<f64>)>,
    crossings: Vec<Crossing>,
    /// G(1), real.
    at_dc: f64,
    /// Direction of the crossing at θ = 0 (sign of Im G just above it).
    dir_dc: i64,
    /// G(−1) and its crossing direction, when the sweep reached θ = π.
    at_nyquist: Option<(f64, i64)>,
    unstable: usize,
}

impl OpenLoop {
    pub fn new(setup: &LoopSetup) -> Result<Self, DesignError> {
        let parts = LoopParts::new(setup)?;
        OpenLoop::read_off(parts.fir, parts.rest, parts.dt)
    }

    fn read_off(
        fir: Vec<(usize, f64)>,
        mut rest: ClosedLoop,
        dt: f64,
    ) -> Result<Self, DesignError> {
        let rest = probe(&mut rest, 1, 1, |lp, u, y| {
            y[0] = lp.tick(Drive::Reference(u[0])).feedthrough;
        });
        let unstable = eigenvalues(rest.a())?
            .iter()
            .filter(|z| z.norm() >= 1.0 - 1e-12)
            .count();
        Ok(Self {
            fir,
            rest,
            unstable,
            dt,
        })
    }

    /// G(e^{jθ}): hand motion per cylinder reference, the loop gain per unit K_BF.
    pub fn response(&self, theta: f64) -> Complex<f64> {
        let s: Complex<f64> = self
            .fir
            .iter()
            .map(|&(d, a)| Complex::from_polar(a, -theta * d as f64))
            .sum();
        s * self.rest.response(0, 0, theta)
    }

    /// Samples G and finds its negative-real-axis crossings that matter for K ≤ `k_limit`.
    pub fn sweep(&self, k_limit: f64) -> Sweep {
        let pi = std::f64::consts::PI;
        // Above θ_top, |K·G| < 1/4 for every K ≤ k_limit (|S| ≤ Σ|aᵢ|): no crossing left of
        // −1/K there. Found on a log grid of the rest of the loop, doubled for safety.
        let fir_gain: f64 = self.fir.iter().map(|t| t.1.abs()).sum();
        let mut top = 0.0_f64;
        for i in 0..400 {
            let theta = 1e-5 * (pi / 1e-5).powf(i as f64 / 399.0);
            if self.rest.response(0, 0, theta).norm() * fir_gain * k_limit >= 0.25 {
                top = theta;
            }
        }
        let top = (2.0 * top).min(pi);
        let g = |t: f64| self.response(t);
        let step = 0.5 * self.dt; // 0.5 rad/s
        let n = (top / step).ceil().max(1.0) as usize;
        let mut samples = vec![(0.0, g(0.0))];
        for i in 1..=n {
            let theta = top * i as f64 / n as f64;
            let prev = *samples.last().expect("starts with θ = 0");
            refine(&g, prev, (theta, g(theta)), 0, &mut samples);
        }
        let mut crossings = Vec::new();
        for w in samples.windows(2) {
            let ((ta, ga), (tb, gb)) = (w[0], w[1]);
            if ta == 0.0 || (ga.im < 0.0) == (gb.im < 0.0) || ga.im == 0.0 {
                continue;
            }
            let t = ga.im / (ga.im - gb.im);
            let re_guess = ga.re + t * (gb.re - ga.re);
            if re_guess * k_limit >= -0.5 {
                continue;
            }
            let (mut lo, mut hi) = (ta, tb);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                if (g(mid).im < 0.0) == (ga.im < 0.0) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            crossings.push(Crossing {
                re: g(0.5 * (lo + hi)).re,
                dir: if gb.im > ga.im { 1 } else { -1 },
            });
        }
        let sign = |v: f64| if v > 0.0 { 1 } else { -1 };
        let dir_dc = samples.get(1).map_or(1, |s| sign(s.1.im));
        let at_nyquist = (top >= pi).then(|| {
            let before = samples[samples.len().saturating_sub(2)].1;
            (g(pi).re, -sign(before.im))
        });
        Sweep {
            at_dc: samples[0].1.re,
            dir_dc,
            at_nyquist,
            samples,
            crossings,
            unstable: self.unstable,
        }
    }

    /// Largest K ≤ `limit` with the loop stable on all of [0, K]; `None` when stable on all
    /// of it (as [`super::LinearizedLoop::max_stable_up_to`]).
    pub fn max_stable_up_to(&self, limit: f64) -> Option<f64> {
        self.sweep(limit).max_stable_up_to(limit)
    }

    /// The Nyquist verdict at K.
    pub fn is_stable(&self, k: f64) -> bool {
        self.sweep(k).closed_loop_unstable(k) == 0
    }

    /// The Nyquist view at `k_bf`, the curve sampled for plotting.
    pub fn nyquist(&self, k_bf: f64) -> Result<Nyquist, DesignError> {
        check("kbf", k_bf, 0.0, MAX_KBF)?;
        let sweep = self.sweep(MAX_KBF);
        let stride = sweep.samples.len().div_ceil(2000).max(1);
        let shown: Vec<_> = sweep
            .samples
            .iter()
            .step_by(stride)
            .chain(sweep.samples.last())
            .collect();
        let hz = 1.0 / (2.0 * std::f64::consts::PI * self.dt);
        let z = sweep.closed_loop_unstable(k_bf);
        Ok(Nyquist {
            kbf: k_bf,
            freqs_hz: shown.iter().map(|s| s.0 * hz).collect(),
            re: shown.iter().map(|s| k_bf * s.1.re).collect(),
            im: shown.iter().map(|s| k_bf * s.1.im).collect(),
            open_loop_unstable: self.unstable,
            encirclements: sweep.encirclements(k_bf),
            closed_loop_unstable: z,
            stable: z == 0,
            max_stable_kbf: sweep.max_stable_up_to(MAX_KBF),
        })
    }
}

/// Appends samples up to `b`, halving the interval while G's phase moves by more than
/// 0.25 rad across it (so no crossing of the real axis falls between two samples unseen).
fn refine(
    g: &impl Fn(f64) -> Complex<f64>,
    a: (f64, Complex<f64>),
    b: (f64, Complex<f64>),
    depth: u32,
    out: &mut Vec<(f64, Complex<f64>)>,
) {
    let turn = (b.1 * a.1.conj()).arg().abs();
    if turn > 0.25 && depth < 24 {
        let t = 0.5 * (a.0 + b.0);
        let mid = (t, g(t));
        refine(g, a, mid, depth + 1, out);
        refine(g, mid, b, depth + 1, out);
    } else {
        out.push(b);
    }
}

impl Sweep {
    /// Counter-clockwise encirclements of −1 by K·G over the whole circle: of −1/K by G,
    /// counted as signed crossings of the ray left of −1/K (the upper half's crossings
    /// twice, by symmetry; those at θ = 0 and π once).
    pub fn encirclements(&self, k: f64) -> i64 {
        if k <= 0.0 {
            return 0;
        }
        let p = -1.0 / k;
        let mut ccw: i64 = self
            .crossings
            .iter()
            .filter(|c| c.re < p)
            .map(|c| -2 * c.dir)
            .sum();
        if self.at_dc < p {
            ccw -= self.dir_dc;
        }
        if let Some((re, dir)) = self.at_nyquist
            && re < p
        {
            ccw -= dir;
        }
        ccw
    }

    pub fn closed_loop_unstable(&self, k: f64) -> i64 {
        self.unstable as i64 - self.encirclements(k)
    }

    pub fn max_stable_up_to(&self, limit: f64) -> Option<f64> {
        if self.unstable > 0 {
            return Some(0.0);
        }
        let first = self
            .crossings
            .iter()
            .map(|c| c.re)
            .chain([self.at_dc])
            .chain(self.at_nyquist.map(|n| n.0))
            .filter(|&re| re < 0.0)
            .map(|re| -1.0 / re)
            .fold(f64::INFINITY, f64::min);
        (first <= limit).then_some(first)
    }
}
