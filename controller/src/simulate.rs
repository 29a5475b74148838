//! Offline simulation: the closed loop ticked as fast as the CPU allows, deterministic for a
//! given configuration and seed, built from the same `tick` as the real-time loop.

use serde::{Deserialize, Serialize};

use crate::closed_loop::{ClosedLoop, LoopSetup};
use crate::error::{DesignError, ParamError};
use crate::operator::{OperatorParams, SyntheticOperator};
use crate::params::{MachineCondition, Seat, check};
use crate::rng::Rng;
pub use crate::runner::Sample;
use crate::runner::{HandSource, TrialRunner};
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
    /// The cab-vibration interlock's limit (mm/s² RMS over 1 s), or none (bench signals
    /// have no person in the cab).
    pub max_cab_rms_mm_s2: Option<f64>,
    /// The machine's condition: the compensator is designed for `setup.plant` and runs on
    /// that rig under the condition (default: the thesis's rig).
    pub condition: MachineCondition,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimSummary {
    pub compensator: String,
    pub signal: String,
    /// The seat (`on`/`off`; the output's key: `station`).
    #[serde(rename = "station")]
    pub seat: String,
    pub kbf: f64,
    pub duration_s: f64,
    pub ticks: u64,
    pub seed: u64,
    /// Mean-squared tracking error, target − cylinder position (mm²).
    pub mse_tracking_mm2: f64,
    /// Mean-squared measured cab acceleration ((mm/s²)²).
    pub ms_cab_accel: f64,
    /// ISO 2631-1 W_d-weighted r.m.s. of the cab acceleration (m/s²) and its vibration dose
    /// value (m/s^1.75), as the loop measures them (`exposure`).
    pub cab_aw_m_s2: f64,
    pub cab_vdv_m_s175: f64,
    /// Realized target statistics (steps only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_mean_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_std_mm: Option<f64>,
    /// `complete`, or `cab-vibration` when the interlock stopped the run.
    pub outcome: String,
    /// When the interlock stopped the run (s), and the RMS it measured (mm/s²).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stopped_at_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stop_rms_mm_s2: Option<f64>,
}

/// Runs the configured simulation; `on_sample` sees every tick's record.
pub fn simulate(
    cfg: &SimConfig,
    mut on_sample: impl FnMut(&Sample),
) -> Result<SimSummary, DesignError> {
    let dt = cfg.setup.loop_params.dt;
    check("duration_s", cfg.duration_s, dt, 3600.0)?;
    let bench = cfg.signal != SignalKind::Steps;
    if bench && cfg.setup.seat == Seat::On {
        return Err(ParamError::Invalid {
            name: "station",
            message: format!(
                "the {} bench signal drives the cylinder reference directly (no operator, no feedthrough); use station off or signal steps",
                cfg.signal.name()
            ),
        }
        .into());
    }
    let (signal, stats) = match cfg.signal {
        SignalKind::SweptSine => (Signal::SweptSine(SweptSine::bench(cfg.duration_s)), None),
        SignalKind::Trapezoid => (Signal::Trapezoid(Trapezoid::bench()), None),
        SignalKind::Steps => {
            let t = StepTarget::generate(&cfg.steps, cfg.duration_s, cfg.seed)?;
            (t.signal(), Some((t.mean_mm, t.std_mm)))
        }
    };
    let noise_seed = Rng::derive(cfg.seed, Rng::ACCEL_NOISE).next_u64();
    let lp = ClosedLoop::new(&cfg.setup, noise_seed)?
        .with_rig(cfg.condition.apply(&cfg.setup.plant)?, noise_seed)?;
    let hand = if bench {
        HandSource::Reference
    } else {
        HandSource::Synthetic(SyntheticOperator::new(
            cfg.operator,
            dt,
            cfg.setup.loop_params.k_bf,
            cfg.seed,
        )?)
    };
    let mut runner = TrialRunner::new(signal, lp, hand, dt, cfg.duration_s);
    if let Some(limit) = cfg.max_cab_rms_mm_s2 {
        check("max_cab_rms_mm_s2", limit, 10.0, 1e6)?;
        runner = runner.with_interlock(limit);
    }
    while !runner.done() && !runner.tripped() {
        on_sample(&runner.tick(0.0));
    }
    let stop = runner.tripped().then(|| {
        (
            runner.progress().0 as f64 * dt,
            runner.interlock().map_or(0.0, |il| il.rms()),
        )
    });
    let metrics = runner.metrics();
    let (exposure, _) = runner.exposure();
    let (target_mean_mm, target_std_mm) = (stats.map(|s| s.0), stats.map(|s| s.1));
    Ok(SimSummary {
        compensator: cfg.setup.compensator.kind().name().to_string(),
        signal: cfg.signal.name().to_string(),
        seat: cfg.setup.seat.as_str().to_string(),
        kbf: cfg.setup.loop_params.k_bf,
        duration_s: metrics.ticks as f64 * dt,
        ticks: metrics.ticks,
        seed: cfg.seed,
        mse_tracking_mm2: metrics.mse_tracking_mm2,
        ms_cab_accel: metrics.ms_cab_accel,
        cab_aw_m_s2: exposure.aw_m_s2,
        cab_vdv_m_s175: exposure.vdv_m_s175,
        target_mean_mm,
        target_std_mm,
        outcome: if stop.is_some() {
            "cab-vibration"
        } else {
            "complete"
        }
        .to_string(),
        stopped_at_s: stop.map(|s| s.0),
        stop_rms_mm_s2: stop.map(|s| s.1),
    })
}
