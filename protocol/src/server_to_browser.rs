//! Messages the server sends the browsers: what a station shows (the subject's view, and
//! the experimenter's view of it), and the live sockets' events.
//!
//! *Invariant:* [`StationView`] and everything in it has no field that could carry a
//! compensator's name; only [`MonitorView`], for the experimenter, names it.

use serde::{Deserialize, Serialize};

use crate::controller_to_server::LiveSample;
use crate::params::{CompensatorKind, Seat};
use crate::records::{DoneReason, StationRole};
use crate::study::{ConsentForm, SurveyParams};

/// What a station shows its subject now.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StationView {
    #[serde(flatten)]
    pub phase: Phase<TestView>,
    pub station: StationInfo,
}

/// The station itself, as its page shows it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StationInfo {
    pub name: String,
    pub role: StationRole,
}

/// Where the station's subject is in the protocol; `T` is how a test is shown.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "phase", rename_all = "snake_case")]
pub enum Phase<T> {
    /// No subject assigned.
    Waiting,
    Consent {
        subject: String,
        consent: ConsentForm,
    },
    Survey {
        subject: String,
        trial_id: i64,
        label: String,
        survey: SurveyParams,
    },
    /// The next step is at a seat this station does not serve.
    Move {
        subject: String,
        to: Seat,
    },
    /// The next test, waiting for the experimenter to start it.
    Ready {
        subject: String,
        test: T,
    },
    Running {
        subject: String,
        test: T,
    },
    Done {
        subject: String,
        reason: DoneReason,
    },
}

/// A test as the subject sees it: blinded (no field for the compensator).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct TestView {
    pub trial_id: i64,
    /// "Controller k" or "Practice".
    pub label: String,
    pub practice: bool,
    /// Position in the schedule (0 = practice).
    pub number: i64,
    /// Scored tests in the schedule.
    pub of: i64,
    pub duration_s: f64,
    #[serde(rename = "station")]
    pub seat: Seat,
    /// How much the display shakes with the simulated cab (0 off the machine).
    pub shake_gain: f64,
    pub target_range_mm: f64,
    pub k_bf: f64,
    pub started_at: Option<i64>,
}

/// What a station shows, for the experimenter's live monitor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct MonitorView {
    #[serde(flatten)]
    pub phase: Phase<MonitorTest>,
    pub station: MonitorStation,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct MonitorStation {
    pub id: i64,
    pub name: String,
    pub role: StationRole,
    pub subject_id: Option<i64>,
}

/// A test as the experimenter sees it: the subject's view and the compensator it runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct MonitorTest {
    #[serde(flatten)]
    pub test: TestView,
    #[serde(rename = "controller")]
    pub compensator: CompensatorKind,
}

/// A message on the station's WebSocket.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum StationEvent {
    /// Something changed: read the station's state again.
    Changed,
    /// A live sample of the station's running test.
    Live { sample: LiveSample },
}

/// A message on the dashboard's live feed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum MonitorEvent {
    Live {
        sample: LiveSample,
    },
    /// A trial's row changed.
    Trial {
        trial_id: i64,
    },
    /// The controller link went up or down.
    Controller {
        connected: bool,
    },
    /// The E-stop latch was set or cleared.
    #[serde(rename = "estop")]
    EStop {
        latched: bool,
    },
}
