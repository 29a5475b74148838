//! Lab Streaming Layer (LSL) streams, published only when `--lsl` is given (no LSL socket is
//! opened otherwise: discovery answers multicast and broadcast queries).
//!
//! Per station two streams: the 1 kHz signals of its tests, published here in the
//! controller process from the loop's ticks ([`tap`] hands them over, [`publisher`] sends
//! them), and its irregular markers, published by the server, which knows the protocol's
//! events. [`streams`] describes both (names, channels with units, study, station and
//! subject) and sets the resolve scope. The wire protocol is `labstream-net`'s, a pure-Rust
//! implementation of liblsl's.
//!
//! The 1 kHz signals are published here and not by the server because they exist only in the loop:
//! the server gets decimated live samples and a trial's record after its end, so only the
//! controller can hand over every tick as it happens. `tap`: the hand-over — the loop offers each
//! recorded tick (target, device, cylinder position, cab acceleration, valve command, stamped with
//! its wake-up time on CLOCK_MONOTONIC, which is LSL's clock) to a bounded rtrb SPSC ring,
//! prefaulted; a full ring drops the row and counts it (the loop never waits for a slow reader).
//! `publisher`: the `bdft-lsl` thread reading the ring and pushing rows to the stations' outlets,
//! and the table of stations (published or re-published on the server's `LslStation` when the
//! subject or study changes, same source id so recorders find it again) and of trial → station
//! routes, shared with the I/O side behind a mutex the loop never touches. `streams`: channel
//! labels, units and meanings from `RECORD_CHANNELS`, study, station and subject in a `bdft` node;
//! the server's marker stream is described here too; the resolve scope is the machine by default.
//!
//! *Invariant:* the loop's share is one ring push per trial per tick: no allocation, lock or block
//! (`rt_loop::tests::the_loop_tick_never_allocates` runs with a ring that fills).

pub mod publisher;
pub mod streams;
pub mod tap;
