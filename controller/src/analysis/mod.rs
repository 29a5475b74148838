//! Stability analysis of each compensator with the feedthrough loop closed.
//!
//! The closed loop is analysed in discrete time at the loop rate, exactly as it runs: its
//! one-tick state map is read off the real `ClosedLoop::tick` by probing each state (the
//! loop is linear while nothing saturates, and noise and dead-band are switched off). The
//! shaper's delays are then just more states, so the verdict — all eigenvalues strictly
//! inside the unit circle — is sound for them too. Poles are reported in rad/s as
//! s = ln(z)/dt (exact for the plant's zero-order-hold modes).
//!
//! K_BF enters the map affinely (r_c = K_BF·(p_h − h)), so A(K) = A₀ + K·(A₁ − A₀) is read
//! once and the largest stable K_BF is found by scanning and bisecting on K.
//!
//! Files: `design_view`: `analyze --model design|implemented` — the LQR loops' continuous design
//! model (ideal measurements, so the observer poles are exactly the designed ones) beside the
//! sampled loop, every pole difference attributed to the element that makes it (rate filter,
//! accelerometer filters, sampling) by adding them one at a time; for the PID family the two views
//! are one. `robustness`: the design fixed on the nominal plant and run on perturbed rigs
//! (`ClosedLoop::with_rig`) — the K_H × structure-frequency map of the largest stable K_BF (K_H
//! only scales the loop gain, so it divides) and the Monte-Carlo pass rate. `state_space`: any
//! block's state-space map probed off its `step` (`probe`), evaluated on the unit circle after one
//! Hessenberg reduction (O(n²) a frequency); the stability analysis, `frequency` and `nyquist` all
//! read their matrices here. `frequency`: Bode data of the rig's parts, the body, each compensator
//! and closed loop (`bdft-controller frequency`). `personal`: a design tuned to one person's body —
//! the LQR's α (largest) or the cab feedback's β (smallest) within a band around the study's,
//! keeping the gate's margin by the same `margin` (bisection: the margin is monotone in each weight
//! in every loop we have), and stable off the machine. `nyquist`: the feedthrough loop opened at
//! r_c (G = h/r_c off `tick`), the shaper split off as an exact FIR Σaᵢz^{−dᵢ} in series with the
//! small rest; the largest stable K_BF is min(−1/x) over G's negative-real-axis crossings x, the
//! verdict Z = P − N from the same crossings. The shaper designs' margins (analyze, robustness)
//! come from here, the others' from eigenvalues.
//!
//! `adaptive_gate`: an adaptive design's stability gate — its design frozen at every ratio of a
//! grid over its range, each analysed as above. Everywhere else an adaptive design is analysed
//! frozen at r = 1 (`linear_setup`).
//!
//! *Invariant:* the Nyquist verdict equals the sampled loop's eigenvalue verdict (tested per
//! design, below and above each margin, and on robustness map cells).

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::closed_loop::{ClosedLoop, Drive, LoopSetup};
use crate::error::DesignError;
use crate::linalg::{eigenvalues, spectral_radius};
use crate::params::{MAX_KBF, Seat, check};
pub use adaptive_gate::{FrozenVerdict, GATE_POINTS, adaptive_gate, gate_ratios};

mod adaptive_gate;
pub mod design_view;
pub mod frequency;
pub mod nyquist;
pub mod personal;
pub mod robustness;
pub mod state_space;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompensatorAnalysis {
    pub name: String,
    pub stable: bool,
    /// Largest closed-loop eigenvalue magnitude at the loop rate (< 1 is stable).
    pub spectral_radius: f64,
    /// Largest K_BF such that the loop is stable for every K in [0, K_BF]; `null` when it is
    /// stable over the whole searched range [0, MAX_KBF]; 0 when unstable even without
    /// feedthrough.
    pub max_stable_kbf: Option<f64>,
    /// Closed-loop poles [re, im] in rad/s; empty for loops with pure delays (the shaper),
    /// whose delay-line eigenvalues are not poles of a rational system.
    pub poles: Vec<[f64; 2]>,
    /// The delay the compensator's input shaper adds to the reference (its last impulse,
    /// s); absent for designs without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub added_delay_s: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnalysisReport {
    pub kbf: f64,
    /// The view `compensators` reports.
    pub model: design_view::Model,
    pub compensators: Vec<CompensatorAnalysis>,
    /// Both views of each compensator side by side, each difference with its cause.
    pub comparison: Vec<design_view::ModelComparison>,
}

/// Which time the loop's matrix maps: one tick of the sampled loop (the implemented view), or
/// the state derivative of a continuous-time loop (the design view, [`design_view`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Domain {
    Sampled,
    Continuous,
}

/// The linear map of a closed loop, affine in K_BF.
#[derive(Debug, Clone)]
pub struct LinearizedLoop {
    a0: DMatrix<f64>,
    a1: DMatrix<f64>,
    dt: f64,
    domain: Domain,
    has_delays: bool,
    added_delay_s: Option<f64>,
}

impl LinearizedLoop {
    /// Reads the loop's map off `tick` at the station "on" (feedthrough closed).
    pub fn new(setup: &LoopSetup) -> Result<Self, DesignError> {
        let mut lp = ClosedLoop::new(&linear_setup(setup), 0)?;
        Ok(Self::read_off(&mut lp, setup.loop_params.dt))
    }

    /// Reads the map off a loop built from a [`linear_setup`].
    pub fn read_off(lp: &mut ClosedLoop, dt: f64) -> Self {
        let a0 = probe(lp, 0.0);
        let a1 = probe(lp, 1.0);
        Self {
            a1: a1 - &a0,
            a0,
            dt,
            domain: Domain::Sampled,
            has_delays: lp.compensator().has_delays(),
            added_delay_s: lp.compensator().shaper_duration(dt),
        }
    }

    /// A continuous-time loop ẋ = (A₀ + K_BF·A₁)x; `dt` is the loop period its spectral
    /// radius is reported at.
    pub fn continuous(a0: DMatrix<f64>, a1: DMatrix<f64>, dt: f64) -> Self {
        Self {
            a0,
            a1,
            dt,
            domain: Domain::Continuous,
            has_delays: false,
            added_delay_s: None,
        }
    }

    pub fn domain(&self) -> Domain {
        self.domain
    }

    pub fn matrix(&self, k_bf: f64) -> DMatrix<f64> {
        &self.a0 + &self.a1 * k_bf
    }

    /// Largest eigenvalue magnitude over one loop period: for a continuous loop that of its
    /// exact discretization, e^{max Re(s)·dt}, so both views read the same way.
    pub fn spectral_radius(&self, k_bf: f64) -> Result<f64, DesignError> {
        let m = self.matrix(k_bf);
        match self.domain {
            Domain::Sampled => spectral_radius(&m),
            Domain::Continuous => Ok(eigenvalues(&m)?
                .iter()
                .map(|s| (s.re * self.dt).exp())
                .fold(0.0, f64::max)),
        }
    }

    pub fn is_stable(&self, k_bf: f64) -> Result<bool, DesignError> {
        Ok(self.spectral_radius(k_bf)? < 1.0 - 1e-12)
    }

    /// Closed-loop poles in rad/s, sorted by real then imaginary part.
    pub fn poles(&self, k_bf: f64) -> Result<Vec<[f64; 2]>, DesignError> {
        let mut poles: Vec<[f64; 2]> = eigenvalues(&self.matrix(k_bf))?
            .into_iter()
            .filter_map(|z| match self.domain {
                Domain::Sampled => (z.norm() > 1e-9).then(|| z.ln() / self.dt),
                Domain::Continuous => Some(z),
            })
            .map(|s| [s.re, s.im])
            .collect();
        poles.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
        Ok(poles)
    }

    /// Largest K with the loop stable on all of [0, K] (see [`CompensatorAnalysis`]), from
    /// eigenvalues.
    pub fn max_stable_kbf(&self) -> Result<Option<f64>, DesignError> {
        self.max_stable_up_to(MAX_KBF)
    }

    /// The same margin by the quickest sound route for `setup`, the setup this loop was
    /// linearized from: the shaper's loop from its frequency response (the FIR split off,
    /// `nyquist`) — the same first loss of stability without ~100 eigenvalue problems of
    /// ~210 states —, every other loop from eigenvalues.
    pub fn margin(&self, setup: &LoopSetup) -> Result<Option<f64>, DesignError> {
        if self.has_delays {
            Ok(nyquist::OpenLoop::new(setup)?.max_stable_up_to(MAX_KBF))
        } else {
            self.max_stable_kbf()
        }
    }

    /// Largest K ≤ `limit` with the loop stable on all of [0, K]; `None` when stable on all
    /// of [0, limit].
    pub fn max_stable_up_to(&self, limit: f64) -> Result<Option<f64>, DesignError> {
        if !self.is_stable(0.0)? {
            return Ok(Some(0.0));
        }
        // Scan on a grid fine enough not to step over a stability window of the loops we
        // have (their margins are 0.3–4), then bisect the first loss of stability.
        let grid = 0.05;
        let mut lo = 0.0;
        let mut hi = None;
        while lo < limit {
            let k = (lo + grid).min(limit);
            if self.is_stable(k)? {
                lo = k;
            } else {
                hi = Some(k);
                break;
            }
        }
        let Some(mut hi) = hi else {
            return Ok(None);
        };
        while hi - lo > 1e-5 {
            let mid = 0.5 * (lo + hi);
            if self.is_stable(mid)? {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Ok(Some(lo))
    }
}

/// The setup as the analysis linearizes it: station on (feedthrough closed), no
/// accelerometer noise, no dead-band, and an adaptive design frozen at r = 1 — its fixed
/// design, what it runs while not confident (the estimator and the schedule are not
/// linear; [`adaptive_gate`] judges the design frozen at every r of its range).
pub fn linear_setup(setup: &LoopSetup) -> LoopSetup {
    let mut setup = setup.clone();
    setup.compensator = setup.compensator.frozen_at(1.0);
    setup.seat = Seat::On;
    setup.plant = linear_rig(setup.plant);
    setup
}

/// A rig without its nonlinear and random parts.
pub fn linear_rig(mut rig: crate::params::PlantParams) -> crate::params::PlantParams {
    rig.accel_noise_std = 0.0;
    rig.engine_vibration_rms = 0.0;
    rig.dead_band = 0.0;
    rig
}

/// The one-tick map at `k_bf` with no input ([`state_space::probe_matrices`]).
fn probe(lp: &mut ClosedLoop, k_bf: f64) -> DMatrix<f64> {
    lp.set_k_bf(k_bf);
    let (a, ..) = state_space::probe_matrices(lp, 0, 0, |lp, _, _| {
        lp.tick(Drive::Hand(0.0));
    });
    lp.reset();
    a
}

/// Analyses one compensator at the setup's K_BF, as implemented (the sampled loop).
pub fn analyze(setup: &LoopSetup) -> Result<CompensatorAnalysis, DesignError> {
    check("kbf", setup.loop_params.k_bf, 0.0, MAX_KBF)?;
    analyze_loop(setup, &LinearizedLoop::new(setup)?)
}

/// Verdict, margin and poles of one linearized loop at the setup's K_BF.
pub fn analyze_loop(
    setup: &LoopSetup,
    lin: &LinearizedLoop,
) -> Result<CompensatorAnalysis, DesignError> {
    let k_bf = setup.loop_params.k_bf;
    check("kbf", k_bf, 0.0, MAX_KBF)?;
    let rho = lin.spectral_radius(k_bf)?;
    Ok(CompensatorAnalysis {
        name: setup.compensator.kind().name().to_string(),
        stable: rho < 1.0 - 1e-12,
        spectral_radius: rho,
        max_stable_kbf: lin.margin(setup)?,
        poles: if lin.has_delays {
            Vec::new()
        } else {
            lin.poles(k_bf)?
        },
        added_delay_s: lin.added_delay_s,
    })
}
