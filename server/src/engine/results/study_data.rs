//! What the analyses count, decided once: an attempt is valid when it is a scored test that
//! ran complete, and counts when it is also the latest attempt of its test (a redone test
//! counts once); a study's analysable data are each subject's cells of the summary
//! variables from the attempts that count. The box plots, averages, inferential table,
//! learning curve, exports' `valid`/`latest` flags and the power planner all read it here.

use std::collections::BTreeMap;

use bdft_protocol::records::TrialStatus;
use bdft_protocol::study::CancellationArm;
use sqlx::AnyPool;

use crate::error::Result;
use crate::store;
use crate::store::exports::{TrialExportRow, Withdrawn};

/// The variables summarised per compensator × seat, in the order of every cell.
pub const SUMMARY_VARIABLES: [&str; 6] = [
    "mse_tracking_mm2",
    "ms_cab_accel",
    "rating_accuracy",
    "rating_speed",
    "rating_smoothness",
    "rating_controllability",
];

/// The key of a compensator's cell in `Cells`: its name, with `+arm` when it cancelled.
pub fn cancelled_key(compensator: &str, arm: CancellationArm) -> String {
    match arm {
        CancellationArm::Off => compensator.to_string(),
        arm => format!("{compensator}+{arm}"),
    }
}

/// A key of `Cells` split into the compensator and what it cancelled with.
pub fn split_key(key: &str) -> (&str, &str) {
    key.split_once('+').unwrap_or((key, "off"))
}

/// Whether an attempt is a valid measurement: a test, not the practice, that ran complete.
/// (The trials export's `valid` flag.)
pub fn valid(r: &TrialExportRow) -> bool {
    r.phase.scored() && r.status == TrialStatus::Complete
}

/// Whether an attempt counts in the analyses: valid and the latest attempt of its test, so
/// a redone test counts once, and a test whose latest attempt failed not at all.
pub fn counts(r: &TrialExportRow) -> bool {
    valid(r) && r.latest
}

/// One subject's values of the summary variables per (compensator, seat); a cancelled
/// test's compensator is keyed with its arm (`cancelled_key`: "pid+personal", seat "on"),
/// so an analysis of the compensators by name reads the uncancelled tests alone.
pub type Cells = BTreeMap<(String, String), [Option<f64>; 6]>;

/// A study's analysable data: its compensators and seats (names, in the study's order) and
/// each subject's cells from the latest attempt of every test when it is complete.
#[derive(Debug)]
pub struct StudyData {
    pub compensators: Vec<String>,
    /// The study's cancelling arms (none without the factor).
    pub arms: Vec<CancellationArm>,
    pub seats: Vec<String>,
    pub subjects: Vec<Cells>,
    /// Each subject's machine condition (as `subjects`): the study's, or their level of its
    /// condition factor.
    pub conditions: Vec<String>,
}

/// The attempts the analyses count (`counts`): of every scored test, the latest attempt,
/// when it is complete (a redone test counts once; practice never).
pub fn analysable(rows: &[TrialExportRow]) -> impl Iterator<Item = &TrialExportRow> {
    rows.iter().filter(|r| counts(r))
}

impl StudyData {
    pub async fn load(pool: &AnyPool, study_id: i64) -> Result<Self> {
        let study = store::studies::get(pool, study_id).await?;
        let rows = store::exports::trial_rows(pool, study_id, Withdrawn::LeftOut).await?;
        let mut subjects: BTreeMap<i64, (String, Cells)> = BTreeMap::new();
        for r in analysable(&rows) {
            let f = |v: Option<i64>| v.map(|x| x as f64);
            let subject = subjects
                .entry(r.enrol_index)
                .or_insert_with(|| (r.condition.clone(), Cells::new()));
            subject.1.insert(
                (
                    cancelled_key(r.controller.name(), r.cancellation),
                    r.station.as_str().into(),
                ),
                [
                    r.mse_tracking_mm2,
                    r.ms_cab_accel,
                    f(r.accuracy),
                    f(r.speed),
                    f(r.smoothness),
                    f(r.controllability),
                ],
            );
        }
        Ok(Self {
            compensators: study
                .params
                .compensators
                .iter()
                .map(|c| c.kind().name().to_string())
                .collect(),
            arms: study
                .params
                .cancellation
                .as_ref()
                .map_or_else(Vec::new, |c| c.arms.clone()),
            seats: study
                .params
                .seats
                .iter()
                .map(|s| s.as_str().to_string())
                .collect(),
            conditions: subjects.values().map(|s| s.0.clone()).collect(),
            subjects: subjects.into_values().map(|s| s.1).collect(),
        })
    }

    /// One row per subject with every cell of `keys` (`cancelled_key`s) at `seat`: the
    /// values of `metric` (an index into `SUMMARY_VARIABLES`).
    pub fn complete_rows(&self, keys: &[String], metric: usize, seat: &str) -> Vec<Vec<f64>> {
        self.subjects
            .iter()
            .filter_map(|s| {
                keys.iter()
                    .map(|c| s.get(&(c.clone(), seat.to_string()))?[metric])
                    .collect()
            })
            .collect()
    }
}
