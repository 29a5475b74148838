//! Errors of the control core.

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
