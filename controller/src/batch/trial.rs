//! A batch of `LANES` trials ticked together: the scalar `TrialRunner::tick`, operation for
//! operation, over every lane.

use bdft_protocol::params::Seat;
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::{InputSource, Metrics};

use crate::closed_loop::ClosedLoop;
use crate::model::idx;
use crate::operator::SyntheticOperator;
use crate::rng::Rng;
use crate::runner::{HandSource, TrialRunner};
use crate::runtime::setup::build_runner;
use crate::runtime::slot::SlotLoop;
use crate::signals::Signal;

use super::normal::NormalLanes;
use super::operator::OperatorLanes;
use super::rig::{BodyLanes, CompensatorLanes, InterlockLanes, PlantLanes};
use super::{LANES, Lanes, ZERO};

/// Where a batch's normal deviates come from, one per lane for each of the two noise
/// streams a trial has.
pub(crate) trait Deviates {
    /// The operators' remnant this tick (0 in a lane that draws none).
    fn remnant(&mut self) -> Lanes;
    /// The accelerometers' noise this tick.
    fn accel(&mut self) -> Lanes;
}

/// The batch's own vectorized streams (`normal::NormalLanes`), seeded from each lane's
/// scalar streams: the same trial seeds give the same batch, on any machine.
#[derive(Debug, Clone)]
pub(crate) struct FastDeviates {
    remnant: NormalLanes,
    accel: NormalLanes,
}

impl Deviates for FastDeviates {
    #[inline(always)]
    fn remnant(&mut self) -> Lanes {
        self.remnant.next()
    }
    #[inline(always)]
    fn accel(&mut self) -> Lanes {
        self.accel.next()
    }
}

/// The scalar trial's own deviates (each lane's `Rng::normal`, drawn exactly when the
/// scalar trial draws): a batch run on these reproduces the scalar trials.
#[cfg(test)]
#[derive(Debug, Clone)]
pub(crate) struct ScalarDeviates {
    remnant: [Option<Rng>; LANES],
    accel: [Option<Rng>; LANES],
}

#[cfg(test)]
impl Deviates for ScalarDeviates {
    fn remnant(&mut self) -> Lanes {
        std::array::from_fn(|l| self.remnant[l].as_mut().map_or(0.0, |r| r.normal()))
    }
    fn accel(&mut self) -> Lanes {
        std::array::from_fn(|l| self.accel[l].as_mut().map_or(0.0, |r| r.normal()))
    }
}

/// The lanes' targets.
#[derive(Debug, Clone)]
enum Targets {
    /// Random steps on one interval (every study's targets): the level index is the same
    /// for every lane, so a tick computes it once and reads one row; `levels[i]` holds each
    /// lane's level i, a lane with fewer levels repeating its last (`Signal::at` holds the
    /// last level after the end).
    Steps {
        interval_s: f64,
        levels: Vec<Lanes>,
    },
    Each(Vec<Signal>),
}

impl Targets {
    fn new(signals: Vec<Signal>) -> Self {
        let steps: Option<Vec<(f64, &Vec<f64>)>> = signals
            .iter()
            .map(|s| match s {
                Signal::Steps {
                    interval_s,
                    levels_mm,
                } => Some((*interval_s, levels_mm)),
                _ => None,
            })
            .collect();
        match steps {
            Some(lanes) if lanes.iter().all(|(i, _)| *i == lanes[0].0) => {
                let longest = lanes.iter().map(|(_, v)| v.len()).max().unwrap_or(1);
                Self::Steps {
                    interval_s: lanes[0].0,
                    levels: (0..longest)
                        .map(|i| std::array::from_fn(|l| lanes[l].1[i.min(lanes[l].1.len() - 1)]))
                        .collect(),
                }
            }
            _ => Self::Each(signals),
        }
    }

    /// `Signal::at` for every lane.
    #[inline(always)]
    fn at(&self, t: f64) -> Lanes {
        match self {
            Self::Steps { interval_s, levels } => {
                levels[((t / interval_s).max(0.0) as usize).min(levels.len() - 1)]
            }
            Self::Each(signals) => std::array::from_fn(|l| signals[l].at(t)),
        }
    }
}

/// `LANES` trials of one design at one seat, each with its own subject, target and seeds.
#[derive(Debug, Clone)]
pub(crate) struct BatchTrial {
    targets: Targets,
    plant: PlantLanes,
    body: BodyLanes,
    compensator: CompensatorLanes,
    operator: OperatorLanes,
    interlock: InterlockLanes,
    k_bf: Lanes,
    seat_on: bool,
    dt: f64,
    total: u64,
    displayed_y: Lanes,
    sum_sq_error: Lanes,
    sum_sq_accel: Lanes,
    tripped: [bool; LANES],
}

/// The parts of one lane's scalar trial.
struct Lane<'a> {
    runner: &'a TrialRunner<SlotLoop>,
    rig: &'a ClosedLoop,
    operator: &'a SyntheticOperator,
}

fn lane(runner: &TrialRunner<SlotLoop>) -> Result<Lane<'_>, String> {
    let SlotLoop::Sim(rig) = &runner.lp else {
        return Err("a batched trial runs on the simulated rig".into());
    };
    let HandSource::Synthetic(operator) = &runner.hand else {
        return Err("a batched trial needs a synthetic operator".into());
    };
    // The batch's operators track their targets; an identification test's hold still.
    if runner.signal.excites() {
        return Err("an identification test is not batched: its operator holds still".into());
    }
    Ok(Lane {
        runner,
        rig,
        operator,
    })
}

/// The first field in which `b` differs from `a` among those a batch's trials share.
fn shared_difference(a: &StartTrial, b: &StartTrial) -> Option<&'static str> {
    [
        ("compensator", a.compensator != b.compensator),
        ("plant", a.plant != b.plant),
        ("station", a.seat != b.seat),
        ("k_bf", a.k_bf != b.k_bf),
        ("duration_s", a.duration_s != b.duration_s),
        (
            "max_cab_rms_mm_s2",
            a.max_cab_rms_mm_s2 != b.max_cab_rms_mm_s2,
        ),
    ]
    .into_iter()
    .find_map(|(name, differs)| differs.then_some(name))
}

impl BatchTrial {
    /// Builds the batch of `starts` (one per lane) at sample period `dt` through the scalar
    /// trial's own setup — validation, designs, operators — and the deviates it runs on.
    pub(crate) fn build(
        starts: &[&StartTrial; LANES],
        dt: f64,
    ) -> Result<(Self, FastDeviates), String> {
        let (batch, runners) = Self::from_starts(starts, dt)?;
        let seeds = |pick: &dyn Fn(&Lane) -> Rng| -> Result<[[u64; 4]; LANES], String> {
            let mut out = [[0u64; 4]; LANES];
            for (o, r) in out.iter_mut().zip(&runners) {
                *o = Rng::new(pick(&lane(r)?).next_u64()).s;
            }
            Ok(out)
        };
        let deviates = FastDeviates {
            remnant: NormalLanes::new(seeds(&|l| l.operator.rng)?),
            accel: NormalLanes::new(seeds(&|l| l.rig.plant.noise)?),
        };
        Ok((batch, deviates))
    }

    /// The batch and the scalar runners it was built from.
    fn from_starts(
        starts: &[&StartTrial; LANES],
        dt: f64,
    ) -> Result<(Self, Vec<TrialRunner<SlotLoop>>), String> {
        for (l, st) in starts.iter().enumerate() {
            if let Some(field) = shared_difference(starts[0], st) {
                return Err(format!(
                    "the trials of a batch share {field}; trial {l} differs from trial 0"
                ));
            }
            if !matches!(st.input, InputSource::Synthetic { .. }) {
                return Err(format!(
                    "trial {l}: a batched trial needs a synthetic operator"
                ));
            }
        }
        let runners = starts
            .iter()
            .map(|st| build_runner(st, dt, false).map(|(r, _)| r))
            .collect::<Result<Vec<_>, _>>()?;
        let lanes = runners.iter().map(lane).collect::<Result<Vec<_>, _>>()?;
        let each = |l: usize| &lanes[l];
        let Some(interlock) = lanes[0].runner.interlock.as_ref() else {
            return Err("a batched trial runs with the vibration interlock".into());
        };
        let body = BodyLanes::new(&std::array::from_fn(|l| &each(l).rig.body))
            .ok_or("the trials of a batch share one body model kind")?;
        let batch = Self {
            targets: Targets::new(lanes.iter().map(|l| l.runner.signal.clone()).collect()),
            plant: PlantLanes::new(&std::array::from_fn(|l| &each(l).rig.plant))?,
            body,
            compensator: CompensatorLanes::new(&lanes[0].rig.compensator)?,
            operator: OperatorLanes::new(&std::array::from_fn(|l| each(l).operator)),
            interlock: InterlockLanes::new(interlock),
            k_bf: std::array::from_fn(|l| each(l).rig.k_bf),
            seat_on: lanes[0].rig.seat == Seat::On,
            dt: lanes[0].runner.dt,
            total: lanes[0].runner.total,
            displayed_y: ZERO,
            sum_sq_error: ZERO,
            sum_sq_accel: ZERO,
            tripped: [false; LANES],
        };
        drop(lanes);
        Ok((batch, runners))
    }

    /// The batch and the scalar trials' own deviates (for the tests that hold the batch to
    /// the scalar path), with the scalar runners themselves.
    #[cfg(test)]
    pub(crate) fn build_scalar(
        starts: &[&StartTrial; LANES],
        dt: f64,
    ) -> Result<(Self, ScalarDeviates, Vec<TrialRunner<SlotLoop>>), String> {
        let (batch, runners) = Self::from_starts(starts, dt)?;
        let lanes = runners.iter().map(lane).collect::<Result<Vec<_>, _>>()?;
        let deviates = ScalarDeviates {
            remnant: std::array::from_fn(|l| {
                lanes[l].operator.noisy().then_some(lanes[l].operator.rng)
            }),
            accel: std::array::from_fn(|l| {
                let p = &lanes[l].rig.plant;
                (p.params().accel_noise_std > 0.0).then_some(p.noise)
            }),
        };
        drop(lanes);
        Ok((batch, deviates, runners))
    }

    /// `TrialRunner::tick` for every lane.
    #[inline(always)]
    fn tick<D: Deviates>(&mut self, k: u64, deviates: &mut D) {
        let t = k as f64 * self.dt;
        let target = self.targets.at(t);
        let felt = if self.seat_on {
            self.plant.x[idx::XC_DD]
        } else {
            ZERO
        };
        let (hand, regripped) =
            self.operator
                .step(&target, &self.displayed_y, &felt, &deviates.remnant());
        if regripped {
            self.body.set_grip(&self.operator.grip);
        }
        // `ClosedLoop::tick`: measure, body, reference, compensator, plant.
        let y = self.plant.x[idx::Y];
        let cab_accel = self.plant.cab_accel(&deviates.accel());
        self.displayed_y = y;
        let h = if self.seat_on {
            self.body.step(&self.plant.x[idx::XC])
        } else {
            ZERO
        };
        let mut r_c = ZERO;
        for l in 0..LANES {
            r_c[l] = self.k_bf[l] * (hand[l] - h[l]);
        }
        let v = self.compensator.step(&r_c, &y, &cab_accel);
        self.plant.step(&v);
        for l in 0..LANES {
            let e = target[l] - y[l];
            self.sum_sq_error[l] += e * e;
            self.sum_sq_accel[l] += cab_accel[l] * cab_accel[l];
        }
        let trips = self.interlock.update(&cab_accel);
        for l in 0..LANES {
            self.tripped[l] |= trips[l];
        }
    }

    /// Every lane to its trial's end, or until the interlock has stopped them all.
    #[inline(always)]
    fn run_lanes<D: Deviates>(&mut self, deviates: &mut D) {
        for k in 0..self.total {
            self.tick(k, deviates);
            if self.tripped.iter().all(|&t| t) {
                break;
            }
        }
    }

    /// Each lane's metrics; None where the interlock stopped the trial.
    pub(crate) fn results(&self) -> [Option<Metrics>; LANES] {
        let n = self.total.max(1) as f64;
        std::array::from_fn(|l| {
            (!self.tripped[l]).then(|| Metrics {
                ticks: self.total,
                mse_tracking_mm2: self.sum_sq_error[l] / n,
                ms_cab_accel: self.sum_sq_accel[l] / n,
            })
        })
    }
}

/// A build of the batch's tick loop: the same code compiled for a set of vector
/// instructions. All compute the same IEEE operations in the same order (no fused
/// multiply–add), so their results are bit for bit the same (tested).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Build {
    /// One 512-bit register holds a quantity of all eight lanes.
    Avx512,
    Avx2,
    /// What every x86-64 (or other) CPU runs.
    Baseline,
}

impl Build {
    /// Widest first.
    pub const ALL: [Build; 3] = [Build::Avx512, Build::Avx2, Build::Baseline];

    /// The widest build this CPU runs.
    pub fn widest() -> Build {
        Build::ALL
            .into_iter()
            .find(|b| b.available())
            .unwrap_or(Build::Baseline)
    }

    /// Whether this CPU (and its operating system) runs this build.
    pub fn available(self) -> bool {
        match self {
            Build::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            Build::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(target_arch = "x86_64")]
            Build::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }
}

/// Runs the batch with `build`; false, and nothing run, where this CPU lacks it.
#[allow(unsafe_code)]
pub(crate) fn run_with<D: Deviates>(
    build: Build,
    batch: &mut BatchTrial,
    deviates: &mut D,
) -> bool {
    if !build.available() {
        return false;
    }
    match build {
        Build::Baseline => batch.run_lanes(deviates),
        // SAFETY: the one requirement for calling a function compiled with a target feature
        // is that the CPU has it, which `available` checked above.
        #[cfg(target_arch = "x86_64")]
        Build::Avx512 => unsafe { run_avx512(batch, deviates) },
        // SAFETY: as above.
        #[cfg(target_arch = "x86_64")]
        Build::Avx2 => unsafe { run_avx2(batch, deviates) },
        #[cfg(not(target_arch = "x86_64"))]
        _ => unreachable!("no such build on this architecture"),
    }
    true
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn run_avx512<D: Deviates>(batch: &mut BatchTrial, deviates: &mut D) {
    batch.run_lanes(deviates)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_avx2<D: Deviates>(batch: &mut BatchTrial, deviates: &mut D) {
    batch.run_lanes(deviates)
}
