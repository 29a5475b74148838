//! The fit: the population's medians (and the spread of its people, where the target
//! carries spreads) by simulated moments. The moments are the logarithms of the target's
//! cell means (and the mean log coefficient of variation over the cells with a spread); the
//! simulator is `sim::simulate` on a fixed set of simulated subjects, so every evaluation
//! uses common random numbers and the moments move smoothly with the parameters.
//! Levenberg–Marquardt on the logarithms of the parameters, the Jacobian by forward
//! differences; weights 1/(target's variance + Monte-Carlo variance) on the log scale.
//! Intervals from a bootstrap linearized at the optimum: over subjects (a study's own data)
//! or over the table's cells redrawn with the shared deviation of the people who gave them
//! (`table_error`); the delay's ends then carried onto its profile (`Problem::profile_ends`:
//! the delay–gain ridge is curved). A parameter whose half-e-fold change moves the moments by less than one
//! standard error is not identified: left as it was and named.

use std::sync::atomic::{AtomicBool, Ordering};

use bdft_controller::rng::Rng;
use bdft_protocol::params::{PopulationParams, Spread, bounds};
use bdft_protocol::study::StudyParams;
use bdft_protocol::trial::Metrics;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::predict::{
    AT_BOUND_LOG, GoodnessOfFit, MetricDiscrepancy, Parts, discrepancies, goodness, interval,
    metric_index, parameter_and_prior, prior_log_sd,
};
use super::sim::{Cell, SubjectRef, all_cells, simulate};
use super::table_error::TableError;
use super::target::{Metric, Target, TargetCell, mean_sd};
use crate::engine::dry_runs::job::Progress;
use crate::error::{AppError, Result};

/// A population parameter the calibration may fit: a median, or the people's spread.
#[derive(Debug, Clone, Copy)]
pub(super) struct Knob {
    pub(super) name: &'static str,
    pub(super) get: fn(&PopulationParams) -> f64,
    pub(super) set: fn(&mut PopulationParams, f64),
    pub(super) bounds: (f64, f64),
}

/// The medians a target of tracking error and cab acceleration moves: the delay (the error
/// level), the operator's error gain (how fast they correct), the delay felt vibration adds
/// (the riding effect) and the body's feedthrough gain (vibration on the machine). Adding a
/// knob is one entry here: the fit, its intervals, the predictions' Jacobian and prior
/// ranges and the coverage test's true populations all follow this table.
pub(super) const MEDIANS: [Knob; 4] = [
    Knob {
        name: "reaction_delay_s",
        get: |p| p.reaction_delay_s.median,
        set: |p, v| p.reaction_delay_s.median = v,
        bounds: bounds::REACTION_DELAY_S,
    },
    Knob {
        name: "error_gain",
        get: |p| p.error_gain.median,
        set: |p, v| p.error_gain.median = v,
        bounds: (0.02, bounds::ERROR_GAIN.1),
    },
    Knob {
        name: "vibration_delay_s_per_m_s2",
        get: |p| p.vibration_delay_s_per_m_s2.median,
        set: |p, v| p.vibration_delay_s_per_m_s2.median = v,
        bounds: (0.01, bounds::VIBRATION_DELAY_S_PER_M_S2.1),
    },
    Knob {
        name: "body_k_h",
        get: |p| p.body_k_h.median,
        set: |p, v| p.body_k_h.median = v,
        bounds: bounds::BODY_K_H,
    },
];

/// Every spread of the people's operators, scaled together: what a target with spreads over
/// subjects moves.
fn operator_spreads(p: &mut PopulationParams) -> [&mut Spread; 5] {
    [
        &mut p.reaction_delay_s,
        &mut p.error_gain,
        &mut p.remnant_std_mm,
        &mut p.neuromuscular_w,
        &mut p.vibration_delay_s_per_m_s2,
    ]
}

const SPREAD: Knob = Knob {
    name: "operator_spread (cv of the operator's delay, gain, remnant, corner, vibration delay)",
    get: |p| p.reaction_delay_s.cv,
    set: |p, v| {
        let scale = v / p.reaction_delay_s.cv.max(1e-9);
        for s in operator_spreads(p) {
            s.cv = (s.cv * scale).clamp(1e-3, 2.0);
        }
    },
    bounds: (0.01, 1.5),
};

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FittedParameter {
    pub name: String,
    pub before: f64,
    pub fitted: f64,
    /// 95 % interval.
    pub low: f64,
    pub high: f64,
}

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct CellFit {
    /// The compensator (key `controller`, as the report has always named it).
    #[serde(rename = "controller")]
    pub compensator: String,
    /// The seat (key `station`).
    #[serde(rename = "station")]
    pub seat: String,
    pub metric: String,
    /// The target's mean (None for a prediction of a metric the target did not hold).
    pub target: Option<f64>,
    pub target_sd: Option<f64>,
    pub target_n: Option<usize>,
    /// For a prediction: what the study's people gave in the cell (their mean, and how many
    /// of them), not fitted; None where they gave nothing or the target was a table.
    pub observed: Option<f64>,
    pub observed_n: Option<usize>,
    /// The fitted population's simulated mean and its Monte-Carlo standard error.
    pub prediction: f64,
    pub monte_carlo_error: f64,
    /// The 95 % prediction interval of the mean (`predict`): the fitted parameters'
    /// uncertainty, the unidentified knobs' prior range, the Monte-Carlo error and the
    /// metric's model discrepancy where the fit estimated it; for a held-out row also the
    /// row's own error. None for the ratings, and where the simulation gave no mean.
    pub low: Option<f64>,
    pub high: Option<f64>,
    /// For a held-out row: whether its target lies inside [low, high].
    pub inside: Option<bool>,
    /// What the interval leaves out, if anything (a metric never fitted: its discrepancy is
    /// unknown).
    pub note: Option<String>,
}

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FitReport {
    pub source: String,
    pub simulated_subjects: usize,
    pub iterations: usize,
    /// Σ weight·(log prediction − log target)² at the start and at the end.
    pub objective_before: f64,
    pub objective: f64,
    pub parameters: Vec<FittedParameter>,
    /// Parameters the target cannot move (left as they were).
    pub not_identified: Vec<String>,
    /// How the intervals were found.
    pub intervals: String,
    /// Every target cell: target, fitted prediction, Monte-Carlo error.
    pub cells: Vec<CellFit>,
    /// Every other metric in every cell of the study, predicted by the fitted population:
    /// the honest test of the model.
    pub predictions: Vec<CellFit>,
    /// The rows held out of the fit: each predicted with its interval, beside its target.
    pub held_out: Vec<CellFit>,
    /// The misfit against what the Monte-Carlo and the target's errors allow, and the verdict.
    pub goodness_of_fit: GoodnessOfFit,
    /// Every fitted knob that ended within 1 % (in log) of a bound, named with the bound.
    pub at_bound: Vec<String>,
    /// Each metric's model discrepancy (method of moments on its fitted cells).
    pub discrepancy: Vec<MetricDiscrepancy>,
    /// How the prediction intervals were made.
    pub prediction_intervals: String,
    #[schema(value_type = Object)]
    pub population: PopulationParams,
}

/// What one evaluation gives: the simulated metrics per subject and cell.
struct Eval {
    rows: Vec<Vec<Option<Metrics>>>,
}

impl Eval {
    /// Mean, its Monte-Carlo standard error and the sd over subjects of `metric` in cell `j`.
    fn cell(&self, j: usize, metric: Metric) -> (f64, f64, f64) {
        let v: Vec<f64> = self
            .rows
            .iter()
            .filter_map(|r| r[j].map(|m| metric.of(&m)))
            .collect();
        if v.len() < 2 {
            return (f64::NAN, f64::NAN, f64::NAN);
        }
        let (mean, sd) = mean_sd(&v);
        (mean, sd / (v.len() as f64).sqrt(), sd)
    }
}

/// A target row as the report names it: "lqr on mse_tracking_mm2".
fn row_label(params: &StudyParams, t: &TargetCell) -> String {
    format!(
        "{} {} {}",
        params.compensators[t.cell.compensator].kind().name(),
        t.cell.seat.as_str(),
        t.metric.name()
    )
}

/// The fit's problem: the target's moments, their weights, the knobs fitted.
struct Problem<'a> {
    params: &'a StudyParams,
    target: &'a Target,
    cells: Vec<Cell>,
    subjects: Vec<SubjectRef>,
    knobs: Vec<Knob>,
    progress: &'a Progress,
    cancel: &'a AtomicBool,
}

impl Problem<'_> {
    fn population(&self, theta: &[f64]) -> PopulationParams {
        let mut pop = self.params.population;
        for (k, t) in self.knobs.iter().zip(theta) {
            (k.set)(&mut pop, t.exp().clamp(k.bounds.0, k.bounds.1));
        }
        pop
    }

    fn run(&self, theta: &[f64]) -> Result<Eval> {
        if self.cancel.load(Ordering::Relaxed) {
            return Err(AppError::Conflict("the calibration was cancelled".into()));
        }
        let params = StudyParams {
            population: self.population(theta),
            ..self.params.clone()
        };
        let rows = simulate(
            &params,
            &self.subjects,
            &self.cells,
            self.progress,
            self.cancel,
        )?;
        Ok(Eval { rows })
    }

    fn index(&self, cell: Cell) -> usize {
        self.cells
            .iter()
            .position(|&c| c == cell)
            .expect("a simulated cell")
    }

    /// The Jacobian of the moments `m` at `theta` in log-parameter space with respect to
    /// the knobs `which` (one column each, in that order), by forward differences of
    /// `JACOBIAN_STEP`.
    fn jacobian(&self, theta: &[f64], m: &DVector<f64>, which: &[usize]) -> Result<DMatrix<f64>> {
        Ok(self.jacobians(theta, m, None, which)?.0)
    }

    /// `jacobian`, and from the same evaluations the Jacobian of every output's log mean
    /// (`outputs`; `p` their values at `theta`; an empty matrix without `p`).
    fn jacobians(
        &self,
        theta: &[f64],
        m: &DVector<f64>,
        p: Option<&DVector<f64>>,
        which: &[usize],
    ) -> Result<(DMatrix<f64>, DMatrix<f64>)> {
        let mut jac = DMatrix::zeros(m.len(), which.len());
        let mut jac_p = DMatrix::zeros(p.map_or(0, |p| p.len()), which.len());
        for (c, &k) in which.iter().enumerate() {
            let mut th = theta.to_vec();
            th[k] += JACOBIAN_STEP;
            let e = self.run(&th)?;
            let (mk, _) = self.moments(&e);
            jac.set_column(c, &((mk - m) / JACOBIAN_STEP));
            if let Some(p) = p {
                jac_p.set_column(c, &((self.predicted(&e).0 - p) / JACOBIAN_STEP));
            }
        }
        Ok((jac, jac_p))
    }

    /// Every cell × metric of the study: what the fit predicts (`predicted`' order).
    fn outputs(&self) -> Vec<(Cell, Metric)> {
        self.cells
            .iter()
            .flat_map(|&c| Metric::ALL.map(|m| (c, m)))
            .collect()
    }

    /// Every output's log mean in an evaluation and its Monte-Carlo variance (NaN where the
    /// simulation gave fewer than two trials).
    fn predicted(&self, e: &Eval) -> (DVector<f64>, DVector<f64>) {
        let (mean, var): (Vec<f64>, Vec<f64>) = self
            .outputs()
            .into_iter()
            .map(|(c, m)| {
                let (mean, se, _) = e.cell(self.index(c), m);
                if mean > 0.0 {
                    (mean.ln(), (se / mean).powi(2))
                } else {
                    (f64::NAN, f64::NAN)
                }
            })
            .unzip();
        (DVector::from_vec(mean), DVector::from_vec(var))
    }

    /// One damped Gauss–Newton (Levenberg–Marquardt) step of the knobs `free` from `theta`,
    /// `jac` their Jacobian columns at the moments `m`: the new parameters (within the
    /// knobs' bounds), the step's largest component and the new parameters' evaluation;
    /// none when the damped normal equations are singular.
    fn damped_step(
        &self,
        theta: &[f64],
        free: &[usize],
        jac: &DMatrix<f64>,
        m: &DVector<f64>,
        c: Criterion,
        lambda: f64,
    ) -> Result<Option<(Vec<f64>, f64, Eval)>> {
        let jw = jac.transpose() * DMatrix::from_diagonal(c.weights);
        let mut a = &jw * jac;
        for d in 0..a.nrows() {
            a[(d, d)] *= 1.0 + lambda;
        }
        // A moment the simulation could not give (every test of a cell stopped) leaves no
        // step to take.
        let Some(step) = a
            .lu()
            .solve(&(&jw * (c.target - m)))
            .filter(|s| s.iter().all(|v| v.is_finite()))
        else {
            return Ok(None);
        };
        let step = step.map(|s| s.clamp(-0.7, 0.7));
        let mut th = theta.to_vec();
        for (i, &k) in free.iter().enumerate() {
            let (lo, hi) = self.knobs[k].bounds;
            th[k] = (th[k] + step[i]).clamp(lo.max(1e-6).ln(), hi.ln());
        }
        let e = self.run(&th)?;
        Ok(Some((th, step.amax(), e)))
    }

    /// The profile criterion of knob `k` at the log-value `v`: the criterion minimized over
    /// the knobs `others` from `start` (`k` set to `v`) by up to `PROFILE_STEPS` damped
    /// Gauss–Newton steps, their Jacobian recomputed for each; with the parameters reached.
    fn profile(
        &self,
        start: &[f64],
        k: usize,
        v: f64,
        others: &[usize],
        c: Criterion,
    ) -> Result<(f64, Vec<f64>)> {
        let mut theta = start.to_vec();
        theta[k] = v;
        let (mut m, _) = self.moments(&self.run(&theta)?);
        let mut q = c.of(&m);
        let mut lambda = 1e-3;
        for _ in 0..PROFILE_STEPS {
            if others.is_empty() {
                break;
            }
            let jac = self.jacobian(&theta, &m, others)?;
            let mut moved = None;
            for _ in 0..3 {
                let Some((th, largest, e)) =
                    self.damped_step(&theta, others, &jac, &m, c, lambda)?
                else {
                    break;
                };
                let (mt, _) = self.moments(&e);
                let o = c.of(&mt);
                if o < q {
                    moved = Some((th, largest, mt, o));
                    lambda = (lambda / 10.0).max(1e-6);
                    break;
                }
                lambda *= 10.0;
            }
            let Some((th, largest, mt, o)) = moved else {
                break;
            };
            (theta, m, q) = (th, mt, o);
            if largest < 0.01 {
                break;
            }
        }
        Ok((q, theta))
    }

    /// Both ends of the interval of `at.identified[i]` (log scale) carried from the
    /// bootstrap's ends `boot` onto its profile. The delay–gain ridge is curved and the
    /// bootstrap, linearized at the fit, follows only its tangent: so each end is put where
    /// the profile criterion rises above the fit's as far as the linear model's
    /// criterion does at the bootstrap's end on that side, (end − fit)² / `var` (`var` the
    /// parameter's variance in (JᵀWJ)⁻¹) — the bootstrap's end where the model is linear.
    /// The rise is the bootstrap's, not χ²₁'s, because the criterion's weights leave out the
    /// cells' correlation that the bootstrap carries. Found by secant steps on the square
    /// root of the rise (nearly linear in the parameter), each profile point started on the
    /// linear model's ridge at the fit or at the previous point.
    fn profile_ends(
        &self,
        at: &Optimum,
        i: usize,
        var: f64,
        boot: [f64; 2],
        c: Criterion,
    ) -> Result<[f64; 2]> {
        let Optimum {
            theta,
            identified,
            criterion: q_min,
            jac,
        } = *at;
        let k = identified[i];
        let others: Vec<usize> = identified.iter().copied().filter(|&o| o != k).collect();
        let jo = jac.select_columns(others.iter());
        let jow = jo.transpose() * DMatrix::from_diagonal(c.weights);
        // How the others move with the parameter along the linear model's ridge (none
        // when it is the only one identified: nalgebra's LU cannot solve a 0 × 0 system).
        let ridge = if others.is_empty() {
            DVector::zeros(0)
        } else {
            (&jow * &jo)
                .lu()
                .solve(&-(&jow * jac.column(k)))
                .unwrap_or_else(|| DVector::zeros(others.len()))
        };
        let (lo, hi) = self.knobs[k].bounds;
        let (lo, hi) = (lo.max(1e-6).ln(), hi.ln());
        let fit = theta[k];
        let mut ends = boot;
        for end in &mut ends {
            let half = (*end - fit).abs();
            if half <= 0.0 || !var.is_finite() || var <= 0.0 {
                continue;
            }
            let target = half / var.sqrt();
            let side = (*end - fit).signum();
            // On the linear ridge, kept within every knob's bounds (a nearly singular ridge
            // can point far out, or nowhere).
            let mut start = theta.to_vec();
            for (j, &o) in others.iter().enumerate() {
                let moved = start[o] + ridge[j] * (*end - fit);
                let (olo, ohi) = self.knobs[o].bounds;
                if moved.is_finite() {
                    start[o] = moved.clamp(olo.max(1e-6).ln(), ohi.ln());
                }
            }
            *end = end.clamp(lo, hi);
            let gap = |q: f64| (q - q_min).max(0.0).sqrt() - target;
            let (mut v0, mut g0) = (fit, -target);
            let (q, mut reached) = self.profile(&start, k, *end, &others, c)?;
            let (mut v1, mut g1) = (*end, gap(q));
            if !g1.is_finite() {
                // The simulation gives no criterion there: the bootstrap's end stands.
                continue;
            }
            for _ in 0..PROFILE_SECANTS {
                if g1.abs() <= 0.01 * target || (g1 - g0).abs() < 1e-12 {
                    break;
                }
                // On its side of the fit, within the knob's bounds, at most 3 half-widths out.
                let v2 = (v1 - g1 * (v1 - v0) / (g1 - g0)).clamp(
                    (fit - 3.0 * half).max(lo).min(fit),
                    (fit + 3.0 * half).min(hi).max(fit),
                );
                if (v2 - fit) * side <= 0.0 {
                    break;
                }
                let (q, next) = self.profile(&reached, k, v2, &others, c)?;
                if !gap(q).is_finite() {
                    break;
                }
                (v0, g0) = (v1, g1);
                (v1, g1, reached) = (v2, gap(q), next);
            }
            *end = v1;
        }
        Ok(ends)
    }

    /// Moments of an evaluation, and their Monte-Carlo variances: per target cell the mean
    /// log metric over subjects where the target knows its spread (else the log of the
    /// mean), then the mean over those cells of the sd of the log metric.
    fn moments(&self, e: &Eval) -> (DVector<f64>, DVector<f64>) {
        let mut m = Vec::new();
        let mut var = Vec::new();
        let mut sds = Vec::new();
        for t in &self.target.cells {
            let j = self.index(t.cell);
            if t.log.is_some() {
                let logs: Vec<f64> = e
                    .rows
                    .iter()
                    .filter_map(|r| r[j].map(|x| t.metric.of(&x).max(1e-12).ln()))
                    .collect();
                let (mean, sd) = if logs.len() < 2 {
                    (f64::NAN, f64::NAN)
                } else {
                    mean_sd(&logs)
                };
                m.push(mean);
                var.push(sd * sd / logs.len().max(1) as f64);
                sds.push(sd);
            } else {
                // Fewer than two simulated subjects completed the cell: no mean, as in the
                // log branch (a made-up ln 1e-12 would be a finite, enormous misfit).
                let (mean, se, _) = e.cell(j, t.metric);
                m.push(if mean > 0.0 { mean.ln() } else { f64::NAN });
                var.push((se / mean).powi(2));
            }
        }
        if !sds.is_empty() {
            m.push(sds.iter().sum::<f64>() / sds.len() as f64);
            // The sd of a normal sample has a standard error of about sd/√(2n).
            var.push(m[m.len() - 1].powi(2) / (2.0 * self.subjects.len() as f64));
        }
        (DVector::from_vec(m), DVector::from_vec(var))
    }

    /// The target's moments and their variances, as `moments`.
    fn target_moments(&self, target: &Target) -> (DVector<f64>, DVector<f64>) {
        let mut m = Vec::new();
        let mut var = Vec::new();
        let mut sds = Vec::new();
        for t in &target.cells {
            match (t.log, t.n) {
                (Some((mean, sd)), Some(n)) => {
                    m.push(mean);
                    var.push(sd * sd / n as f64);
                    sds.push((sd, n));
                }
                _ => {
                    m.push(t.mean.ln());
                    var.push(t.metric.default_log_se().powi(2));
                }
            }
        }
        if !sds.is_empty() {
            let mean = sds.iter().map(|s| s.0).sum::<f64>() / sds.len() as f64;
            let n = sds.iter().map(|s| s.1).sum::<usize>() / sds.len();
            m.push(mean);
            var.push(mean * mean / (2.0 * n as f64));
        }
        (DVector::from_vec(m), DVector::from_vec(var))
    }
}

/// The fit's criterion: the target's moments and their weights.
#[derive(Clone, Copy)]
struct Criterion<'a> {
    target: &'a DVector<f64>,
    weights: &'a DVector<f64>,
}

impl Criterion<'_> {
    /// Σ weight·(moment − target)² of the moments `m`.
    fn of(&self, m: &DVector<f64>) -> f64 {
        let r = m - self.target;
        r.component_mul(&r).dot(self.weights)
    }
}

/// The fit where it ended: the log-parameters, the knobs identified, the criterion's value
/// and the Jacobian of every knob.
#[derive(Clone, Copy)]
struct Optimum<'a> {
    theta: &'a [f64],
    identified: &'a [usize],
    criterion: f64,
    jac: &'a DMatrix<f64>,
}

/// Refuses a target with fewer moments than the parameters it would fit (422).
pub fn check_enough(target: &Target) -> Result<()> {
    let spread = !target.with_spread().is_empty();
    let params = MEDIANS.len() + usize::from(spread);
    let moments = target.cells.len() + usize::from(spread);
    if moments < params {
        return Err(AppError::BadRequest(format!(
            "table: {} cells give {moments} moments, too few for the {params} parameters fitted ({}{}); give at least {} cells",
            target.cells.len(),
            MEDIANS.map(|k| k.name).join(", "),
            if spread { ", operator_spread" } else { "" },
            MEDIANS.len(),
        )));
    }
    Ok(())
}

/// Forward-difference step of the Jacobian (log units: 16 %).
const JACOBIAN_STEP: f64 = 0.15;

/// The knobs (`MEDIANS`) whose intervals are carried onto their profiles: the delay and the
/// error gain (a slower person or a less correcting one: the delay–gain ridge is curved, so
/// the linearized interval of either end can miss it) and the body's feedthrough gain (more
/// feedthrough or more delay under the vibration it lets through: both raise the riding
/// cost, most with the LQR). Each profile costs about as many evaluations as the fit, so the
/// vibration delay keeps the linearized bootstrap's interval.
const PROFILED: [&str; 3] = ["reaction_delay_s", "error_gain", "body_k_h"];

/// Damped Gauss–Newton steps of a profile point's refit.
const PROFILE_STEPS: usize = 2;

/// Secant steps of a profile end after its first point.
const PROFILE_SECANTS: usize = 3;

/// Bootstrap resamples for the intervals.
const BOOTSTRAP: usize = 400;

/// How many simulated subjects a calibration runs per evaluation, at most.
pub const MAX_SUBJECTS: usize = 512;

/// Fits `params.population` to `target` with `n_sim` simulated subjects (seeded `seed`):
/// the fitted population and the report. `progress` counts simulated trials; `cancel` stops
/// it (409).
pub fn fit(
    params: &StudyParams,
    target: &Target,
    source: &str,
    n_sim: usize,
    seed: u64,
    progress: &Progress,
    cancel: &AtomicBool,
) -> Result<FitReport> {
    fit_with(params, target, source, n_sim, seed, true, progress, cancel)
}

/// `fit`, with the profiles of the `PROFILED` parameters' ends (`profile`) or without (the
/// linearized bootstrap's intervals; the predictions do not use the profiles, and a
/// profile costs about as many evaluations as the fit).
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_with(
    params: &StudyParams,
    target: &Target,
    source: &str,
    n_sim: usize,
    seed: u64,
    profile: bool,
    progress: &Progress,
    cancel: &AtomicBool,
) -> Result<FitReport> {
    if !(8..=MAX_SUBJECTS).contains(&n_sim) {
        return Err(AppError::BadRequest(format!(
            "simulated_subjects: 8 to {MAX_SUBJECTS}"
        )));
    }
    check_enough(target)?;
    let with_sd = target.with_spread();
    let mut knobs: Vec<Knob> = MEDIANS.to_vec();
    if !with_sd.is_empty() {
        knobs.push(SPREAD);
    }
    let cells = all_cells(params);
    let subjects: Vec<SubjectRef> = (0..n_sim as u32)
        .map(|index| SubjectRef { seed, index })
        .collect();
    let problem = Problem {
        params,
        target,
        cells,
        subjects,
        knobs,
        progress,
        cancel,
    };
    let before: Vec<f64> = problem
        .knobs
        .iter()
        .map(|k| (k.get)(&params.population).max(k.bounds.0))
        .collect();
    let (t, t_var) = problem.target_moments(target);
    let mut theta: Vec<f64> = before.iter().map(|v| v.ln()).collect();
    let mut eval = problem.run(&theta)?;
    let (mut m, mc) = problem.moments(&eval);
    // A target cell the starting population cannot complete has no moment to fit to: say
    // which, rather than fit to nothing (a step that loses a cell later is refused instead).
    let empty: Vec<String> = target
        .cells
        .iter()
        .zip(m.iter())
        .filter(|(_, v)| !v.is_finite())
        .map(|(c, _)| row_label(params, c))
        .collect();
    if !empty.is_empty() {
        return Err(AppError::Conflict(format!(
            "fewer than 2 of the {n_sim} simulated subjects completed {} (the vibration \
             interlock stopped the rest): no mean to fit to; calibrate with more simulated \
             subjects, or without that row",
            empty.join(", ")
        )));
    }
    let mut p = problem.predicted(&eval).0;
    let w: DVector<f64> = (&t_var + &mc).map(|v| 1.0 / v.max(1e-12));
    let criterion = Criterion {
        target: &t,
        weights: &w,
    };
    let objective_before = criterion.of(&m);
    let mut current = objective_before;
    let mut lambda = 1e-2;
    let mut iterations = 0;
    let mut jac;
    let mut jac_p;
    let mut identified: Vec<usize>;
    let all: Vec<usize> = (0..problem.knobs.len()).collect();
    loop {
        iterations += 1;
        (jac, jac_p) = problem.jacobians(&theta, &m, Some(&p), &all)?;
        // Identified: half an e-fold of the parameter moves the moments by at least one
        // standard error (weighted norm of the column).
        identified = all
            .iter()
            .copied()
            .filter(|&k| 0.5 * jac.column(k).component_mul(&jac.column(k)).dot(&w).sqrt() >= 1.0)
            .collect();
        if identified.is_empty() || iterations > 8 {
            break;
        }
        let j = jac.select_columns(identified.iter());
        let mut accepted = false;
        for _ in 0..4 {
            let Some((th, _, e)) =
                problem.damped_step(&theta, &identified, &j, &m, criterion, lambda)?
            else {
                break;
            };
            let (mt, _) = problem.moments(&e);
            let o = criterion.of(&mt);
            if o < current {
                theta = th;
                eval = e;
                m = mt;
                p = problem.predicted(&eval).0;
                current = o;
                lambda = (lambda / 10.0).max(1e-6);
                accepted = true;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            // The Jacobian is the optimum's already.
            break;
        }
        if current < 1e-3 {
            (jac, jac_p) = problem.jacobians(&theta, &m, Some(&p), &all)?;
            break;
        }
    }
    // Each metric's model discrepancy (`predict`), from its fitted moments' misfit; it
    // enters the intervals' weights (w2) and draws, and the prediction intervals.
    let moment_metric: Vec<Option<Metric>> = target
        .cells
        .iter()
        .map(|c| Some(c.metric))
        .chain(std::iter::repeat(None))
        .take(m.len())
        .collect();
    let residual = &m - &t;
    let tau2 = discrepancies(&moment_metric, &residual, &w, identified.len());
    let tau2_of = |i: usize| {
        moment_metric[i]
            .and_then(|mt| tau2[metric_index(mt)])
            .unwrap_or(0.0)
    };
    let w2 = DVector::from_fn(m.len(), |i, _| 1.0 / (1.0 / w[i] + tau2_of(i)));
    let criterion2 = Criterion {
        target: &t,
        weights: &w2,
    };
    // Covariance of the identified log-parameters.
    let j = jac.select_columns(identified.iter());
    let jw = j.transpose() * DMatrix::from_diagonal(&w2);
    let info = &jw * &j;
    let cov = info.clone().try_inverse();
    // The bootstrap's moves of the identified log-parameters (for the predictions).
    let mut deltas: Vec<DVector<f64>> = Vec::new();
    // Intervals by a two-sided bootstrap, linearized at the fit: each resample redraws the
    // target (the study's subjects resampled, or the table's cells together from their
    // standard errors and the simulated subjects' correlation between cells: `TableError`)
    // and the simulated subjects (resampled: the Monte-Carlo error, with its correlation
    // across cells), adds the metrics' model discrepancy where the fit found one, and moves
    // the fit by the Gauss–Newton step that answers the change.
    let (low_high, intervals): (Vec<(f64, f64)>, String) = match &cov {
        Some(cov) => {
            let mut rng = Rng::new(seed ^ 0xb007);
            let table = TableError::new(target, &t_var, &problem.cells, &eval.rows);
            let mut draws: Vec<Vec<f64>> = vec![Vec::new(); identified.len()];
            let resample =
                |rows: &[Vec<Option<Metrics>>], rng: &mut Rng| -> Vec<Vec<Option<Metrics>>> {
                    let n = rows.len();
                    (0..n)
                        .map(|_| rows[((rng.next_f64() * n as f64) as usize).min(n - 1)].clone())
                        .collect()
                };
            let discrepant = (0..m.len()).any(|i| tau2_of(i) > 0.0);
            for _ in 0..BOOTSTRAP {
                let tb = match &target.subjects {
                    Some(rows) => {
                        let mut boot =
                            super::target::from_subjects(&problem.cells, resample(rows, &mut rng));
                        // Only the fitted cells (not the held-out ones).
                        boot.cells.retain(|b| {
                            target
                                .cells
                                .iter()
                                .any(|a| a.cell == b.cell && a.metric == b.metric)
                        });
                        if boot.cells.len() != target.cells.len()
                            || boot
                                .cells
                                .iter()
                                .zip(&target.cells)
                                .any(|(a, b)| a.cell != b.cell || a.metric != b.metric)
                        {
                            continue;
                        }
                        problem.target_moments(&boot).0
                    }
                    None => &t + table.draw(&mut rng),
                };
                let tb = if discrepant {
                    tb + DVector::from_fn(m.len(), |i, _| rng.normal() * tau2_of(i).sqrt())
                } else {
                    tb
                };
                let mb = problem
                    .moments(&Eval {
                        rows: resample(&eval.rows, &mut rng),
                    })
                    .0;
                if mb.iter().any(|v| !v.is_finite()) {
                    continue;
                }
                let delta = cov * (&jw * ((tb - &t) - (mb - &m)));
                for (i, d) in delta.iter().enumerate() {
                    draws[i].push(theta[identified[i]] + d);
                }
                deltas.push(delta);
            }
            let mut ci: Vec<(f64, f64)> = draws
                .into_iter()
                .map(|mut d| {
                    if d.is_empty() {
                        return (f64::NAN, f64::NAN);
                    }
                    d.sort_by(f64::total_cmp);
                    let at =
                        |q: f64| d[((q * (d.len() - 1) as f64).round() as usize).min(d.len() - 1)];
                    (at(0.025).exp(), at(0.975).exp())
                })
                .collect();
            // The ends of the medians on a curved ridge carried onto their profiles
            // (`Problem::profile_ends`).
            let optimum = Optimum {
                theta: &theta,
                identified: &identified,
                criterion: criterion2.of(&m),
                jac: &jac,
            };
            let mut profiled = "";
            for (i, &k) in identified.iter().enumerate() {
                if profile
                    && PROFILED.contains(&problem.knobs[k].name)
                    && ci[i].0 > 0.0
                    && ci[i].1.is_finite()
                {
                    let ends = problem.profile_ends(
                        &optimum,
                        i,
                        cov[(i, i)],
                        [ci[i].0.ln(), ci[i].1.ln()],
                        criterion2,
                    )?;
                    ci[i] = (ends[0].exp(), ends[1].exp());
                    profiled = "; the delay's, the error gain's and the feedthrough gain's ends then carried onto their profiles (the other identified parameters refitted at each value, each end where the criterion rises above the fit's as far as the linear model's does at the bootstrap's end: the bootstrap's interval where the model is linear, bending with the delay–gain and the feedthrough–delay ridges where it is not)";
                }
            }
            let data = if target.subjects.is_some() {
                "the study's subjects resampled".to_string()
            } else {
                format!(
                    "the table's cells redrawn together from their standard errors (sd/√n) with the simulated subjects' correlation of log metric between cells (mean {:.2}{}), as the same people give every cell; a cell without sd and n on its own, by its metric's judged error ({})",
                    table.mean_correlation,
                    if table.shrink > 0.0 {
                        format!(", shrunk by {:.0e} for a factor", table.shrink)
                    } else {
                        String::new()
                    },
                    Metric::ALL
                        .map(|m| format!("{} ±{:.0} %", m.name(), 100.0 * m.default_log_se()))
                        .join(", ")
                )
            };
            let discrepancy = if discrepant {
                "; each metric's model discrepancy (below) added to its cells' variances and draws"
            } else {
                ""
            };
            (
                ci,
                format!(
                    "95 % bootstrap ({BOOTSTRAP} resamples, linearized at the fit): {data}, and the simulated subjects resampled (the Monte-Carlo error){discrepancy}{profiled}"
                ),
            )
        }
        None => (
            Vec::new(),
            "none: the identified parameters are collinear".into(),
        ),
    };
    let population = problem.population(&theta);
    let parameters = identified
        .iter()
        .enumerate()
        .map(|(i, &k)| FittedParameter {
            name: problem.knobs[k].name.to_string(),
            before: before[k],
            fitted: (problem.knobs[k].get)(&population),
            low: low_high.get(i).map_or(f64::NAN, |x| x.0),
            high: low_high.get(i).map_or(f64::NAN, |x| x.1),
        })
        .collect();
    let not_identified = (0..problem.knobs.len())
        .filter(|k| !identified.contains(k))
        .map(|k| problem.knobs[k].name.to_string())
        .collect();
    // The fitted knobs that ended at a bound (within 1 % in log).
    let at_bound: Vec<String> = identified
        .iter()
        .filter_map(|&k| {
            let knob = &problem.knobs[k];
            let v = (knob.get)(&population);
            let (lo, hi) = knob.bounds;
            if (v / lo).ln().abs() <= AT_BOUND_LOG {
                Some(format!("{} (at its lower bound {lo})", knob.name))
            } else if (hi / v).ln().abs() <= AT_BOUND_LOG {
                Some(format!("{} (at its upper bound {hi})", knob.name))
            } else {
                None
            }
        })
        .collect();
    let name = |c: Cell| params.compensators[c.compensator].kind().name().to_string();
    // The goodness of fit: the misfit against χ² with moments − identified parameters.
    let label = |i: usize| match target.cells.get(i) {
        Some(c) => row_label(params, c),
        None => "the mean log spread".to_string(),
    };
    let worst: Vec<(String, f64)> = (0..m.len())
        .map(|i| (label(i), residual[i] * w[i].sqrt()))
        .collect();
    let goodness_of_fit = goodness(
        current,
        m.len() as i64 - identified.len() as i64,
        &worst,
        &at_bound,
    );
    // Every output's prediction interval (`predict`).
    let outputs = problem.outputs();
    let (_, p_mc) = problem.predicted(&eval);
    let prior_sd: Vec<f64> = problem
        .knobs
        .iter()
        .map(|k| prior_log_sd((k.get)(&population), k.bounds))
        .collect();
    let spread = parameter_and_prior(&jac_p, &identified, &deltas, &prior_sd);
    let fit_of = |cell: Cell, metric: Metric, t: Option<&TargetCell>, held: bool| {
        let (mean, se, _) = eval.cell(problem.index(cell), metric);
        let o = outputs
            .iter()
            .position(|&x| x == (cell, metric))
            .expect("an output");
        let discrepancy = tau2[metric_index(metric)];
        // A held-out row's own error: its log mean's standard error.
        let own = match t {
            Some(t) if held => match (t.sd, t.n) {
                (Some(sd), Some(n)) if t.log.is_some() => (sd / t.mean).powi(2) / n as f64,
                _ => metric.default_log_se().powi(2),
            },
            _ => 0.0,
        };
        let parts = Parts {
            parameters: spread[o].0,
            prior: spread[o].1,
            monte_carlo: p_mc[o],
            discrepancy: discrepancy.unwrap_or(0.0),
            target: own,
        };
        let range = interval(mean, parts.total());
        CellFit {
            compensator: name(cell),
            seat: cell.seat.as_str().to_string(),
            metric: metric.name().to_string(),
            target: t.map(|t| t.mean),
            target_sd: t.and_then(|t| t.sd),
            target_n: t.and_then(|t| t.n),
            observed: None,
            observed_n: None,
            prediction: mean,
            monte_carlo_error: se,
            low: range.map(|r| r.0),
            high: range.map(|r| r.1),
            inside: t
                .filter(|_| held)
                .and_then(|t| range.map(|r| r.0 <= t.mean && t.mean <= r.1)),
            note: discrepancy.is_none().then(|| {
                format!(
                    "{} was not in the fitted target: its model discrepancy is unknown, and the interval leaves it out",
                    metric.name()
                )
            }),
        }
    };
    let cells = target
        .cells
        .iter()
        .map(|t| fit_of(t.cell, t.metric, Some(t), false))
        .collect();
    let held_out = target
        .held_out
        .iter()
        .map(|t| fit_of(t.cell, t.metric, Some(t), true))
        .collect();
    let in_target =
        |c: Cell, m: Metric, rows: &[TargetCell]| rows.iter().any(|t| t.cell == c && t.metric == m);
    let predictions = outputs
        .iter()
        .filter(|&&(c, m)| !in_target(c, m, &target.cells) && !in_target(c, m, &target.held_out))
        .map(|&(c, m)| fit_of(c, m, None, false))
        .collect();
    let discrepancy = Metric::ALL
        .iter()
        .map(|&mt| MetricDiscrepancy {
            metric: mt.name().to_string(),
            fitted_cells: target.cells.iter().filter(|c| c.metric == mt).count(),
            log_sd: tau2[metric_index(mt)].map(f64::sqrt),
        })
        .collect();
    let prediction_intervals = format!(
        "95 % on the log scale, the log mean ± 1.96 √(sum of variances): the identified parameters' bootstrap draws through the Jacobian of every cell × metric's log mean (forward differences, step {JACOBIAN_STEP} in log), each unidentified knob's prior range (its value ×/÷ {} within its bounds, as a 95 % range) through the same Jacobian, the Monte-Carlo error, the metric's model discrepancy where its cells were fitted (unknown, left out and noted, for a metric never fitted), and for a held-out row its own error (sd/√n of the mean, else its metric's judged error); the knobs the calibration never fits are taken as known",
        super::predict::PRIOR_FACTOR
    );
    Ok(FitReport {
        source: source.to_string(),
        simulated_subjects: n_sim,
        iterations,
        objective_before,
        objective: current,
        parameters,
        not_identified,
        intervals,
        cells,
        predictions,
        held_out,
        goodness_of_fit,
        at_bound,
        discrepancy,
        prediction_intervals,
        population,
    })
}
