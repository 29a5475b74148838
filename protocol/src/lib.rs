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

pub mod browser_to_server;
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
