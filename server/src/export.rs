//! Tidy CSV exports for R or pandas, streamed row by row (memory stays constant however large
//! the study): `trials` (one row per test attempt), `samples` (the 1 kHz records, long
//! format), `summary` (statistics per controller × station). Withdrawn subjects are left
//! out. Text cells are neutralized against spreadsheet formula injection.

use sqlx::SqlitePool;
use tokio::io::{AsyncWrite, AsyncWriteExt, BufWriter};

use bdft_protocol::trial::RECORD_CHANNELS;

use crate::db::rfc3339;
use crate::store::{StoreError, unblob};

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExportKind {
    Trials,
    Samples,
    Summary,
}

impl std::str::FromStr for ExportKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "trials" => Ok(Self::Trials),
            "samples" => Ok(Self::Samples),
            "summary" => Ok(Self::Summary),
            _ => Err(format!(
                "unknown export {s:?}; valid: trials, samples, summary"
            )),
        }
    }
}

/// A text cell: quoted when needed, and prefixed with an apostrophe when a spreadsheet would
/// read it as a formula (=, +, -, @, tab, carriage return).
pub fn text_cell(s: &str) -> String {
    let neutral = if s.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        format!("'{s}")
    } else {
        s.to_string()
    };
    if neutral.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", neutral.replace('"', "\"\""))
    } else {
        neutral
    }
}

fn num(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

pub const TRIAL_COLUMNS: [&str; 32] = [
    "study_id",
    "trial_id",
    "subject_code",
    "subject_index",
    "synthetic",
    "starting_station",
    "station",
    "block",
    "position",
    "slot",
    "attempt",
    "controller",
    "blinded_label",
    "practice",
    "status",
    "status_reason",
    "seed",
    "target_mean_mm",
    "target_std_mm",
    "k_bf",
    "duration_s",
    "mse_tracking_mm2",
    "ms_cab_accel",
    "rating_accuracy",
    "rating_speed",
    "rating_smoothness",
    "rating_controllability",
    "comment",
    "protocol_hash",
    "started_at",
    "finished_at",
    "consent_version",
];

#[derive(sqlx::FromRow)]
struct TrialExportRow {
    study_id: i64,
    trial_id: i64,
    code: String,
    enrol_index: i64,
    synthetic: bool,
    starting_station: String,
    station: String,
    block: i64,
    position: i64,
    slot: i64,
    attempt: i64,
    controller: String,
    blinded_label: String,
    practice: bool,
    status: String,
    status_reason: Option<String>,
    target_seed: i64,
    target_mean_mm: f64,
    target_std_mm: f64,
    k_bf: f64,
    duration_s: f64,
    mse_tracking_mm2: Option<f64>,
    ms_cab_accel: Option<f64>,
    accuracy: Option<i64>,
    speed: Option<i64>,
    smoothness: Option<i64>,
    controllability: Option<i64>,
    comment: Option<String>,
    protocol_hash: Option<String>,
    started_at: Option<i64>,
    finished_at: Option<i64>,
    consent_version: Option<String>,
}

const TRIALS_SQL: &str = "SELECT s.study_id, t.id AS trial_id, s.code, s.enrol_index, s.synthetic, s.starting_station, t.station, t.block, t.position, t.slot, t.attempt, \
     t.controller, t.blinded_label, t.practice, t.status, t.status_reason, t.target_seed, t.target_mean_mm, t.target_std_mm, t.k_bf, t.duration_s, \
     t.mse_tracking_mm2, t.ms_cab_accel, v.accuracy, v.speed, v.smoothness, v.controllability, v.comment, t.protocol_hash, t.started_at, t.finished_at, s.consent_version \
     FROM trials t JOIN subjects s ON s.id = t.subject_id LEFT JOIN surveys v ON v.trial_id = t.id \
     WHERE s.study_id = ? AND s.withdrawn_at IS NULL ORDER BY s.enrol_index, t.slot, t.attempt";

/// Writes the export of `kind` for `study_id` to `out`.
pub async fn write(
    pool: &SqlitePool,
    study_id: i64,
    kind: ExportKind,
    out: impl AsyncWrite + Unpin,
) -> Result<(), ExportError> {
    crate::store::study(pool, study_id).await?;
    let mut w = BufWriter::with_capacity(1 << 16, out);
    match kind {
        ExportKind::Trials => trials(pool, study_id, &mut w).await?,
        ExportKind::Samples => samples(pool, study_id, &mut w).await?,
        ExportKind::Summary => summary(pool, study_id, &mut w).await?,
    }
    w.flush().await?;
    Ok(())
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
    #[error("writing the export: {0}")]
    Io(#[from] std::io::Error),
}

async fn trials(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    w.write_all(format!("{}\n", TRIAL_COLUMNS.join(",")).as_bytes())
        .await?;
    let rows: Vec<TrialExportRow> = sqlx::query_as(TRIALS_SQL)
        .bind(study_id)
        .fetch_all(pool)
        .await?;
    for r in rows {
        let rating = |v: Option<i64>| v.map(|x| x.to_string()).unwrap_or_default();
        let cells = [
            r.study_id.to_string(),
            r.trial_id.to_string(),
            text_cell(&r.code),
            (r.enrol_index + 1).to_string(),
            u8::from(r.synthetic).to_string(),
            r.starting_station,
            r.station,
            r.block.to_string(),
            r.position.to_string(),
            r.slot.to_string(),
            r.attempt.to_string(),
            r.controller,
            text_cell(&r.blinded_label),
            u8::from(r.practice).to_string(),
            r.status,
            text_cell(r.status_reason.as_deref().unwrap_or("")),
            r.target_seed.to_string(),
            r.target_mean_mm.to_string(),
            r.target_std_mm.to_string(),
            r.k_bf.to_string(),
            r.duration_s.to_string(),
            num(r.mse_tracking_mm2),
            num(r.ms_cab_accel),
            rating(r.accuracy),
            rating(r.speed),
            rating(r.smoothness),
            rating(r.controllability),
            text_cell(r.comment.as_deref().unwrap_or("")),
            r.protocol_hash.unwrap_or_default(),
            r.started_at.map(rfc3339).unwrap_or_default(),
            r.finished_at.map(rfc3339).unwrap_or_default(),
            text_cell(r.consent_version.as_deref().unwrap_or("")),
        ];
        w.write_all(cells.join(",").as_bytes()).await?;
        w.write_all(b"\n").await?;
    }
    Ok(())
}

async fn samples(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    let header: Vec<&str> = [
        "study_id",
        "trial_id",
        "subject_code",
        "station",
        "controller",
        "practice",
        "t_s",
    ]
    .into_iter()
    .chain(RECORD_CHANNELS)
    .collect();
    w.write_all(format!("{}\n", header.join(",")).as_bytes())
        .await?;
    let trials: Vec<(i64, String, String, String, bool)> = sqlx::query_as(
        "SELECT t.id, s.code, t.station, t.controller, t.practice FROM trials t JOIN subjects s ON s.id = t.subject_id \
         JOIN trial_records r ON r.trial_id = t.id WHERE s.study_id = ? AND s.withdrawn_at IS NULL ORDER BY s.enrol_index, t.slot, t.attempt",
    )
    .bind(study_id)
    .fetch_all(pool)
    .await?;
    // One trial's record in memory at a time (about 5 MB for 140 s).
    let channels = RECORD_CHANNELS.join(", ");
    let sql = format!("SELECT dt, {channels} FROM trial_records WHERE trial_id = ?");
    let mut line = String::with_capacity(256);
    for (trial_id, code, station, controller, practice) in trials {
        let row = sqlx::query(&sql).bind(trial_id).fetch_one(pool).await?;
        use sqlx::Row;
        let dt: f64 = row.try_get(0)?;
        let cols: Vec<Vec<f32>> = (0..RECORD_CHANNELS.len())
            .map(|i| row.try_get::<Vec<u8>, _>(i + 1).map(|b| unblob(&b)))
            .collect::<Result<_, _>>()?;
        drop(row);
        let prefix = format!(
            "{study_id},{trial_id},{},{station},{controller},{},",
            text_cell(&code),
            u8::from(practice)
        );
        for k in 0..cols[0].len() {
            line.clear();
            line.push_str(&prefix);
            line.push_str(&format!("{:.3}", k as f64 * dt));
            for c in &cols {
                line.push(',');
                line.push_str(&c[k].to_string());
            }
            line.push('\n');
            w.write_all(line.as_bytes()).await?;
        }
    }
    Ok(())
}

/// Quantile by linear interpolation between order statistics (R's type 7, numpy's default).
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q;
    let (lo, hi) = (h.floor() as usize, h.ceil() as usize);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// Statistics of one variable for one controller × station.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Stats {
    pub controller: String,
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

/// Values of the summary variables (in `SUMMARY_VARIABLES` order) of every completed,
/// non-practice test of subjects who have not withdrawn, by (controller, station).
pub type GroupValues = std::collections::BTreeMap<(String, String), Vec<[Option<f64>; 6]>>;

pub async fn group_values(pool: &SqlitePool, study_id: i64) -> Result<GroupValues, ExportError> {
    let rows: Vec<TrialExportRow> = sqlx::query_as(TRIALS_SQL)
        .bind(study_id)
        .fetch_all(pool)
        .await?;
    let mut groups = GroupValues::new();
    for r in rows
        .into_iter()
        .filter(|r| !r.practice && r.status == "complete")
    {
        let f = |v: Option<i64>| v.map(|x| x as f64);
        groups.entry((r.controller, r.station)).or_default().push([
            r.mse_tracking_mm2,
            r.ms_cab_accel,
            f(r.accuracy),
            f(r.speed),
            f(r.smoothness),
            f(r.controllability),
        ]);
    }
    Ok(groups)
}

/// Per controller × station statistics: the numbers behind the box plots and the table of
/// averages.
pub async fn summary_stats(pool: &SqlitePool, study_id: i64) -> Result<Vec<Stats>, ExportError> {
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

async fn summary(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    w.write_all(b"controller,station,variable,n,mean,median,q1,q3,min,max\n")
        .await?;
    for s in summary_stats(pool, study_id).await? {
        let line = format!(
            "{},{},{},{},{},{},{},{},{},{}\n",
            s.controller, s.station, s.variable, s.n, s.mean, s.median, s.q1, s.q3, s.min, s.max
        );
        w.write_all(line.as_bytes()).await?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formula_cells_are_neutralized_and_quoted() {
        assert_eq!(text_cell("S01"), "S01");
        assert_eq!(text_cell("=HYPERLINK(\"x\")"), "\"'=HYPERLINK(\"\"x\"\")\"");
        assert_eq!(text_cell("+1"), "'+1");
        assert_eq!(text_cell("-2"), "'-2");
        assert_eq!(text_cell("@SUM(A1)"), "'@SUM(A1)");
        assert_eq!(text_cell("a,b"), "\"a,b\"");
        assert_eq!(text_cell("line\nbreak"), "\"line\nbreak\"");
    }

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
