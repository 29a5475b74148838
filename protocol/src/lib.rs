//! bdft-lab's wire types: every message that crosses a process boundary, the parameters
//! they carry, and their one encoding. Internals (nalgebra states, database rows) convert
//! to these at the boundary.
//!
//! - [`server_to_controller`] / [`controller_to_server`]: the TCP link, framed by
//!   [`framing`] (length-prefixed JSON), opened by the controller's `Challenge` and the
//!   server's `Hello` carrying [`PROTOCOL_VERSION`] and a proof of the shared key
//!   ([`link_auth`]).
//! - [`rig`]: the fixed binary UDP datagrams of a real rig and a haptic-device host.
//! - [`params`], [`trial`]: the data those messages carry.
//! - [`browser_to_server`] / [`server_to_browser`]: the stations' and the dashboard's
//!   messages (JSON bodies and WebSocket text); [`records`]: the states of the study's
//!   records (trial status, consent, station role) as the API and exports name them.
//!
//! Files (`docs/protocol.md` documents the wire): `framing`: 4-byte length + JSON, `FrameCodec`,
//! the one codec both ends of the link use, and `BlockingFramed` for blocking clients. `trial`:
//! what a trial runs and produces; `RECORD_CHANNELS`: the full-rate record's columns — name, unit,
//! meaning, resolution — that the stored record, the samples export and `simulate --out` all use.
//! `numbers`: the one number format of analysts' files: rounded to a column's resolution and 12
//! significant digits, no float noise. `params`: every parameter that crosses a process: plant,
//! body, seat, compensator designs, operator, step targets, each with its defaults and `validate`.
//! `browser_to_server` / `server_to_browser`: operator input, consent, survey answers, timing
//! reports, the station's `StationView`, the experimenter's `MonitorView`, the live sockets'
//! events. `exposure`: the 2002/44/EC action and limit values, a test's `TrialExposure`, the daily
//! `DoseSum` — A(8) and the day's VDV — and the `ExposureAllowance` a test on the machine starts
//! with. `records`: `TrialStatus` — `invalid` for a test whose display was hidden or stalled —,
//! `ConsentDecision`, `StationRole`, `DoneReason`, `TestPhase` — practice, scored test or
//! identification test —: the states the server's rows hold, each with its names and parse errors
//! that list them. `study`: study parameters, with the display limits `max_hidden_ms` and
//! `max_frame_gap_ms`, and the station's texts — consent form, instructions — with their
//! placeholders and the one renderer that fills them in from the parameters. `consent`: the consent
//! form and its `{procedure}`: what the study does, generated from the parameters, appended when a
//! lab's text leaves it out. `cancellation`: the model a test's model-based cancellation
//! predicts the body's feedthrough with. `link_auth`: the link key, key files, and the HMAC-SHA256 proofs of
//! the challenge–response both ends run before anything else. `hex`: the one text form of every
//! hash, key, token and signature: encode, decode, SHA-256 in hex. `PROTOCOL_VERSION` is exchanged
//! in the handshake. Golden tests pin the wire text (`golden.rs`, `golden_browser.rs`). The
//! `openapi` feature derives the OpenAPI schemas the server's document uses.
//!
//! *Invariants:* the controller and the server never define their own copies of these;
//! `StationView` has no field that could carry a compensator's name; messages without fields are
//! empty struct variants, so they refuse unknown fields too.

pub mod browser_to_server;
pub mod cancellation;
pub mod consent;
pub mod controller_to_server;
pub mod exposure;
pub mod framing;
pub mod hex;
pub mod identification;
pub mod link_auth;
pub mod numbers;
pub mod params;
pub mod records;
pub mod rig;
pub mod server_to_browser;
pub mod server_to_controller;
pub mod study;
pub mod trial;

/// Version of the server ↔ controller protocol; both ends must agree in the hello. 3: the
/// exposure guard (`StartTrial::exposure_allowance`, `TrialResult::exposure`, fault
/// `exposure-budget`) — a controller without it must not run a test that relies on it.
pub const PROTOCOL_VERSION: u32 = 3;

#[cfg(test)]
mod golden;
#[cfg(test)]
mod golden_browser;
