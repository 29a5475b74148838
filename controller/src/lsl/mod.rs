//! Lab Streaming Layer (LSL) streams, published only when `--lsl` is given (no LSL socket is
//! opened otherwise: discovery answers multicast and broadcast queries).
//!
//! Per station two streams: the 1 kHz signals of its tests, published here in the
//! controller process from the loop's ticks ([`tap`] hands them over, [`publisher`] sends
//! them), and its irregular markers, published by the server, which knows the protocol's
//! events. [`streams`] describes both (names, channels with units, study, station and
//! subject) and sets the resolve scope. The wire protocol is `labstream-net`'s, a pure-Rust
//! implementation of liblsl's.

pub mod publisher;
pub mod streams;
pub mod tap;
