//! Descriptive statistics per compensator × seat: the numbers behind the box plots, the
//! table of averages and the summary export. Only the latest attempt of each test counts,
//! when it is complete, of subjects who have not withdrawn (`study_data`).

use sqlx::AnyPool;

use super::inference::quantile::quantile;
use super::study_data::{SUMMARY_VARIABLES, StudyData, split_key};
use crate::error::Result;

/// Statistics of one variable for one compensator × seat.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct Stats {
    /// The compensator's name (the API's key: `controller`).
    #[serde(rename = "controller")]
    pub compensator: String,
    /// The seat: on or off the machine (the API's key: `station`).
    #[serde(rename = "station")]
    pub seat: String,
    /// What the tests cancelled the feedthrough with (`off` at the desk and without the
    /// factor).
    pub cancellation: String,
    /// The machine's condition of the subjects summarised: the study's, or one level of its
    /// condition factor (a group per level).
    pub condition: String,
    pub variable: String,
    pub n: usize,
    pub mean: f64,
    pub median: f64,
    pub q1: f64,
    pub q3: f64,
    pub min: f64,
    pub max: f64,
}

/// Values of the summary variables (in `SUMMARY_VARIABLES` order) of the latest attempt of
/// every non-practice test when it is complete, of the subjects who have not withdrawn, by
/// (compensator, seat) name: a redone test counts once.
pub type GroupValues = std::collections::BTreeMap<(String, String), Vec<[Option<f64>; 6]>>;

pub async fn group_values(pool: &AnyPool, study_id: i64) -> Result<GroupValues> {
    let mut groups = GroupValues::new();
    for subject in StudyData::load(pool, study_id).await?.subjects {
        for (key, values) in subject {
            groups.entry(key).or_default().push(values);
        }
    }
    Ok(groups)
}

/// Per compensator × seat statistics, and per machine condition in a study with a
/// condition factor: the numbers behind the table of averages and the summary export.
pub async fn summary_stats(pool: &AnyPool, study_id: i64) -> Result<Vec<Stats>> {
    let data = StudyData::load(pool, study_id).await?;
    let mut groups: std::collections::BTreeMap<_, Vec<[Option<f64>; 6]>> = Default::default();
    for (subject, condition) in data.subjects.into_iter().zip(data.conditions) {
        for ((key, seat), values) in subject {
            groups
                .entry((condition.clone(), key, seat))
                .or_default()
                .push(values);
        }
    }
    let mut out = Vec::new();
    for ((condition, key, seat), values) in groups {
        let (controller, cancellation) = split_key(&key);
        for (i, variable) in SUMMARY_VARIABLES.iter().enumerate() {
            let mut xs: Vec<f64> = values.iter().filter_map(|v| v[i]).collect();
            if xs.is_empty() {
                continue;
            }
            xs.sort_by(f64::total_cmp);
            out.push(Stats {
                compensator: controller.to_string(),
                seat: seat.clone(),
                cancellation: cancellation.to_string(),
                condition: condition.clone(),
                variable: (*variable).into(),
                n: xs.len(),
                mean: xs.iter().sum::<f64>() / xs.len() as f64,
                median: quantile(&xs, 0.5),
                q1: quantile(&xs, 0.25),
                q3: quantile(&xs, 0.75),
                min: xs[0],
                max: xs[xs.len() - 1],
            });
        }
    }
    Ok(out)
}
