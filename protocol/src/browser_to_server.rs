//! Messages the browsers send the server: the station's operator input (WebSocket text),
//! consent, survey answers and the display's timing figures (JSON bodies). Every one refuses
//! unknown fields.

use serde::{Deserialize, Serialize};

use crate::records::ConsentDecision;
use crate::study::SurveyAnswer;

/// A message on the station's WebSocket.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum StationMessage {
    /// The operator's intended hand position (mm of device travel) in the running test;
    /// `seq` increases and comes back in live samples (round-trip timing).
    Input {
        trial_id: i64,
        seq: u64,
        position_mm: f64,
    },
    /// How the display keeps up in the running test, sent when the page's visibility
    /// changes and every 250 ms while it runs: whether the page is hidden now, frames drawn
    /// so far, the longest gap between two frames, the time it was hidden (Page Visibility)
    /// and the input messages sent, all since the test started. The server stops the test
    /// and files it invalid beyond the study's display limits.
    Display {
        trial_id: i64,
        hidden: bool,
        frames: u64,
        longest_gap_ms: f64,
        hidden_ms: f64,
        inputs: u64,
    },
}

/// The subject's decision on the consent form shown.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ConsentRequest {
    pub decision: ConsentDecision,
}

/// The survey of one completed test: its id and the answers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(from = "SurveyFields")]
pub struct SurveySubmission {
    pub trial_id: i64,
    #[serde(flatten)]
    pub answer: SurveyAnswer,
}

/// The submission as it is read: every field written out, because serde cannot refuse
/// unknown fields through `flatten`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SurveyFields {
    trial_id: i64,
    accuracy: Option<i64>,
    speed: Option<i64>,
    smoothness: Option<i64>,
    controllability: Option<i64>,
    #[serde(default)]
    comment: String,
}

impl From<SurveyFields> for SurveySubmission {
    fn from(f: SurveyFields) -> Self {
        Self {
            trial_id: f.trial_id,
            answer: SurveyAnswer {
                accuracy: f.accuracy,
                speed: f.speed,
                smoothness: f.smoothness,
                controllability: f.controllability,
                comment: f.comment,
            },
        }
    }
}

/// Round trips of operator input to its echo in a live sample (ms).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct RttPercentiles {
    pub p50: f64,
    pub p95: f64,
    pub max: f64,
}

/// How the station's display kept up during a test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct TimingReport {
    pub trial_id: i64,
    /// Frames drawn.
    pub frames: u64,
    /// Frames that took longer than the display's period.
    pub long_frames: u64,
    /// The longest gap between two frames (ms).
    pub longest_gap_ms: f64,
    /// Time the page was hidden during the test (ms).
    pub hidden_ms: f64,
    /// Operator input messages sent a second, on average over the test.
    pub input_hz: f64,
    pub rtt_ms: RttPercentiles,
}

/// Longest round trip, frame gap or hidden time accepted (ms): ten minutes.
const MAX_RTT_MS: f64 = 600_000.0;
/// Highest input rate accepted: twice what the server lets a station send.
const MAX_INPUT_HZ: f64 = 1000.0;

impl TimingReport {
    /// Every figure finite and in range; the message names the field and the range.
    pub fn validate(&self) -> Result<(), String> {
        for (name, v) in [
            ("rtt_ms.p50", self.rtt_ms.p50),
            ("rtt_ms.p95", self.rtt_ms.p95),
            ("rtt_ms.max", self.rtt_ms.max),
            ("longest_gap_ms", self.longest_gap_ms),
            ("hidden_ms", self.hidden_ms),
        ] {
            if !v.is_finite() || !(0.0..=MAX_RTT_MS).contains(&v) {
                return Err(format!(
                    "{name}: a finite number of milliseconds from 0 to 600000"
                ));
            }
        }
        if !self.input_hz.is_finite() || !(0.0..=MAX_INPUT_HZ).contains(&self.input_hz) {
            return Err("input_hz: a finite rate from 0 to 1000 a second".into());
        }
        if self.long_frames > self.frames {
            return Err("long_frames cannot exceed frames".into());
        }
        Ok(())
    }
}
