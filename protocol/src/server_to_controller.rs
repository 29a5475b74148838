//! Messages the server sends the controller.

use serde::{Deserialize, Serialize};

use crate::cancellation::CancellationModel;
use crate::exposure::ExposureAllowance;
use crate::link_auth::{Bytes32, LinkRole};
use crate::params::{
    BodyModel, CompensatorSpec, MAX_KBF, MachineCondition, ParamError, PlantParams, Seat, check,
};
use crate::trial::{InputSource, MAX_TRIAL_S, TargetSpec, TrialId};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ServerToController {
    /// The answer to the controller's `Challenge`, and the first message on a connection:
    /// the server's nonce and its proof of the link key ([`crate::link_auth`]). Answered by
    /// `HelloAck` or `Rejected` + close.
    Hello {
        protocol_version: u32,
        client: String,
        role: LinkRole,
        nonce: Bytes32,
        proof: Bytes32,
    },
    StartTrial(Box<StartTrial>),
    /// Stop a running trial early, as aborted with this reason.
    AbortTrial {
        trial_id: TrialId,
        reason: String,
    },
    /// The operator's intended hand position (mm of device travel) for a trial fed by the
    /// server; `seq` increases per trial and is echoed in live samples (round-trip timing).
    OperatorInput {
        trial_id: TrialId,
        seq: u64,
        position_mm: f64,
    },
    /// Keeps the link alive; the controller treats silence as a lost link.
    Heartbeat {
        seq: u64,
    },
    // The fieldless messages are empty struct variants, not unit variants: serde's
    // `deny_unknown_fields` refuses `{"type":"status","x":1}` only for struct variants.
    /// Emergency stop: every valve to zero at once, every trial faulted; latched.
    EStop {},
    /// Clears a latched E-stop.
    ResetEStop {},
    /// Asks for a `Status`.
    Status {},
    /// Lockstep mode only: run this many ticks, then answer `Stepped`.
    Step {
        ticks: u32,
    },
    /// Only to a controller started with `--lsl`: publish (or keep) the station's LSL signal
    /// stream, described with these codes; `trial_id`, when given, is the trial about to
    /// start there, whose ticks go to that stream. Sent when a subject is assigned to a
    /// station and before each of its tests.
    LslStation(Box<LslStation>),
}

/// Who a station's LSL signal stream is about (`ServerToController::LslStation`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LslStation {
    pub station_id: i64,
    pub station: String,
    pub study_id: i64,
    pub study: String,
    pub subject: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trial_id: Option<TrialId>,
}

/// The longest name or code an `LslStation` may carry (characters).
pub const MAX_LSL_TEXT: usize = 200;

impl LslStation {
    /// Refuses texts longer than [`MAX_LSL_TEXT`] or with control characters (they go into
    /// the stream's XML description).
    pub fn check(&self) -> Result<(), String> {
        for (field, text) in [
            ("station", &self.station),
            ("study", &self.study),
            ("subject", &self.subject),
        ] {
            if text.chars().count() > MAX_LSL_TEXT || text.chars().any(char::is_control) {
                return Err(format!(
                    "lsl_station.{field}: at most {MAX_LSL_TEXT} characters, no control characters"
                ));
            }
        }
        Ok(())
    }
}

/// Everything a trial needs. Parameters are recorded with the trial by the server.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartTrial {
    pub trial_id: TrialId,
    pub compensator: CompensatorSpec,
    /// The seat, on the wire under its old name `station`.
    #[serde(rename = "station")]
    pub seat: Seat,
    pub k_bf: f64,
    pub target: TargetSpec,
    pub duration_s: f64,
    pub input: InputSource,
    /// Simulated rig and body (ignored by a real rig, which has its own).
    #[serde(default)]
    pub plant: PlantParams,
    #[serde(default)]
    pub body: BodyModel,
    /// Seed of the simulated accelerometer noise.
    #[serde(default)]
    pub noise_seed: u64,
    /// Rate of the decimated live samples (Hz).
    #[serde(default = "default_live_rate")]
    pub live_rate_hz: f64,
    /// Operator input older than this stops the trial (ms).
    #[serde(default = "default_stale_ms")]
    pub stale_input_ms: f64,
    /// The cab-vibration interlock: RMS cab acceleration over a 1 s sliding window above
    /// this stops the trial (mm/s²).
    #[serde(default = "default_max_cab_rms")]
    pub max_cab_rms_mm_s2: f64,
    /// The in-loop exposure guard: what this test may still add to its subject's day
    /// (ISO 2631-1 W_d-weighted cab acceleration); the test stops (`exposure-budget`) once
    /// used up. None: no guard (a desk test, a bench run, the planner).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_allowance: Option<ExposureAllowance>,
    /// Model-based cancellation of the feedthrough (`docs/cancellation.md`): the device's
    /// reading less what this model predicts the cab adds to it. On the machine only, in a
    /// tracking test. None: no cancellation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cancellation: Option<CancellationModel>,
    /// The machine's condition (`params::MachineCondition`): the simulated rig is `plant`
    /// under it, while the compensator stays designed for `plant` — a fixed design meeting
    /// the field. A real rig is what it is; there the condition is what the lab says it
    /// stands on, recorded. Default (left out of the JSON): the thesis's rig.
    #[serde(default, skip_serializing_if = "MachineCondition::is_default")]
    pub condition: MachineCondition,
}

/// 6 m/s² RMS (why: the controller's `interlock::DEFAULT_LIMIT_MM_S2`).
pub const DEFAULT_MAX_CAB_RMS_MM_S2: f64 = 6000.0;

fn default_max_cab_rms() -> f64 {
    DEFAULT_MAX_CAB_RMS_MM_S2
}

fn default_live_rate() -> f64 {
    100.0
}

fn default_stale_ms() -> f64 {
    100.0
}

impl StartTrial {
    pub fn validate(&self) -> Result<(), ParamError> {
        self.compensator.validate()?;
        check("k_bf", self.k_bf, 0.0, MAX_KBF)?;
        self.target.validate()?;
        check("duration_s", self.duration_s, 0.001, MAX_TRIAL_S)?;
        self.plant.validate()?;
        self.condition.apply(&self.plant)?;
        self.body.validate()?;
        check("live_rate_hz", self.live_rate_hz, 1.0, 1000.0)?;
        check("stale_input_ms", self.stale_input_ms, 5.0, 10_000.0)?;
        check("max_cab_rms_mm_s2", self.max_cab_rms_mm_s2, 10.0, 1e6)?;
        if let Some(allowance) = &self.exposure_allowance {
            allowance.validate()?;
        }
        if let InputSource::Synthetic { operator, .. } = &self.input {
            operator.validate()?;
        }
        if let Some(model) = &self.cancellation {
            model.validate()?;
            // At the desk no body rides; in the identification test the device never reaches
            // the cylinder.
            let refused = match (&self.seat, &self.target) {
                (Seat::Off, _) => {
                    Some("at the desk no body rides: cancellation is for tests on the machine")
                }
                (_, TargetSpec::Identification { .. }) => Some(
                    "the identification test's device never reaches the cylinder: nothing to cancel",
                ),
                _ => None,
            };
            if let Some(message) = refused {
                return Err(ParamError::Invalid {
                    name: "cancellation",
                    message: message.into(),
                });
            }
        }
        // An identification test runs whole periods: the trial is exactly its transient and
        // recorded periods, so the estimator finds every period it expects.
        if let TargetSpec::Identification { excitation, .. } = &self.target {
            let want = excitation.duration_s();
            if (self.duration_s - want).abs() > 1e-9 * want {
                return Err(ParamError::Invalid {
                    name: "duration_s",
                    message: format!(
                        "{} s given; an identification test lasts its multisine's \
                         (transient_periods + periods) × period_s = {want} s",
                        self.duration_s
                    ),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod lsl_station_tests {
    use super::*;

    #[test]
    fn lsl_texts_are_refused_naming_the_field_when_too_long_or_with_control_characters() {
        let ok = LslStation {
            station_id: 1,
            station: "cab".into(),
            study_id: 2,
            study: "pilot".into(),
            subject: "S001".into(),
            trial_id: None,
        };
        assert_eq!(ok.check(), Ok(()));
        let long = LslStation {
            subject: "x".repeat(MAX_LSL_TEXT + 1),
            ..ok.clone()
        };
        assert!(long.check().unwrap_err().contains("lsl_station.subject"));
        let control = LslStation {
            station: "cab\n".into(),
            ..ok
        };
        assert!(control.check().unwrap_err().contains("lsl_station.station"));
    }
}
