//! Descriptive statistics per compensator × seat: the numbers behind the box plots, the
//! table of averages and the summary export. Only the latest attempt of each test counts,
//! when it is complete, of subjects who have not withdrawn (`inference_table::StudyData`).

use sqlx::SqlitePool;

use super::inference_table::StudyData;
use crate::error::Result;

/// Quantile by linear interpolation between order statistics (R's type 7, numpy's default).
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q;
    let (lo, hi) = (h.floor() as usize, h.ceil() as usize);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// Statistics of one variable for one compensator × seat.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct Stats {
    /// The compensator's name.
    pub controller: String,
    /// The seat: on or off the machine.
    pub station: String,
    pub variable: String,
    pub n: usize,
    pub mean: f64,
    pub median: f64,
    pub q1: f64,
    pub q3: f64,
    pub min: f64,
    pub max: f64,
}

pub const SUMMARY_VARIABLES: [&str; 6] = [
    "mse_tracking_mm2",
    "ms_cab_accel",
    "rating_accuracy",
    "rating_speed",
    "rating_smoothness",
    "rating_controllability",
];

/// Values of the summary variables (in `SUMMARY_VARIABLES` order) of the latest attempt of
/// every non-practice test when it is complete, of the subjects who have not withdrawn, by
/// (compensator, seat) name: a redone test counts once.
pub type GroupValues = std::collections::BTreeMap<(String, String), Vec<[Option<f64>; 6]>>;

pub async fn group_values(pool: &SqlitePool, study_id: i64) -> Result<GroupValues> {
    let mut groups = GroupValues::new();
    for subject in StudyData::load(pool, study_id).await?.subjects {
        for (key, values) in subject {
            groups.entry(key).or_default().push(values);
        }
    }
    Ok(groups)
}

/// Per compensator × seat statistics: the numbers behind the box plots and the table of
/// averages.
pub async fn summary_stats(pool: &SqlitePool, study_id: i64) -> Result<Vec<Stats>> {
    let mut out = Vec::new();
    for ((controller, station), values) in group_values(pool, study_id).await? {
        for (i, variable) in SUMMARY_VARIABLES.iter().enumerate() {
            let mut xs: Vec<f64> = values.iter().filter_map(|v| v[i]).collect();
            if xs.is_empty() {
                continue;
            }
            xs.sort_by(f64::total_cmp);
            out.push(Stats {
                controller: controller.clone(),
                station: station.clone(),
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_numpy_linear() {
        // numpy.quantile([1, 2, 3, 4, 10], [0.25, 0.5, 0.75]) = [2, 3, 4]
        let xs = [1.0, 2.0, 3.0, 4.0, 10.0];
        assert_eq!(
            (quantile(&xs, 0.25), quantile(&xs, 0.5), quantile(&xs, 0.75)),
            (2.0, 3.0, 4.0)
        );
        // numpy.quantile([1, 2, 3, 4], [0.25, 0.5]) = [1.75, 2.5]
        let ys = [1.0, 2.0, 3.0, 4.0];
        assert_eq!((quantile(&ys, 0.25), quantile(&ys, 0.5)), (1.75, 2.5));
    }
}
