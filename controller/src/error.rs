//! Errors of the control core.

use thiserror::Error;

pub use bdft_protocol::params::ParamError;

/// A design routine could not produce a result for these parameters.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DesignError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("the Riccati equation has no stabilizing solution: {0}")]
    Riccati(String),
    #[error("pole placement failed: {0}")]
    Placement(String),
    #[error("a matrix that must be invertible is singular: {0}")]
    Singular(&'static str),
    #[error("the eigenvalue iteration did not converge")]
    Eigen,
}
