//! Linear-algebra design routines written for this project: zero-order-hold discretization,
//! eigenvalues, the continuous algebraic Riccati equation and observer pole placement.
//!
//! Design code runs once per trial set-up, so it works on heap matrices (`DMatrix`); only the
//! per-tick code uses fixed-size types.
//!
//! Routines: `zoh` (matrix exponential, Van Loan block), `eigenvalues` (balanced Schur), `care`
//! (matrix sign function + Newton–Kleinman, balanced), `lyapunov`, `place_observer` (parametric
//! Sylvester method for several outputs, the solve refined on its residual: clustered poles are as
//! sensitive to L as V is ill-conditioned).

mod care;
mod discretize;
mod eigen;
mod place;

pub use care::{CareSolution, care, care_residual, lyapunov};
pub use discretize::zoh;
pub use eigen::{eigenvalues, spectral_radius};
pub use place::place_observer;
