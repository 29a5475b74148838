//! Messages the controller sends the server.

use serde::{Deserialize, Serialize};

use crate::exposure::TrialExposure;
use crate::link_auth::Bytes32;
use crate::trial::{FaultKind, Metrics, Outcome, TimingSummary, TrialId};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ControllerToServer {
    /// The controller's first frame on every connection: a fresh nonce the server's `Hello`
    /// must prove the link key over ([`crate::link_auth`]).
    Challenge {
        protocol_version: u32,
        nonce: Bytes32,
    },
    /// The hello was authentic; `proof` is the controller's proof of the same key.
    HelloAck {
        protocol_version: u32,
        proof: Bytes32,
        controller: String,
        loop_rate_hz: f64,
        /// "sim" or "udp".
        rig: String,
        lockstep: bool,
    },
    /// The trial is installed and its first tick has run.
    TrialStarted {
        trial_id: TrialId,
        tick: u64,
    },
    /// A decimated sample for display.
    Live(LiveSample),
    /// Part of the full-rate record, in order; all chunks precede the `TrialResult`.
    RecordChunk(RecordChunk),
    /// The trial ended; its record has been sent completely.
    TrialResult(Box<TrialResult>),
    /// Something went wrong, for a trial or the whole controller.
    Fault {
        trial_id: Option<TrialId>,
        kind: FaultKind,
        message: String,
    },
    Heartbeat {
        seq: u64,
    },
    Status(Box<Status>),
    /// Lockstep: the requested ticks have run; `tick` is the loop's tick counter now.
    Stepped {
        tick: u64,
    },
    /// A message was not acted upon (malformed, out of range, not allowed now); `trial_id`
    /// names the trial when the message was about one.
    Rejected {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        trial_id: Option<TrialId>,
        reason: String,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct LiveSample {
    pub trial_id: TrialId,
    /// Seconds since the trial started.
    pub t: f64,
    pub target_mm: f64,
    /// What the input device reads: intended hand position minus feedthrough (mm).
    pub device_mm: f64,
    pub cylinder_mm: f64,
    pub cab_accel_mm_s2: f64,
    /// `seq` of the newest operator input used (0 if none): round-trip timing.
    pub input_seq: u64,
    /// CLOCK_MONOTONIC time of the tick that produced it (µs; comparable only on the
    /// controller's host): delivery-latency measurements.
    pub stamp_us: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordChunk {
    pub trial_id: TrialId,
    /// Chunk number from 0.
    pub index: u32,
    /// Tick (from the trial's start) of the first sample.
    pub start_tick: u64,
    /// One array per channel of `trial::RECORD_CHANNELS`, all of the same length.
    pub channels: Vec<Vec<f32>>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrialResult {
    pub trial_id: TrialId,
    pub outcome: Outcome,
    pub metrics: Metrics,
    pub timing: TimingSummary,
    /// Sample period of the record (s).
    pub dt: f64,
    pub record_chunks: u32,
    /// ISO 2631-1 figures of the cab acceleration the trial ran (None from a controller
    /// that predates them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<TrialExposure>,
    /// When (s into the trial) cancellation's guard turned it off for the rest of the test;
    /// None when it never did or the test did not cancel (`docs/cancellation.md`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cancellation_off_at_s: Option<f64>,
    /// What an adaptive compensator's estimator and schedule did over the test (its last
    /// estimate, when it first trusted it, its retunes and its fallbacks to the fixed design);
    /// None for a fixed design.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptation: Option<crate::params::AdaptationStatus>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Status {
    pub estop_latched: bool,
    pub running_trials: Vec<TrialId>,
    pub tick: u64,
    pub overruns: u64,
    /// Messages and datagrams rejected since start (malformed or out of range).
    pub rejected_messages: u64,
    pub rejected_datagrams: u64,
    pub realtime: RealtimeStatus,
    pub rig: String,
    pub lockstep: bool,
}

/// What the operating system granted the loop thread.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeStatus {
    pub sched_fifo: bool,
    pub memory_locked: bool,
    pub pinned_cpu: Option<usize>,
}
