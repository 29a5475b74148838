//! Parameters that cross process boundaries: recorded with every trial, stored by the
//! server, sent to the controller. Each has the documented default and a `validate` that
//! names the parameter and its allowed range.

mod adapt;
mod compensator;
mod condition;
mod experiment;
mod population;
mod rig;

pub use adapt::*;
pub use compensator::*;
pub use condition::*;
pub use experiment::*;
pub use population::*;
pub use rig::*;

use thiserror::Error;

/// A parameter a user supplied is not acceptable.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ParamError {
    #[error("{name} = {value} is out of range: it must be a finite number in [{lo}, {hi}]")]
    OutOfRange {
        name: &'static str,
        value: f64,
        lo: f64,
        hi: f64,
    },
    #[error("{name}: {message}")]
    Invalid { name: &'static str, message: String },
}

/// Checks that `value` is finite and inside [lo, hi]; the error names the parameter and the
/// allowed range so that a user can correct it.
pub fn check(name: &'static str, value: f64, lo: f64, hi: f64) -> Result<(), ParamError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(ParamError::OutOfRange {
            name,
            value,
            lo,
            hi,
        })
    }
}
