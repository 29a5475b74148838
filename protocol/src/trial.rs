//! Types shared by both directions of the server ↔ controller link: what a trial runs and
//! what it produced.

use serde::{Deserialize, Serialize};

use crate::identification::{IdentificationTask, MultisineSpec};
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
    /// The identification test (`docs/identification.md`): the multisine is the cylinder
    /// reference itself, the person's hand is recorded but never reaches it (K_BF = 0 for
    /// the loop), and the trial lasts `excitation.duration_s()`.
    Identification {
        excitation: MultisineSpec,
        task: IdentificationTask,
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
            Self::Identification { excitation, .. } => excitation.validate(),
        }
    }

    /// The name `kind` carries on the wire.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Steps { .. } => "steps",
            Self::SweptSine { .. } => "swept-sine",
            Self::Trapezoid { .. } => "trapezoid",
            Self::Sampled { .. } => "sampled",
            Self::Identification { .. } => "identification",
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
    /// The in-loop exposure guard: the test's W_d-weighted cab acceleration used up what
    /// the subject's daily exposure budget had left (`StartTrial::exposure_allowance`).
    ExposureBudget,
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

/// One column of the full-rate record as the analysts' files carry it (the server's samples
/// export and `bdft-controller simulate --out` write the same columns, names, units and
/// number format from this one definition).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordColumn {
    /// Column name; it ends in the unit.
    pub name: &'static str,
    pub unit: &'static str,
    pub meaning: &'static str,
    /// Values are written to this many decimals (the column's resolution, 10^-decimals):
    /// `numbers::format_number`.
    pub decimals: u8,
}

/// Time since the trial's start, the first column of a record file (one row per tick).
pub const RECORD_TIME: RecordColumn = RecordColumn {
    name: "t_s",
    unit: "s",
    meaning: "time since the trial started (tick × sample period)",
    decimals: 3,
};

/// Positions are stored as f32 (about 7 significant digits: 0.01 µm at 100 mm), so 0.1 µm
/// is as fine as they mean anything.
const MM_DECIMALS: u8 = 4;

/// Channels of the full-rate record, in the order of `RecordChunk::channels`.
pub const RECORD_CHANNELS: [RecordColumn; 10] = [
    RecordColumn {
        name: "target_mm",
        unit: "mm",
        meaning: "pursuit target (cylinder position the subject is asked to follow)",
        decimals: MM_DECIMALS,
    },
    RecordColumn {
        name: "hand_mm",
        unit: "mm",
        meaning: "intended hand position (the operator's output before feedthrough)",
        decimals: MM_DECIMALS,
    },
    RecordColumn {
        name: "feedthrough_mm",
        unit: "mm",
        meaning: "hand motion forced by cab vibration (biodynamic feedthrough)",
        decimals: MM_DECIMALS,
    },
    RecordColumn {
        name: "cyl_ref_mm",
        unit: "mm",
        meaning: "cylinder reference the compensator's output sets",
        decimals: MM_DECIMALS,
    },
    RecordColumn {
        name: "valve_cmd",
        unit: "1",
        meaning: "valve command applied, after saturation (dimensionless)",
        decimals: 6,
    },
    RecordColumn {
        name: "cyl_pos_mm",
        unit: "mm",
        meaning: "measured cylinder position",
        decimals: MM_DECIMALS,
    },
    RecordColumn {
        name: "cab_accel_mm_s2",
        unit: "mm/s²",
        meaning: "measured fore-aft cab (seat) acceleration",
        decimals: 3,
    },
    RecordColumn {
        name: "device_mm",
        unit: "mm",
        meaning: "input device reading: intended hand position less the feedthrough",
        decimals: MM_DECIMALS,
    },
    RecordColumn {
        name: "tick_latency_us",
        unit: "µs",
        meaning: "wake-up latency of the real-time tick (0 in an offline simulation)",
        decimals: 1,
    },
    // Last: the columns of an earlier release keep their places.
    RecordColumn {
        name: "cancellation_mm",
        unit: "mm",
        meaning: "what model-based cancellation subtracted from the device reading (0: none); the cancelled signal is device_mm − cancellation_mm, and cyl_ref_mm is K_BF times it",
        decimals: MM_DECIMALS,
    },
];

/// Where the record channel called `name` is in `RECORD_CHANNELS`.
pub fn record_channel(name: &str) -> Option<usize> {
    RECORD_CHANNELS.iter().position(|c| c.name == name)
}
