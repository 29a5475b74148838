//! Offline simulation: the closed loop ticked as fast as the CPU allows, deterministic for a
//! given configuration and seed, built from the same `tick` as the real-time loop.

use serde::{Deserialize, Serialize};

use crate::closed_loop::{ClosedLoop, Drive, LoopSetup};
use crate::error::{DesignError, ParamError};
use crate::operator::{OperatorParams, SyntheticOperator};
use crate::params::{Station, check};
use crate::rng::Rng;
use crate::signals::{Signal, StepParams, StepTarget, SweptSine, Trapezoid};

/// The signal families `simulate` offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SignalKind {
    SweptSine,
    Trapezoid,
    Steps,
}

impl SignalKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::SweptSine => "swept-sine",
            Self::Trapezoid => "trapezoid",
            Self::Steps => "steps",
        }
    }

    /// Default run length: 30 s for the bench signals (as on the rig), one 140 s protocol
    /// test for the steps.
    pub fn default_duration_s(self) -> f64 {
        match self {
            Self::SweptSine | Self::Trapezoid => 30.0,
            Self::Steps => 140.0,
        }
    }
}

impl std::str::FromStr for SignalKind {
    type Err = ParamError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        [Self::SweptSine, Self::Trapezoid, Self::Steps]
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| ParamError::Invalid {
                name: "signal",
                message: format!("unknown signal {s:?}; valid: swept-sine, trapezoid, steps"),
            })
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    pub setup: LoopSetup,
    pub signal: SignalKind,
    pub duration_s: f64,
    pub seed: u64,
    pub operator: OperatorParams,
    pub steps: StepParams,
}

/// One 1 kHz sample of the record.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    pub t: f64,
    pub target: f64,
    pub hand: f64,
    pub feedthrough: f64,
    pub r_c: f64,
    pub valve: f64,
    pub y: f64,
    pub cab_accel: f64,
}

/// Column names of the record, in `Sample` order.
pub const SAMPLE_COLUMNS: [&str; 8] = [
    "t_s",
    "target_mm",
    "hand_mm",
    "feedthrough_mm",
    "cyl_ref_mm",
    "valve_cmd",
    "cyl_pos_mm",
    "cab_accel_mm_s2",
];

impl Sample {
    pub fn values(&self) -> [f64; 8] {
        [
            self.t,
            self.target,
            self.hand,
            self.feedthrough,
            self.r_c,
            self.valve,
            self.y,
            self.cab_accel,
        ]
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimSummary {
    pub compensator: String,
    pub signal: String,
    pub station: String,
    pub kbf: f64,
    pub duration_s: f64,
    pub ticks: u64,
    pub seed: u64,
    /// Mean-squared tracking error, target − cylinder position (mm²).
    pub mse_tracking_mm2: f64,
    /// Mean-squared measured cab acceleration ((mm/s²)²).
    pub ms_cab_accel: f64,
    /// Realized target statistics (steps only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_mean_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_std_mm: Option<f64>,
}

/// Streaming accumulator of the trial metrics over the full-rate record.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Metrics {
    pub ticks: u64,
    sum_sq_error: f64,
    sum_sq_accel: f64,
}

impl Metrics {
    #[inline]
    pub fn add(&mut self, target: f64, y: f64, cab_accel: f64) {
        self.ticks += 1;
        self.sum_sq_error += (target - y) * (target - y);
        self.sum_sq_accel += cab_accel * cab_accel;
    }
    pub fn mse_tracking(&self) -> f64 {
        self.sum_sq_error / self.ticks.max(1) as f64
    }
    pub fn ms_cab_accel(&self) -> f64 {
        self.sum_sq_accel / self.ticks.max(1) as f64
    }
}

/// Runs the configured simulation; `on_sample` sees every tick's record.
pub fn simulate(
    cfg: &SimConfig,
    mut on_sample: impl FnMut(&Sample),
) -> Result<SimSummary, DesignError> {
    let dt = cfg.setup.loop_params.dt;
    check("duration_s", cfg.duration_s, dt, 3600.0)?;
    let bench = cfg.signal != SignalKind::Steps;
    if bench && cfg.setup.station == Station::On {
        return Err(ParamError::Invalid {
            name: "station",
            message: format!(
                "the {} bench signal drives the cylinder reference directly (no operator, no feedthrough); use station off or signal steps",
                cfg.signal.name()
            ),
        }
        .into());
    }
    let signal = match cfg.signal {
        SignalKind::SweptSine => Signal::SweptSine(SweptSine::bench(cfg.duration_s)),
        SignalKind::Trapezoid => Signal::Trapezoid(Trapezoid::bench()),
        SignalKind::Steps => {
            Signal::Steps(StepTarget::generate(&cfg.steps, cfg.duration_s, cfg.seed)?)
        }
    };
    let mut lp = ClosedLoop::new(
        &cfg.setup,
        Rng::derive(cfg.seed, Rng::ACCEL_NOISE).next_u64(),
    )?;
    let mut operator =
        SyntheticOperator::new(cfg.operator, dt, cfg.setup.loop_params.k_bf, cfg.seed)?;
    let ticks = (cfg.duration_s / dt).round() as u64;
    let mut metrics = Metrics::default();
    for k in 0..ticks {
        let t = k as f64 * dt;
        let target = signal.at(t);
        let drive = if bench {
            Drive::Reference(target)
        } else {
            Drive::Hand(operator.step(target, lp.last_measurement().y))
        };
        let r = lp.tick(drive);
        metrics.add(target, r.y, r.cab_accel);
        on_sample(&Sample {
            t,
            target,
            hand: r.hand,
            feedthrough: r.feedthrough,
            r_c: r.r_c,
            valve: r.valve,
            y: r.y,
            cab_accel: r.cab_accel,
        });
    }
    let (target_mean_mm, target_std_mm) = match &signal {
        Signal::Steps(s) => (Some(s.mean_mm), Some(s.std_mm)),
        _ => (None, None),
    };
    Ok(SimSummary {
        compensator: cfg.setup.compensator.kind().name().to_string(),
        signal: cfg.signal.name().to_string(),
        station: cfg.setup.station.as_str().to_string(),
        kbf: cfg.setup.loop_params.k_bf,
        duration_s: ticks as f64 * dt,
        ticks,
        seed: cfg.seed,
        mse_tracking_mm2: metrics.mse_tracking(),
        ms_cab_accel: metrics.ms_cab_accel(),
        target_mean_mm,
        target_std_mm,
    })
}
