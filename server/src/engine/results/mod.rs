//! Room **results**: what a study's data become — descriptive statistics (`stats`), the
//! inferential tests (`inference`, pure functions on numbers) and their table
//! (`inference_table`), the learning curve (`learning`), the figures (`plots`, and the
//! results page's set in `page`), every export (`export`) and a subject's identification
//! tests against the population (`identification`). What counts in an analysis is decided
//! once (`study_data`).
//!
//! *May use:* `study`, `machine` (a bench run's results, for their export). Read-only on the
//! store: nothing here changes a study.

pub mod export;
pub mod identification;
pub mod inference;
pub mod inference_table;
pub mod learning;
pub mod page;
pub mod plots;
pub mod stats;
pub mod study_data;
