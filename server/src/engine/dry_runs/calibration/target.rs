//! What a calibration fits to: cell means of a metric (with their spread over subjects where
//! known), from a table (CSV `controller,station,metric,mean[,sd,n]`, e.g. a published one)
//! or from a study's own completed tests (then per subject, for the bootstrap).

use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::study::StudyParams;
use bdft_protocol::trial::Metrics;
use serde::Serialize;

use super::sim::Cell;
use crate::error::{AppError, Result};

/// The metrics a simulated trial gives (and a calibration can fit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    /// Mean-squared tracking error (mm²).
    MseTrackingMm2,
    /// Mean-squared cab acceleration ((mm/s²)²).
    MsCabAccel,
}

impl Metric {
    pub const ALL: [Metric; 2] = [Metric::MseTrackingMm2, Metric::MsCabAccel];

    pub fn name(self) -> &'static str {
        match self {
            Metric::MseTrackingMm2 => "mse_tracking_mm2",
            Metric::MsCabAccel => "ms_cab_accel",
        }
    }

    pub fn of(self, m: &Metrics) -> f64 {
        match self {
            Metric::MseTrackingMm2 => m.mse_tracking_mm2,
            Metric::MsCabAccel => m.ms_cab_accel,
        }
    }
}

/// One target moment: the mean of `metric` over subjects in `cell`, with its standard
/// deviation over subjects and their number where known.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetCell {
    pub cell: Cell,
    pub metric: Metric,
    pub mean: f64,
    pub sd: Option<f64>,
    pub n: Option<usize>,
    /// Mean and standard deviation over subjects of the metric's logarithm, where the spread
    /// is known: measured from a study's subjects, or from a table's mean and sd as a
    /// log-normal's (ln mean − ½ln(1 + cv²), √ln(1 + cv²)). Medians and spread are fitted
    /// on these, which keeps them apart (an arithmetic mean moves with the spread too).
    pub log: Option<(f64, f64)>,
}

/// A calibration's target: its cells, and for a study's own data each subject's values in
/// every cell of the study (`sim::all_cells` order), which the bootstrap resamples.
#[derive(Debug, Clone)]
pub struct Target {
    pub cells: Vec<TargetCell>,
    pub subjects: Option<Vec<Vec<Option<Metrics>>>>,
}

impl Target {
    /// The cells that carry a spread over subjects (a log sd and its number of subjects).
    pub fn with_spread(&self) -> Vec<usize> {
        (0..self.cells.len())
            .filter(|&i| self.cells[i].log.is_some() && self.cells[i].n.is_some())
            .collect()
    }
}

/// The most rows a table may have (every cell of the largest study twice over).
const MAX_ROWS: usize = 200;

/// Parses a table against the study it calibrates; a bad row is refused (422) naming the row
/// (1 = the first after the header) and what is allowed.
pub fn parse_table(params: &StudyParams, csv: &str) -> Result<Target> {
    let mut lines = csv
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'));
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| {
            AppError::BadRequest(
                "table: empty; the header is controller,station,metric,mean[,sd,n]".into(),
            )
        })?
        .split(',')
        .map(str::trim)
        .collect();
    let want = ["controller", "station", "metric", "mean", "sd", "n"];
    if header.len() < 4 || header.len() > 6 || header.iter().zip(want).any(|(h, w)| *h != w) {
        return Err(AppError::BadRequest(format!(
            "table: header {:?}; expected controller,station,metric,mean with optional sd,n",
            header.join(",")
        )));
    }
    let mut cells: Vec<TargetCell> = Vec::new();
    for (i, line) in lines.enumerate() {
        let row = i + 1;
        if row > MAX_ROWS {
            return Err(AppError::BadRequest(format!(
                "table: more than {MAX_ROWS} rows"
            )));
        }
        let bad = |what: String| AppError::BadRequest(format!("table row {row}: {what}"));
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != header.len() {
            return Err(bad(format!(
                "{} fields; the header has {}",
                f.len(),
                header.len()
            )));
        }
        let kind: CompensatorKind = f[0].parse().map_err(|_| {
            bad(format!(
                "controller {:?} is not one of {}",
                f[0],
                CompensatorKind::STUDY.map(|k| k.name()).join(", ")
            ))
        })?;
        let seat: Seat = f[1]
            .parse()
            .map_err(|_| bad(format!("station {:?}: allowed on, off", f[1])))?;
        let controller = params
            .controllers
            .iter()
            .position(|c| c.kind() == kind)
            .filter(|_| params.stations.contains(&seat))
            .ok_or_else(|| {
                bad(format!(
                    "the study runs no {} test at the {} station",
                    kind.name(),
                    seat.as_str()
                ))
            })?;
        let metric = Metric::ALL
            .into_iter()
            .find(|m| m.name() == f[2])
            .ok_or_else(|| {
                bad(format!(
                    "metric {:?}: allowed {}",
                    f[2],
                    Metric::ALL.map(Metric::name).join(", ")
                ))
            })?;
        let number = |name: &str, s: &str| -> Result<f64> {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("{name} {s:?} is not a number")))
        };
        let mean = number("mean", f[3])?;
        if mean <= 0.0 {
            return Err(bad(format!(
                "mean {mean}: must be positive (a mean square)"
            )));
        }
        let sd = match f.get(4) {
            Some(s) if !s.is_empty() => {
                let sd = number("sd", s)?;
                if sd < 0.0 {
                    return Err(bad(format!("sd {sd}: must not be negative")));
                }
                Some(sd)
            }
            _ => None,
        };
        let n = match f.get(5) {
            Some(s) if !s.is_empty() => Some(
                s.parse::<usize>()
                    .ok()
                    .filter(|&n| (2..=100_000).contains(&n))
                    .ok_or_else(|| {
                        bad(format!("n {s:?}: a whole number of subjects, 2 or more"))
                    })?,
            ),
            _ => None,
        };
        let cell = Cell { controller, seat };
        if cells.iter().any(|c| c.cell == cell && c.metric == metric) {
            return Err(bad(format!(
                "{} at {} ({}) is already in the table",
                kind.name(),
                seat.as_str(),
                metric.name()
            )));
        }
        // A spread counts only with its number of subjects (its weight).
        let log = sd.filter(|&sd| sd > 0.0 && n.is_some()).map(|sd| {
            let s2 = (1.0 + (sd / mean).powi(2)).ln();
            (mean.ln() - 0.5 * s2, s2.sqrt())
        });
        cells.push(TargetCell {
            cell,
            metric,
            mean,
            sd,
            n,
            log,
        });
    }
    Ok(Target {
        cells,
        subjects: None,
    })
}

/// The target of a study's own data: `rows[subject][cell]` over `cells` (the study's
/// completed tests), the mean, sd and n of each metric in each cell with 2 or more subjects.
pub fn from_subjects(cells: &[Cell], rows: Vec<Vec<Option<Metrics>>>) -> Target {
    let mut out = Vec::new();
    for (j, &cell) in cells.iter().enumerate() {
        for metric in Metric::ALL {
            let v: Vec<f64> = rows
                .iter()
                .filter_map(|r| r[j].map(|m| metric.of(&m)))
                .collect();
            if v.len() < 2 {
                continue;
            }
            let (mean, sd) = mean_sd(&v);
            let logs: Vec<f64> = v.iter().map(|x| x.max(1e-12).ln()).collect();
            out.push(TargetCell {
                cell,
                metric,
                mean,
                sd: Some(sd),
                n: Some(v.len()),
                log: Some(mean_sd(&logs)),
            });
        }
    }
    Target {
        cells: out,
        subjects: Some(rows),
    }
}

/// Mean and sample standard deviation.
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}
