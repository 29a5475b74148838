//! The identification test (`docs/identification.md`): the multisine that moves the cab
//! ([`multisine`]), the feedthrough estimated from the record at its lines ([`estimate`])
//! and the seated body fitted to it ([`fit`]), with the study's population as the prior on
//! its resonances ([`prior`]).

pub mod estimate;
pub mod fit;
pub mod multisine;
pub mod prior;

use thiserror::Error;

pub use estimate::estimate;
pub use fit::{fit_body, fit_record, identify};
pub use multisine::Multisine;
pub use prior::BodyPrior;

/// Why a multisine cannot be built, or a record cannot be estimated or fitted.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum IdentificationError {
    /// The multisine's design is not allowed (the message names the parameter).
    #[error("{0}")]
    Spec(String),
    /// The record does not hold what the estimator needs.
    #[error("record: {0}")]
    Record(String),
    /// The fit could not produce a body.
    #[error("fit: {0}")]
    Fit(String),
}

#[cfg(test)]
mod tests;
