//! The design-model view: each loop as the textbook structure its design was computed on,
//! beside the loop as implemented, with the cause of every difference.
//!
//! LQR designs: the design model is continuous and has ideal measurements — the inner
//! velocity loop sees the true ẏ and the observer the true [y; cab state] — so the
//! estimation error obeys ė = (A − LC)e whatever the feedthrough does (separation): the
//! observer poles sit exactly where they were placed. The implemented loop differs by three
//! elements, added one at a time in continuous models so each difference is attributed to
//! the element that makes it: the rate filter (ẏ differentiated from y through a low-pass),
//! the accelerometer's high-pass and leaky integrator (cab-velocity designs only; the
//! observer is fed a filtered signal its model does not contain), and sampling (the sampled
//! loop read off the running code, [`LinearizedLoop::new`]). Each pole is followed from
//! model to model by nearest match; its cause is the element that moved it most.
//!
//! PID designs estimate nothing (no observer, no model inside the compensator): the PID,
//! notch and shaper were designed as the filters that run — the notch pre-warped, the
//! shaper solved on the sample grid — so their design view is the implemented loop and
//! lists no differences.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::{CompensatorAnalysis, LinearizedLoop, analyze_loop};
use crate::closed_loop::LoopSetup;
use crate::compensator::{CabOutput, Compensator, Lqr};
use crate::error::DesignError;
use crate::model::{continuous_plant, idx};
use crate::params::BodyModel;

/// Which loop `analyze` reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    /// The textbook structure with ideal measurements (continuous time).
    Design,
    /// The sampled loop as it runs.
    Implemented,
}

impl Model {
    pub fn name(self) -> &'static str {
        match self {
            Self::Design => "design",
            Self::Implemented => "implemented",
        }
    }
}

impl std::str::FromStr for Model {
    type Err = crate::error::ParamError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        [Self::Design, Self::Implemented]
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| crate::error::ParamError::Invalid {
                name: "model",
                message: format!("unknown model {s:?}; valid: design, implemented"),
            })
    }
}

/// One pole that differs between the views.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoleDifference {
    /// [re, im] rad/s in the design view; `null` for a pole only the implementation has.
    pub design: Option<[f64; 2]>,
    /// [re, im] rad/s in the implemented view; `null` if it has no counterpart there.
    pub implemented: Option<[f64; 2]>,
    /// Distance moved (rad/s); 0 for an added pole.
    pub moved: f64,
    /// The implemented element that moves (or adds) it.
    pub cause: String,
}

/// Both views of one compensator, side by side.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelComparison {
    pub name: String,
    pub design: CompensatorAnalysis,
    pub implemented: CompensatorAnalysis,
    /// Why the design view's structure holds or not for this design.
    pub note: String,
    pub differences: Vec<PoleDifference>,
}

/// The continuous design-model loop of `setup`, or `None` for designs whose design view is
/// the implemented loop (the PID family).
pub fn design_loop(setup: &LoopSetup) -> Result<Option<LinearizedLoop>, DesignError> {
    let Some(lqr) = lqr_of(setup)? else {
        return Ok(None);
    };
    Ok(Some(lqr_continuous(&lqr, setup, Elements::NONE)))
}

/// Both views of one compensator at the setup's K_BF, and the differences explained.
pub fn compare(setup: &LoopSetup) -> Result<ModelComparison, DesignError> {
    let implemented_loop = LinearizedLoop::new(setup)?;
    let implemented = analyze_loop(setup, &implemented_loop)?;
    let name = implemented.name.clone();
    let Some(lqr) = lqr_of(setup)? else {
        return Ok(ModelComparison {
            name,
            design: implemented.clone(),
            implemented,
            note: "no observer and no model inside the compensator: the PID, notch and shaper \
                   were designed as the sampled filters that run, so the design view is the \
                   implemented loop"
                .into(),
            differences: Vec::new(),
        });
    };
    let k_bf = setup.loop_params.k_bf;
    let p = lqr.params();
    let mut stages = vec![(String::new(), lqr_continuous(&lqr, setup, Elements::NONE))];
    stages.push((
        format!(
            "rate filter: ẏ differentiated from y through a low-pass at {:.0} rad/s (the design \
             model has the true ẏ)",
            p.rate_filter_w
        ),
        lqr_continuous(
            &lqr,
            setup,
            Elements {
                rate_filter: true,
                cab_filters: false,
            },
        ),
    ));
    if p.cab_output == CabOutput::Velocity {
        stages.push((
            format!(
                "accelerometer high-pass ({} rad/s) and leaky integrator ({} rad/s): a filtered \
                 cab velocity the observer's model does not contain",
                p.cab_highpass_w, p.cab_leak_w
            ),
            lqr_continuous(&lqr, setup, Elements::ALL),
        ));
    }
    let mut pole_sets = stages
        .iter()
        .map(|(_, l)| l.poles(k_bf))
        .collect::<Result<Vec<_>, _>>()?;
    pole_sets.push(implemented.poles.clone());
    let mut causes: Vec<String> = stages.iter().map(|(c, _)| c.clone()).collect();
    causes.push(format!(
        "sampling at {} s (zero-order hold, Tustin filters, discretized observer)",
        setup.loop_params.dt
    ));
    let design = analyze_loop(setup, &stages[0].1)?;
    Ok(ModelComparison {
        name,
        design,
        implemented,
        note: "design view: ideal measurements of y, ẏ and the cab state, so the estimation \
               error is ė = (A − LC)e and the observer poles are those designed (separation)"
            .into(),
        differences: differences(&pole_sets, &causes),
    })
}

fn lqr_of(setup: &LoopSetup) -> Result<Option<Lqr>, DesignError> {
    // An adaptive design is analysed frozen at r = 1, as everywhere (`linear_setup`).
    let spec = setup.compensator.frozen_at(1.0);
    match Compensator::build(&spec, &setup.plant, setup.loop_params.dt)? {
        Compensator::Lqr(l) => Ok(Some(*l)),
        Compensator::Pid { .. } | Compensator::Adaptive(_) => Ok(None),
    }
}

/// Implemented elements included in a continuous model of the LQR loop.
#[derive(Debug, Clone, Copy)]
struct Elements {
    rate_filter: bool,
    cab_filters: bool,
}

impl Elements {
    const NONE: Self = Self {
        rate_filter: false,
        cab_filters: false,
    };
    const ALL: Self = Self {
        rate_filter: true,
        cab_filters: true,
    };
}

fn lqr_continuous(lqr: &Lqr, setup: &LoopSetup, el: Elements) -> LinearizedLoop {
    let a0 = lqr_matrix(lqr, setup, el, 0.0);
    let a1 = lqr_matrix(lqr, setup, el, 1.0) - &a0;
    LinearizedLoop::continuous(a0, a1, setup.loop_params.dt)
}

/// ẋ = M·x of the LQR loop closed through the feedthrough at `k_bf` (p_h = 0), states
/// [plant (7), estimate (7), rate filter (1)?, high-pass and leaky integrator (2)?, body (2)?].
fn lqr_matrix(lqr: &Lqr, setup: &LoopSetup, el: Elements, k_bf: f64) -> DMatrix<f64> {
    let d = lqr.design();
    let p = lqr.params();
    let cab_filters = el.cab_filters && p.cab_output == CabOutput::Velocity;
    let (xh, mut n) = (7, 14);
    let mut take = |present: bool, len: usize| {
        present.then(|| {
            n += len;
            n - len
        })
    };
    let rate = take(el.rate_filter, 1);
    let cab = take(cab_filters, 2);
    let body_len = match setup.body {
        BodyModel::RigidMass { .. } => 0,
        BodyModel::SingleResonance { .. } => 2,
        BodyModel::Seated { .. } => 4,
    };
    let body = take(body_len > 0, body_len);
    let e = |i: usize| {
        let mut r = DVector::zeros(n);
        r[i] = 1.0;
        r
    };
    let y = e(idx::Y);
    let y_rate = match rate {
        Some(q) => (&y - e(q)) * p.rate_filter_w,
        None => e(idx::Y_D),
    };
    let cab_meas = match (cab, p.cab_output) {
        (Some(c), _) => e(c + 1),
        (None, CabOutput::Velocity) => e(idx::XC_D),
        (None, CabOutput::Acceleration) => e(idx::XC_DD),
    };
    // A transmissibility section (2ζωs + ω²)/(s² + 2ζωs + ω²) in states b, b + 1: its output.
    let section_out = |b: usize, f_hz: f64, zeta: f64| {
        let w = 2.0 * std::f64::consts::PI * f_hz;
        e(b) * (w * w) + e(b + 1) * (2.0 * zeta * w)
    };
    let h = match (setup.body, body) {
        (BodyModel::RigidMass { k_h }, _) => e(idx::XC) * k_h,
        (BodyModel::SingleResonance { k_h, f_hz, zeta }, Some(b)) => {
            section_out(b, f_hz, zeta) * k_h
        }
        (
            BodyModel::Seated {
                k_h,
                arm_f_hz,
                arm_zeta,
                ..
            },
            Some(b),
        ) => (e(idx::XC) - section_out(b + 2, arm_f_hz, arm_zeta)) * k_h,
        (_, None) => unreachable!("body states were added"),
    };
    // u = −K(x̂ − N_x r_c), r_c = −K_BF·h.
    let kn = (&d.k * &d.nx)[(0, 0)];
    let mut u = DVector::zeros(n);
    for j in 0..7 {
        u[xh + j] = -d.k[(0, j)];
    }
    u -= &h * (kn * k_bf);
    let v = (&u - &y_rate) * lqr.inner_gain();
    let (a_plant, b_plant) = continuous_plant(&setup.plant);
    let mut m = DMatrix::zeros(n, n);
    let add_row = |m: &mut DMatrix<f64>, i: usize, row: &DVector<f64>, gain: f64| {
        for j in 0..n {
            m[(i, j)] += gain * row[j];
        }
    };
    for i in 0..7 {
        for j in 0..7 {
            m[(i, j)] = a_plant[(i, j)];
            m[(xh + i, xh + j)] = d.a[(i, j)] - (&d.l * &d.c)[(i, j)];
        }
        add_row(&mut m, i, &v, b_plant[i]);
        add_row(&mut m, xh + i, &u, d.b[(i, 0)]);
        add_row(&mut m, xh + i, &y, d.l[(i, 0)]);
        add_row(&mut m, xh + i, &cab_meas, d.l[(i, 1)]);
    }
    if let Some(q) = rate {
        // q = ω/(s + ω)·y, so ω(y − q) = ωs/(s + ω)·y, the filtered derivative.
        m[(q, q)] = -p.rate_filter_w;
        m[(q, idx::Y)] = p.rate_filter_w;
    }
    if let Some(c) = cab {
        // c₀ = a/(s + ω_h): the high-pass output is a − ω_h·c₀; c₁ leaks at ω_l.
        let (wh, wl) = (p.cab_highpass_w, p.cab_leak_w);
        m[(c, c)] = -wh;
        m[(c, idx::XC_DD)] = 1.0;
        m[(c + 1, c + 1)] = -wl;
        m[(c + 1, idx::XC_DD)] = 1.0;
        m[(c + 1, c)] = -wh;
    }
    // q̈ = −ω²q − 2ζωq̇ + input, output ω²q + 2ζωq̇.
    let section = |m: &mut DMatrix<f64>, b: usize, f_hz: f64, zeta: f64, input: &DVector<f64>| {
        let w = 2.0 * std::f64::consts::PI * f_hz;
        m[(b, b + 1)] = 1.0;
        m[(b + 1, b)] -= w * w;
        m[(b + 1, b + 1)] -= 2.0 * zeta * w;
        add_row(m, b + 1, input, 1.0);
    };
    match (body, setup.body) {
        (Some(b), BodyModel::SingleResonance { f_hz, zeta, .. }) => {
            section(&mut m, b, f_hz, zeta, &e(idx::XC));
        }
        (
            Some(b),
            BodyModel::Seated {
                torso_f_hz,
                torso_zeta,
                arm_f_hz,
                arm_zeta,
                ..
            },
        ) => {
            section(&mut m, b, torso_f_hz, torso_zeta, &e(idx::XC));
            let torso = section_out(b, torso_f_hz, torso_zeta);
            section(&mut m, b + 2, arm_f_hz, arm_zeta, &torso);
        }
        _ => {}
    }
    m
}

/// Follows each pole through the models (`poles[0]` the design view, the last the
/// implemented one; `causes[i]` is what model i adds) and lists those that move or appear.
fn differences(poles: &[Vec<[f64; 2]>], causes: &[String]) -> Vec<PoleDifference> {
    struct Track {
        start: usize,
        at: Option<[f64; 2]>,
        first: [f64; 2],
        biggest: (f64, usize),
    }
    let mut tracks: Vec<Track> = poles[0]
        .iter()
        .map(|&p| Track {
            start: 0,
            at: Some(p),
            first: p,
            biggest: (0.0, 0),
        })
        .collect();
    for (stage, next) in poles.iter().enumerate().skip(1) {
        let current: Vec<(usize, [f64; 2])> = tracks
            .iter()
            .enumerate()
            .filter_map(|(i, t)| t.at.map(|p| (i, p)))
            .collect();
        let matched = nearest_matching(&current.iter().map(|c| c.1).collect::<Vec<_>>(), next);
        let mut taken = vec![false; next.len()];
        for (k, m) in matched.iter().enumerate() {
            let t = &mut tracks[current[k].0];
            match *m {
                Some(j) => {
                    taken[j] = true;
                    let step = distance(t.at.unwrap_or(next[j]), next[j]);
                    if step > t.biggest.0 {
                        t.biggest = (step, stage);
                    }
                    t.at = Some(next[j]);
                }
                None => t.at = None,
            }
        }
        for (_, p) in next.iter().enumerate().filter(|&(j, _)| !taken[j]) {
            tracks.push(Track {
                start: stage,
                at: Some(*p),
                first: *p,
                biggest: (0.0, stage),
            });
        }
    }
    tracks
        .into_iter()
        .filter_map(|t| {
            let design = (t.start == 0).then_some(t.first);
            let moved = t.at.map_or(0.0, |p| distance(p, t.first));
            let scale = t.first[0].hypot(t.first[1]).max(1.0);
            if t.start == 0 && t.at.is_some() && moved <= 1e-6 * scale {
                return None;
            }
            let cause = if t.start > 0 {
                format!("added by the {}", causes[t.start])
            } else if t.at.is_none() {
                "no counterpart in the implemented loop".into()
            } else {
                causes[t.biggest.1].clone()
            };
            Some(PoleDifference {
                design,
                implemented: t.at,
                moved: if t.start == 0 { moved } else { 0.0 },
                cause,
            })
        })
        .collect()
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Pairs each of `from` with a distinct element of `to`, closest pairs first.
fn nearest_matching(from: &[[f64; 2]], to: &[[f64; 2]]) -> Vec<Option<usize>> {
    let mut pairs: Vec<(f64, usize, usize)> = from
        .iter()
        .enumerate()
        .flat_map(|(i, a)| {
            to.iter()
                .enumerate()
                .map(move |(j, b)| (distance(*a, *b), i, j))
        })
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = vec![None; from.len()];
    let mut used = vec![false; to.len()];
    for (_, i, j) in pairs {
        if out[i].is_none() && !used[j] {
            out[i] = Some(j);
            used[j] = true;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensator::{CompensatorKind, CompensatorSpec};
    use crate::param_set::ParamSet;
    use crate::params::{NOMINAL_KBF, Seat};

    fn setup(kind: CompensatorKind) -> LoopSetup {
        ParamSet::default().setup(kind, Seat::On, NOMINAL_KBF)
    }

    fn placed(setup: &LoopSetup) -> [f64; 7] {
        match &setup.compensator {
            CompensatorSpec::Lqr { lqr }
            | CompensatorSpec::LqrCabvel { lqr }
            | CompensatorSpec::LqrCabacc { lqr } => lqr.observer_poles,
            _ => unreachable!(),
        }
    }

    /// Distance from `p` (real) to the nearest pole, relative to |p|.
    fn nearest_relative(p: f64, poles: &[[f64; 2]]) -> f64 {
        poles
            .iter()
            .map(|q| (q[0] - p).hypot(q[1]) / p.abs())
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn the_design_view_has_the_placed_observer_poles_and_the_implemented_view_does_not() {
        for kind in [
            CompensatorKind::Lqr,
            CompensatorKind::LqrCabvel,
            CompensatorKind::LqrCabacc,
        ] {
            let s = setup(kind);
            let c = compare(&s).unwrap();
            assert_eq!(c.design.poles.len(), 14, "{kind}");
            for p in placed(&s) {
                let rel = nearest_relative(p, &c.design.poles);
                assert!(
                    rel < 1e-6,
                    "{kind}: placed {p}: nearest design pole off by {rel:e}"
                );
            }
            // As implemented at least one placed pole has moved by more than 1 %.
            let worst = placed(&s)
                .iter()
                .map(|&p| nearest_relative(p, &c.implemented.poles))
                .fold(0.0, f64::max);
            assert!(worst > 0.01, "{kind}: implemented poles stay put ({worst})");
            assert!(c.design.stable && c.implemented.stable, "{kind}");
            // Every difference is explained by one of the implemented elements.
            assert!(!c.differences.is_empty());
            for d in &c.differences {
                assert!(
                    ["rate filter", "high-pass", "sampling"]
                        .iter()
                        .any(|w| d.cause.contains(w)),
                    "{kind}: {d:?}"
                );
            }
            if kind == CompensatorKind::LqrCabacc {
                assert!(c.differences.iter().all(|d| !d.cause.contains("high-pass")));
            }
        }
    }

    #[test]
    fn the_design_loop_with_every_element_approaches_the_sampled_loop_at_low_frequency() {
        // The continuous model with all implemented elements differs from the sampled loop
        // only by sampling: same pole count, and the poles well below the 1 kHz rate (the
        // structure, the cylinder, the filters) within a few %. The observer's fast poles
        // (0.2 rad per sample) are moved by sampling by up to 25 rad/s.
        // With each body model: the seated body's four states (torso and arm) written
        // continuously here must be the sampled body's.
        for body in [BodyModel::default(), crate::model::SEATED_FOR_TESTS] {
            let mut s = setup(CompensatorKind::LqrCabvel);
            s.body = body;
            let lqr = lqr_of(&s).unwrap().unwrap();
            let cont = lqr_continuous(&lqr, &s, Elements::ALL)
                .poles(NOMINAL_KBF)
                .unwrap();
            let sampled = LinearizedLoop::new(&s).unwrap().poles(NOMINAL_KBF).unwrap();
            assert_eq!(cont.len(), sampled.len(), "{body:?}");
            for p in sampled.iter().filter(|p| p[0].hypot(p[1]) < 60.0) {
                let near = cont
                    .iter()
                    .map(|q| distance(*p, *q))
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    near < 0.05 * p[0].hypot(p[1]).max(1.0),
                    "{body:?} {p:?}: {near}"
                );
            }
        }
    }

    #[test]
    fn pid_designs_have_no_separate_design_view() {
        for kind in [CompensatorKind::Pid, CompensatorKind::PidNotch] {
            let c = compare(&setup(kind)).unwrap();
            assert_eq!(c.design, c.implemented);
            assert!(c.differences.is_empty());
            assert!(design_loop(&setup(kind)).unwrap().is_none());
        }
    }
}
