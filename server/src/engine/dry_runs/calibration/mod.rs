//! Calibration of a study's synthetic population to data, and what a population predicts.

pub mod findings;
pub mod fit;
pub mod predict;
pub mod ratings;
pub mod run;
pub mod sim;
pub mod surveys;
pub mod table_error;
pub mod target;

#[cfg(test)]
mod fit_tests;
#[cfg(test)]
mod tests;
