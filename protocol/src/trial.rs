//! Types shared by both directions of the server ↔ controller link: what a trial runs and
//! what it produced.

use serde::{Deserialize, Serialize};

use crate::params::{OperatorParams, ParamError, check};

/// Identifier the server gives a trial (its database id); echoed in every message about it.
pub type TrialId = u64;

/// The pursuit target, in mm of cylinder position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum TargetSpec {
    /// The protocol's random steps: `levels_mm[i]` holds from i·interval_s.
    Steps {
        interval_s: f64,
        levels_mm: Vec<f64>,
    },
    /// Linear swept sine f0 → f1 over the trial (bench test).
    SweptSine {
        amplitude_mm: f64,
        f0_hz: f64,
        f1_hz: f64,
    },
    /// Smoothed trapezoid (bench test).
    Trapezoid { amplitude_mm: f64, period_s: f64 },
    /// An uploaded reference (bench test): `samples_mm[i]` at i / sample_rate_hz, linear in
    /// between, the last sample held after the end.
    Sampled {
        sample_rate_hz: f64,
        samples_mm: Vec<f64>,
    },
}

/// Longest trial the controller accepts (s); bounds the memory a record preallocates.
pub const MAX_TRIAL_S: f64 = 1800.0;
/// Most step levels a target may carry.
pub const MAX_LEVELS: usize = 100_000;
/// Most samples an uploaded reference may carry (200 s at 1 kHz): bounds the upload and the
/// message that carries it.
pub const MAX_SAMPLES: usize = 200_000;

impl TargetSpec {
    pub fn validate(&self) -> Result<(), ParamError> {
        match self {
            Self::Steps {
                interval_s,
                levels_mm,
            } => {
                check("target.interval_s", *interval_s, 0.01, 600.0)?;
                if levels_mm.is_empty() || levels_mm.len() > MAX_LEVELS {
                    return Err(ParamError::Invalid {
                        name: "target.levels_mm",
                        message: format!(
                            "{} levels given; allowed: 1 to {MAX_LEVELS}",
                            levels_mm.len()
                        ),
                    });
                }
                for &l in levels_mm {
                    check("target.levels_mm", l, -1000.0, 1000.0)?;
                }
                Ok(())
            }
            Self::SweptSine {
                amplitude_mm,
                f0_hz,
                f1_hz,
            } => {
                check("target.amplitude_mm", *amplitude_mm, 0.0, 500.0)?;
                check("target.f0_hz", *f0_hz, 0.0, 100.0)?;
                check("target.f1_hz", *f1_hz, 0.0, 100.0)
            }
            Self::Trapezoid {
                amplitude_mm,
                period_s,
            } => {
                check("target.amplitude_mm", *amplitude_mm, 0.0, 500.0)?;
                check("target.period_s", *period_s, 0.1, 600.0)
            }
            Self::Sampled {
                sample_rate_hz,
                samples_mm,
            } => {
                check("target.sample_rate_hz", *sample_rate_hz, 1.0, 10_000.0)?;
                if !(2..=MAX_SAMPLES).contains(&samples_mm.len()) {
                    return Err(ParamError::Invalid {
                        name: "target.samples_mm",
                        message: format!(
                            "{} samples given; allowed: 2 to {MAX_SAMPLES}",
                            samples_mm.len()
                        ),
                    });
                }
                for &x in samples_mm {
                    check("target.samples_mm", x, -1000.0, 1000.0)?;
                }
                Ok(())
            }
        }
    }
}

/// Where the operator's intended hand position comes from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum InputSource {
    /// `OperatorInput` messages from the server (a browser's pointer or gamepad), held
    /// between samples.
    Server,
    /// Datagrams from a haptic-device host on the controller's input port, this channel.
    Udp { channel: u32 },
    /// The synthetic operator tracks the target (pilots, automated tests).
    Synthetic { operator: OperatorParams, seed: u64 },
    /// No operator: the target is the cylinder reference itself (bench tests).
    Reference,
}

/// Metrics over the full-rate record of a trial.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Metrics {
    pub ticks: u64,
    /// Mean-squared tracking error, target − cylinder position (mm²).
    pub mse_tracking_mm2: f64,
    /// Mean-squared measured cab acceleration ((mm/s²)²).
    pub ms_cab_accel: f64,
}

/// Percentiles of a timing histogram (µs).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Percentiles {
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
}

/// How the real-time loop kept time during a trial (or a benchmark).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct TimingSummary {
    pub ticks: u64,
    /// Deadlines missed by more than a period (those ticks were skipped, not caught up).
    pub overruns: u64,
    /// Wake-up time after the deadline.
    pub wake_latency_us: Percentiles,
    /// Time spent computing the tick (all trials).
    pub compute_us: Percentiles,
}

/// Why a trial or the controller faulted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// Operator input older than the allowed age during a trial.
    StaleInput,
    /// The real rig stopped answering.
    RigTimeout,
    /// The emergency stop was pressed.
    EStop,
    /// The server link was lost.
    LinkLost,
    /// The cab-vibration interlock: RMS cab acceleration over the sliding window above the
    /// trial's limit.
    CabVibration,
    /// A rig reading that cannot be true: not finite, the cylinder beyond its stroke, an
    /// acceleration no cab reaches, or a reply to a command never sent.
    RigImplausible,
    /// The controller process restarted or the trial could not continue for an internal
    /// reason.
    Internal,
}

/// How a trial ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "status", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Outcome {
    /// Ran its full duration.
    Complete,
    /// Stopped by the server (`AbortTrial`), with its reason.
    Aborted { reason: String },
    /// Stopped by a fault; the valve was set to zero at once.
    Faulted { fault: FaultKind, message: String },
}

/// Channels of the full-rate record, in the order of `RecordChunk::channels`.
pub const RECORD_CHANNELS: [&str; 9] = [
    "target_mm",
    "hand_mm",
    "feedthrough_mm",
    "cyl_ref_mm",
    "valve_cmd",
    "cyl_pos_mm",
    "cab_accel_mm_s2",
    "device_mm",
    "tick_latency_us",
];
