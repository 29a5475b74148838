//! Messages the server sends the browsers: what a station shows (the subject's view, and
//! the experimenter's view of it), and the live sockets' events.
//!
//! *Invariant:* [`StationView`] and everything in it has no field that could carry a
//! compensator's name; only [`MonitorView`], for the experimenter, names it.

use serde::{Deserialize, Serialize};

use crate::controller_to_server::LiveSample;
use crate::params::{CompensatorKind, Seat};
use crate::records::{DoneReason, StationRole, TestPhase, TrialStatus};
use crate::study::{ConsentForm, StudyTexts, SurveyParams};

/// What a station shows its subject now.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StationView {
    #[serde(flatten)]
    pub phase: Phase<TestView>,
    pub station: StationInfo,
    /// The subject's last test stopped without counting; absent once a test ran after it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopped: Option<StopNotice>,
    /// The study's texts with their placeholders filled in (absent while no subject is
    /// assigned).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texts: Option<StudyTexts>,
}

/// What the subject is told about a test that was stopped: which one (blinded), how it ended
/// (`aborted`: by the experimenter or the E-stop; `incomplete`: a technical fault;
/// `invalid`: the display was hidden or stalled), and whether it will be repeated
/// (otherwise the experimenter decides) — as the very next test, or later.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StopNotice {
    pub label: String,
    pub status: TrialStatus,
    pub repeated: bool,
    /// The repeat is the subject's next test (absent, false, from servers before it was
    /// told apart).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub repeated_next: bool,
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
    /// A test failed as often as it may be repeated: the experimenter decides (repeat it
    /// or accept it as incomplete) before anything else runs. Never "done" meanwhile. A
    /// practice never completed holds the schedule before any scored test; a scored test,
    /// once every other is done.
    Held {
        subject: String,
        /// The test waiting for the decision (absent in messages of earlier releases).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        failed: Option<HeldTest>,
    },
    Done {
        subject: String,
        reason: DoneReason,
    },
}

/// The test a held schedule waits on: which (blinded), what kind, and how often it failed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct HeldTest {
    pub trial_id: i64,
    pub label: String,
    pub phase: TestPhase,
    pub attempts: i64,
}

/// A test as the subject sees it: blinded (no field for the compensator).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct TestView {
    pub trial_id: i64,
    /// "Controller k", "Practice" or "Identification".
    pub label: String,
    pub phase: TestPhase,
    /// What the subject is asked to do in an identification test (the practice's and the
    /// tests' texts are the study's `texts`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instructions: Option<String>,
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
    /// The station page's live socket; `None` when it has not connected since the server
    /// started.
    pub socket: Option<StationSocket>,
}

/// The station page's live socket (its newest one), for the experimenter: whether it is
/// open, how much operator input it sent, and why the server closed it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StationSocket {
    pub connected: bool,
    /// Messages within the station's rate limit (operator input is forwarded from these).
    pub accepted: u64,
    /// Messages over the rate limit, dropped unread.
    pub dropped: u64,
    /// Why the server closed it (a flood, a newer socket of the station, a too-large
    /// message); `None` while open or when the page closed it.
    pub closed_by_server: Option<String>,
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
    /// The E-stop latch: sent when the socket opens and whenever it changes. While latched
    /// the page shows "Stopped" and sends no input.
    #[serde(rename = "estop")]
    EStop { latched: bool },
}

/// Close codes of the station's WebSocket, so that the page can tell why it was closed.
pub mod station_close {
    /// A newer socket of the same station replaced this one (the page was opened again
    /// elsewhere): the old page must not reconnect, or the two would take turns.
    pub const REPLACED: u16 = 4001;
    /// The station kept sending far more input than its rate limit (RFC 6455: policy
    /// violation).
    pub const FLOOD: u16 = 1008;
    /// A message larger than the limit (RFC 6455: message too big).
    pub const TOO_BIG: u16 = 1009;
    /// Nothing (not even a pong) heard for too long: the peer is gone.
    pub const IDLE: u16 = 1001;
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
