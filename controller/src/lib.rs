//! bdft-lab's control core: models of the backhoe rig and the operator's body, the five
//! compensators of the biodynamic-feedthrough study (plus cab-acceleration feedback for
//! comparison), their design routines, a stability analysis of each with the feedthrough
//! loop closed, and a deterministic offline simulation.
//!
//! Everything is pure: time is passed in (one `step` per tick at `dt`), randomness comes
//! from seeds. The real-time runtime runs exactly these `step` functions.
//!
//! Map: [`params`] (named parameters with the identified defaults) → [`model`] (plant, body)
//! and [`compensator`] (designs in [`linalg`], filters in [`filters`], [`shaper`]) →
//! [`closed_loop`] (one tick) → [`simulate`] and [`analysis`]; [`special`]: the special
//! functions (log-gamma, incomplete gamma and beta) the identification's intervals and the
//! server's statistics share.

pub mod analysis;
pub mod batch;
pub mod closed_loop;
pub mod compensator;
pub mod error;
pub mod exposure;
pub mod filters;
pub mod identification;
pub mod interlock;
pub mod linalg;
pub mod logging;
pub mod lsl;
pub mod model;
pub mod operator;
pub mod param_set;
pub mod params;
pub mod perception;
pub mod population;
pub mod rng;
pub mod runner;
pub mod runtime;
pub mod shaper;
pub mod signals;
pub mod simulate;
pub mod special;
pub mod state;

#[cfg(test)]
mod alloc_check;
#[cfg(test)]
mod fixtures;
#[cfg(test)]
mod tests;
