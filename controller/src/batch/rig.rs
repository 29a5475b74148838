//! The simulated rig for every lane at once: filters, plant, body, compensators and the
//! vibration interlock, each built from its scalar counterpart (so designs, validation and
//! coefficients stay in one place) and stepped with the same operations in the same order
//! as the scalar `step`, one loop over the lanes per operation.

use crate::compensator::{CabSignal, Compensator, Lqr, Pid, Prefilter};
use crate::filters::{Biquad, FirstOrder};
use crate::interlock::VibrationInterlock;
use crate::model::{Body, Plant, engine, engine_advance, idx, transmissibility};
use crate::params::BodyModel;
use crate::params::PlantParams;
use crate::shaper::Shaper;
use crate::state::LinearState;

use super::{LANES, Lanes, ZERO};

/// `model::saturate` written as selects (no `f64::clamp`, whose assertion and branches
/// keep the compiler from vectorizing a loop over lanes): the same value for every input.
#[inline(always)]
pub(crate) fn saturate_lane(v: f64, v_max: f64) -> f64 {
    let clamped = if v < -v_max {
        -v_max
    } else if v > v_max {
        v_max
    } else {
        v
    };
    if v.is_finite() { clamped } else { 0.0 }
}

/// A biquad per lane, each with its own coefficients.
#[derive(Debug, Clone)]
pub(crate) struct BiquadLanes {
    b: [Lanes; 3],
    a: [Lanes; 2],
    z: [Lanes; 2],
}

impl BiquadLanes {
    pub(crate) fn new(filters: &[Biquad; LANES]) -> Self {
        let mut s = Self {
            b: [ZERO; 3],
            a: [ZERO; 2],
            z: [ZERO; 2],
        };
        for (l, f) in filters.iter().enumerate() {
            s.retune(l, f);
            s.z[0][l] = f.z[0];
            s.z[1][l] = f.z[1];
        }
        s
    }

    /// Lane `l` takes `f`'s coefficients and keeps its state (`Biquad::retune`).
    pub(crate) fn retune(&mut self, l: usize, f: &Biquad) {
        let (b, a) = f.coefficients();
        for k in 0..3 {
            self.b[k][l] = b[k];
        }
        self.a[0][l] = a[1];
        self.a[1][l] = a[2];
    }

    #[inline(always)]
    pub(crate) fn step(&mut self, u: &Lanes) -> Lanes {
        let mut y = ZERO;
        for l in 0..LANES {
            y[l] = self.b[0][l] * u[l] + self.z[0][l];
            self.z[0][l] = self.b[1][l] * u[l] - self.a[0][l] * y[l] + self.z[1][l];
            self.z[1][l] = self.b[2][l] * u[l] - self.a[1][l] * y[l];
        }
        y
    }
}

/// A first-order section with one design for all lanes.
#[derive(Debug, Clone)]
pub(crate) struct FirstOrderLanes {
    f: FirstOrder,
    z: Lanes,
}

impl FirstOrderLanes {
    pub(crate) fn new(f: FirstOrder) -> Self {
        Self { f, z: [f.z; LANES] }
    }

    #[inline(always)]
    pub(crate) fn step(&mut self, u: &Lanes) -> Lanes {
        let FirstOrder { b0, b1, a1, .. } = self.f;
        let mut y = ZERO;
        for l in 0..LANES {
            y[l] = b0 * u[l] + self.z[l];
            self.z[l] = b1 * u[l] - a1 * y[l];
        }
        y
    }
}

/// `Plant` for every lane: one discretized model, a state per lane.
#[derive(Debug, Clone)]
pub(crate) struct PlantLanes {
    /// Ad by rows; its rows 4–6 (the cylinder) are zero in columns 0–3 (the structure's
    /// states), and their sums start at column 4: a sum that starts with exact zeros times
    /// finite states has the same value without them.
    ad: [[f64; 7]; 7],
    bd: [f64; 7],
    pub(crate) x: [Lanes; 7],
    v_max: f64,
    dead_band: f64,
    stroke_mm: f64,
    pub(crate) accel_noise_std: f64,
    /// The rig's parameters (the engine tone's), and the tone's phase: one for every lane,
    /// as every lane's trial starts at the same tick.
    params: PlantParams,
    dt: f64,
    engine_phase: f64,
}

impl PlantLanes {
    /// From the lanes' plants, which must share one model (the caller checks the params).
    pub(crate) fn new(plants: &[&Plant; LANES]) -> Result<Self, String> {
        let (ad, bd) = plants[0].discrete();
        if (idx::Y..7).any(|i| (0..idx::Y).any(|j| ad[(i, j)] != 0.0)) {
            return Err("the discretized cylinder sees the structure's states".into());
        }
        let p = plants[0].params();
        let mut x = [ZERO; 7];
        for (l, pl) in plants.iter().enumerate() {
            for (i, xi) in x.iter_mut().enumerate() {
                xi[l] = pl.state()[i];
            }
        }
        Ok(Self {
            ad: std::array::from_fn(|i| std::array::from_fn(|j| ad[(i, j)])),
            bd: std::array::from_fn(|i| bd[i]),
            x,
            v_max: p.v_max,
            dead_band: p.dead_band,
            stroke_mm: p.stroke_mm,
            accel_noise_std: p.accel_noise_std,
            params: *p,
            dt: plants[0].dt(),
            engine_phase: plants[0].engine_phase,
        })
    }

    /// `Plant::measure`'s accelerometer reading given this tick's deviates.
    #[inline(always)]
    pub(crate) fn cab_accel(&self, deviates: &Lanes) -> Lanes {
        let mut a = ZERO;
        let engine = engine(&self.params, self.engine_phase);
        for l in 0..LANES {
            a[l] = self.x[idx::XC_DD][l] + self.accel_noise_std * deviates[l] + engine;
        }
        a
    }

    /// `Plant::step`. One loop over the lanes around the whole update, each lane's
    /// arithmetic inside it: the form the loop vectorizer takes reliably.
    #[inline(always)]
    pub(crate) fn step(&mut self, v: &Lanes) {
        self.engine_phase = engine_advance(&self.params, self.engine_phase, self.dt);
        let s = self.stroke_mm;
        for l in 0..LANES {
            let v = saturate_lane(v[l], self.v_max);
            let past_band = v - self.dead_band.copysign(v);
            let applied = if v.abs() <= self.dead_band {
                0.0
            } else {
                past_band
            };
            let x: [f64; 7] = std::array::from_fn(|j| self.x[j][l]);
            let mut next = [0.0; 7];
            for (i, row) in self.ad.iter().enumerate() {
                let from = if i < idx::Y { 0 } else { idx::Y };
                let mut acc = row[from] * x[from];
                for j in from + 1..7 {
                    acc += row[j] * x[j];
                }
                next[i] = acc + self.bd[i] * applied;
            }
            // Hard end stops, as selects.
            let y = next[idx::Y];
            let stopped = y.abs() > s;
            let dir = y.signum();
            next[idx::Y] = if stopped { s * dir } else { y };
            for i in [idx::Y_D, idx::Y_DD] {
                next[i] = if stopped && next[i] * dir > 0.0 {
                    0.0
                } else {
                    next[i]
                };
            }
            for (state, value) in self.x.iter_mut().zip(next) {
                state[l] = value;
            }
        }
    }
}

/// `Body` for every lane: one model kind, each lane's own parameters.
#[derive(Debug, Clone)]
pub(crate) enum BodyLanes {
    Rigid {
        k_h: Lanes,
    },
    SingleResonance {
        filter: BiquadLanes,
    },
    Seated {
        k_h: Lanes,
        torso: BiquadLanes,
        arm: BiquadLanes,
        models: [BodyModel; LANES],
        grip: Lanes,
        dt: f64,
    },
}

impl BodyLanes {
    /// From the lanes' bodies; None unless they are all of one kind.
    pub(crate) fn new(bodies: &[&Body; LANES]) -> Option<Self> {
        let models: [BodyModel; LANES] = std::array::from_fn(|l| bodies[l].model);
        let k_h: Lanes = std::array::from_fn(|l| match models[l] {
            BodyModel::RigidMass { k_h }
            | BodyModel::SingleResonance { k_h, .. }
            | BodyModel::Seated { k_h, .. } => k_h,
        });
        let same = |f: fn(&BodyModel) -> bool| models.iter().all(f);
        let filters = |pick: fn(&Body) -> Option<Biquad>| -> Option<BiquadLanes> {
            let fs: Vec<Biquad> = bodies.iter().map(|b| pick(b)).collect::<Option<_>>()?;
            Some(BiquadLanes::new(&fs.try_into().ok()?))
        };
        if same(|m| matches!(m, BodyModel::RigidMass { .. })) {
            Some(Self::Rigid { k_h })
        } else if same(|m| matches!(m, BodyModel::SingleResonance { .. })) {
            Some(Self::SingleResonance {
                filter: filters(|b| b.filter)?,
            })
        } else if same(|m| matches!(m, BodyModel::Seated { .. })) {
            Some(Self::Seated {
                k_h,
                torso: filters(|b| b.filter)?,
                arm: filters(|b| b.arm)?,
                models,
                grip: std::array::from_fn(|l| bodies[l].grip),
                dt: bodies[0].dt,
            })
        } else {
            None
        }
    }

    /// `Body::step`.
    #[inline(always)]
    pub(crate) fn step(&mut self, cab_displacement: &Lanes) -> Lanes {
        let mut h = ZERO;
        match self {
            Self::Rigid { k_h } => {
                for l in 0..LANES {
                    h[l] = k_h[l] * cab_displacement[l];
                }
            }
            Self::SingleResonance { filter } => h = filter.step(cab_displacement),
            Self::Seated {
                k_h, torso, arm, ..
            } => {
                let hand = arm.step(&torso.step(cab_displacement));
                for l in 0..LANES {
                    h[l] = k_h[l] * (cab_displacement[l] - hand[l]);
                }
            }
        }
        h
    }

    /// `Body::set_grip` for every lane.
    pub(crate) fn set_grip(&mut self, grips: &Lanes) {
        if let Self::Seated {
            arm,
            models,
            grip,
            dt,
            ..
        } = self
        {
            for l in 0..LANES {
                let g = grips[l];
                if let BodyModel::Seated {
                    arm_f_hz, arm_zeta, ..
                } = models[l]
                    && g != grip[l]
                    && g.is_finite()
                    && g > 0.0
                {
                    grip[l] = g;
                    arm.retune(l, &transmissibility(1.0, arm_f_hz * g, arm_zeta, *dt));
                }
            }
        }
    }
}

/// `Pid` for every lane.
#[derive(Debug, Clone)]
pub(crate) struct PidLanes {
    kp: f64,
    ki_dt: f64,
    derivative: FirstOrderLanes,
    integral: Lanes,
    v_max: f64,
}

impl PidLanes {
    fn new(pid: &Pid) -> Self {
        Self {
            kp: pid.kp,
            ki_dt: pid.ki_dt,
            derivative: FirstOrderLanes::new(pid.derivative),
            integral: [pid.integral; LANES],
            v_max: pid.v_max,
        }
    }

    #[inline(always)]
    fn step(&mut self, e: &Lanes) -> Lanes {
        let e = finite(e);
        let d = self.derivative.step(&e);
        let mut v = ZERO;
        for l in 0..LANES {
            let unsat = self.kp * e[l] + self.integral[l] + d[l];
            v[l] = saturate_lane(unsat, self.v_max);
            let winding_up =
                (unsat > self.v_max && e[l] > 0.0) | (unsat < -self.v_max && e[l] < 0.0);
            let integral = self.integral[l];
            self.integral[l] = if winding_up {
                integral
            } else {
                integral + self.ki_dt * e[l]
            };
        }
        v
    }
}

/// `Shaper` for every lane: one set of taps, a delay line per lane.
#[derive(Debug, Clone)]
pub(crate) struct ShaperLanes {
    taps: Vec<(usize, f64)>,
    buf: Vec<Lanes>,
    head: usize,
}

impl ShaperLanes {
    fn new(s: &Shaper) -> Self {
        Self {
            taps: s.taps().to_vec(),
            buf: vec![ZERO; s.state_len() + 1],
            head: 0,
        }
    }

    #[inline(always)]
    fn step(&mut self, r: &Lanes) -> Lanes {
        let len = self.buf.len();
        self.buf[self.head] = *r;
        let mut out = ZERO;
        for &(d, a) in &self.taps {
            // head + len − d < 2·len: one conditional subtraction, not a division.
            let at = self.head + len - d;
            let past = &self.buf[if at >= len { at - len } else { at }];
            for l in 0..LANES {
                out[l] += a * past[l];
            }
        }
        self.head = if self.head + 1 == len {
            0
        } else {
            self.head + 1
        };
        out
    }
}

#[derive(Debug, Clone)]
pub(crate) enum PrefilterLanes {
    None,
    Notch(BiquadLanes),
    Shaper(ShaperLanes),
}

#[derive(Debug, Clone)]
enum CabLanes {
    Velocity {
        highpass: FirstOrderLanes,
        leak: FirstOrderLanes,
    },
    Acceleration,
}

/// `Lqr` for every lane: one design, an observer state per lane.
#[derive(Debug, Clone)]
pub(crate) struct LqrLanes {
    k: [f64; 7],
    nx: [f64; 7],
    phi: [[f64; 7]; 7],
    gamma_u: [f64; 7],
    gamma_z: [[f64; 2]; 7],
    xhat: [Lanes; 7],
    rate: FirstOrderLanes,
    cab: CabLanes,
    k_p: f64,
    v_max: f64,
}

/// Zero in place of a non-finite value, as the scalar steps sanitize their inputs.
#[inline(always)]
fn finite(x: &Lanes) -> Lanes {
    let mut out = ZERO;
    for l in 0..LANES {
        out[l] = if x[l].is_finite() { x[l] } else { 0.0 };
    }
    out
}

impl LqrLanes {
    fn new(q: &Lqr) -> Self {
        Self {
            k: std::array::from_fn(|j| q.k[j]),
            nx: std::array::from_fn(|j| q.nx[j]),
            phi: std::array::from_fn(|i| std::array::from_fn(|j| q.phi[(i, j)])),
            gamma_u: std::array::from_fn(|i| q.gamma_u[i]),
            gamma_z: std::array::from_fn(|i| [q.gamma_z[(i, 0)], q.gamma_z[(i, 1)]]),
            xhat: std::array::from_fn(|i| [q.xhat[i]; LANES]),
            rate: FirstOrderLanes::new(q.rate),
            cab: match q.cab {
                CabSignal::Velocity { highpass, leak } => CabLanes::Velocity {
                    highpass: FirstOrderLanes::new(highpass),
                    leak: FirstOrderLanes::new(leak),
                },
                CabSignal::Acceleration => CabLanes::Acceleration,
            },
            k_p: q.k_p,
            v_max: q.v_max,
        }
    }

    #[inline(always)]
    fn step(&mut self, r_c: &Lanes, y: &Lanes, cab_accel: &Lanes) -> Lanes {
        let (y, a, r_c) = (finite(y), finite(cab_accel), finite(r_c));
        let y_rate = self.rate.step(&y);
        let cab = match &mut self.cab {
            CabLanes::Velocity { highpass, leak } => leak.step(&highpass.step(&a)),
            CabLanes::Acceleration => a,
        };
        // One loop over the lanes around the whole update, each lane's arithmetic inside it
        // (the loop vectorizer's form): split into a loop per operation, the compiler
        // vectorized this step across rows and scalarized the division.
        let mut v = ZERO;
        for l in 0..LANES {
            let x: [f64; 7] = std::array::from_fn(|j| self.xhat[j][l]);
            let mut u = self.k[0] * (x[0] - self.nx[0] * r_c[l]);
            for j in 1..7 {
                u += self.k[j] * (x[j] - self.nx[j] * r_c[l]);
            }
            v[l] = saturate_lane(self.k_p * (-u - y_rate[l]), self.v_max);
            let u_applied = v[l] / self.k_p + y_rate[l];
            for i in 0..7 {
                let row = &self.phi[i];
                let mut acc = row[0] * x[0];
                for j in 1..7 {
                    acc += row[j] * x[j];
                }
                let [gy, gc] = self.gamma_z[i];
                self.xhat[i][l] = acc + self.gamma_u[i] * u_applied + (gy * y[l] + gc * cab[l]);
            }
        }
        v
    }
}

/// `Compensator` for every lane.
#[derive(Debug, Clone)]
pub(crate) enum CompensatorLanes {
    Pid { pre: PrefilterLanes, pid: PidLanes },
    Lqr(LqrLanes),
}

impl CompensatorLanes {
    /// From one lane's compensator: every lane runs the same design, from its state. An
    /// adaptive design is refused: its estimate, and so its design, is each trial's own.
    pub(crate) fn new(c: &Compensator) -> Result<Self, String> {
        Ok(match c {
            Compensator::Pid { pre, pid } => Self::Pid {
                pre: match pre {
                    Prefilter::None => PrefilterLanes::None,
                    Prefilter::Notch(f) => PrefilterLanes::Notch(BiquadLanes::new(&[*f; LANES])),
                    Prefilter::Shaper(s) => PrefilterLanes::Shaper(ShaperLanes::new(s)),
                },
                pid: PidLanes::new(pid),
            },
            Compensator::Lqr(q) => Self::Lqr(LqrLanes::new(q)),
            Compensator::Adaptive(_) => {
                return Err("an adaptive design's trials run one at a time, not batched".into());
            }
        })
    }

    /// `Compensator::step`: cylinder references and measurements → saturated commands.
    #[inline(always)]
    pub(crate) fn step(&mut self, r_c: &Lanes, y: &Lanes, cab_accel: &Lanes) -> Lanes {
        match self {
            Self::Pid { pre, pid } => {
                let r = match pre {
                    PrefilterLanes::None => *r_c,
                    PrefilterLanes::Notch(f) => f.step(r_c),
                    PrefilterLanes::Shaper(s) => s.step(r_c),
                };
                let mut e = ZERO;
                for l in 0..LANES {
                    e[l] = r[l] - y[l];
                }
                pid.step(&e)
            }
            Self::Lqr(q) => q.step(r_c, y, cab_accel),
        }
    }
}

/// `VibrationInterlock` for every lane: one window length and limit.
#[derive(Debug, Clone)]
pub(crate) struct InterlockLanes {
    squares: Vec<Lanes>,
    next: usize,
    filled: bool,
    sum: Lanes,
    pass_sum: Lanes,
    limit_sq: f64,
}

impl InterlockLanes {
    pub(crate) fn new(il: &VibrationInterlock) -> Self {
        Self {
            squares: vec![ZERO; il.squares.len()],
            next: 0,
            filled: false,
            sum: ZERO,
            pass_sum: ZERO,
            limit_sq: il.limit_sq,
        }
    }

    /// `VibrationInterlock::update`: which lanes trip on this sample.
    #[inline(always)]
    pub(crate) fn update(&mut self, accel_mm_s2: &Lanes) -> [bool; LANES] {
        // On local copies: stores into the ring (heap) between loads of the sums would make
        // the compiler assume they alias and keep it from vectorizing.
        let old = self.squares[self.next];
        let (mut sq, mut sum, mut pass_sum) = (ZERO, self.sum, self.pass_sum);
        for l in 0..LANES {
            let a = accel_mm_s2[l];
            sq[l] = if a.is_finite() { a * a } else { f64::INFINITY };
            sum[l] += sq[l] - old[l];
            pass_sum[l] += sq[l];
        }
        self.squares[self.next] = sq;
        self.sum = sum;
        self.pass_sum = pass_sum;
        self.next += 1;
        if self.next == self.squares.len() {
            self.next = 0;
            self.filled = true;
            self.sum = self.pass_sum;
            self.pass_sum = ZERO;
        }
        let n = self.squares.len() as f64;
        let mut trips = [false; LANES];
        for l in 0..LANES {
            let mean_square = self.sum[l].max(0.0) / n;
            trips[l] = sq[l].is_infinite() | (self.filled & (mean_square > self.limit_sq));
        }
        trips
    }
}
