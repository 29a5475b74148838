//! What a calibration fits to: cell means of a metric (with their spread over subjects where
//! known), from a table (CSV `controller,station,metric,mean[,sd,n[,unit[,use]]]`, e.g. a
//! published one) or from a study's own completed tests (then per subject, for the
//! bootstrap); and the rows held out of the fit, to be predicted (`use` hold-out, or
//! `hold_out`'s `controller:station[:metric]` items).

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

    /// The units a table may give the metric in, each with its factor to the metric's own
    /// (the first); `1e5mm2/s4` is the thesis's ×10⁵ (mm/s²)².
    pub fn units(self) -> &'static [(&'static str, f64)] {
        match self {
            Metric::MseTrackingMm2 => &[("mm2", 1.0), ("cm2", 100.0), ("m2", 1e6)],
            Metric::MsCabAccel => &[("mm2/s4", 1.0), ("1e5mm2/s4", 1e5), ("m2/s4", 1e6)],
        }
    }

    /// The standard error of a table's cell mean on the log scale where the table gives no
    /// sd and n: a judgement, per metric. Tracking error's mean square is read to ±10 %;
    /// cab acceleration's to ±20 %, since papers give it (or the RMS beside it, Table 8's
    /// 0.49–0.66 m/s²) as a root mean square read to ±10 %, and a square doubles a relative
    /// error. The model discrepancy the fit estimates per metric (`predict`) comes on top.
    pub fn default_log_se(self) -> f64 {
        match self {
            Metric::MseTrackingMm2 => 0.10,
            Metric::MsCabAccel => 0.20,
        }
    }

    /// The metric named `name`, or a message listing the metrics the study records.
    pub fn parse(name: &str) -> std::result::Result<Metric, String> {
        Metric::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                format!(
                    "metric {name:?} is not one the study records; allowed {}",
                    Metric::ALL
                        .map(|m| format!("{} ({})", m.name(), m.units()[0].0))
                        .join(", ")
                )
            })
    }
}

/// A unit as written, normalized: spaces dropped, `^2`/`²` as `2`, `^4`/`⁴` as `4`.
fn normalized_unit(u: &str) -> String {
    u.replace(' ', "")
        .replace("^2", "2")
        .replace('²', "2")
        .replace("^4", "4")
        .replace('⁴', "4")
        .to_lowercase()
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
    /// The table's row (1 = the first after the header); None for a study's own data.
    pub row: Option<usize>,
}

/// A calibration's target: its cells, and for a study's own data each subject's values in
/// every cell of the study (`sim::all_cells` order), which the bootstrap resamples.
#[derive(Debug, Clone)]
pub struct Target {
    pub cells: Vec<TargetCell>,
    pub subjects: Option<Vec<Vec<Option<Metrics>>>>,
    /// Rows left out of the fit: predicted, each against its target.
    pub held_out: Vec<TargetCell>,
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
        .ok_or_else(|| AppError::BadRequest(format!("table: empty; the header is {HEADER_FORM}")))?
        .split(',')
        .map(str::trim)
        .collect();
    let want = [
        "controller",
        "station",
        "metric",
        "mean",
        "sd",
        "n",
        "unit",
        "use",
    ];
    if header.len() < 4
        || header.len() > want.len()
        || header.iter().zip(want).any(|(h, w)| *h != w)
    {
        return Err(AppError::BadRequest(format!(
            "table: header {:?}; expected {HEADER_FORM}",
            header.join(",")
        )));
    }
    let mut cells: Vec<TargetCell> = Vec::new();
    let mut held_out: Vec<TargetCell> = Vec::new();
    // The unit each metric was first given in, and on which row.
    let mut units: Vec<(Metric, &'static str, usize)> = Vec::new();
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
        let (kind, cell) = cell_of(params, f[0], f[1]).map_err(bad)?;
        let seat = cell.seat;
        let metric = Metric::parse(f[2]).map_err(bad)?;
        let (unit, factor) = match f.get(6).filter(|u| !u.is_empty()) {
            None => metric.units()[0],
            Some(u) => metric
                .units()
                .iter()
                .copied()
                .find(|(name, _)| *name == normalized_unit(u))
                .ok_or_else(|| {
                    bad(format!(
                        "unit {u:?} for {}: allowed {}",
                        metric.name(),
                        metric
                            .units()
                            .iter()
                            .map(|u| u.0)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ))
                })?,
        };
        match units.iter().find(|u| u.0 == metric) {
            Some(&(_, first, at)) if first != unit => {
                return Err(bad(format!(
                    "{} in {unit}, but row {at} gave it in {first}; a table gives each metric in one unit",
                    metric.name()
                )));
            }
            Some(_) => {}
            None => units.push((metric, unit, row)),
        }
        let hold = match f.get(7).copied().unwrap_or("") {
            "" | "fit" => false,
            "hold-out" => true,
            other => {
                return Err(bad(format!("use {other:?}: allowed fit, hold-out")));
            }
        };
        let number = |name: &str, s: &str| -> Result<f64> {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("{name} {s:?} is not a number")))
        };
        let mean = number("mean", f[3])? * factor;
        if mean <= 0.0 {
            return Err(bad(format!(
                "mean {mean}: must be positive (a mean square)"
            )));
        }
        let sd = match f.get(4) {
            Some(s) if !s.is_empty() => {
                let sd = number("sd", s)? * factor;
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
        let what = format!("{} at {} ({})", kind.name(), seat.as_str(), metric.name());
        let (same, other) = if hold {
            (&held_out, &cells)
        } else {
            (&cells, &held_out)
        };
        if same.iter().any(|c| c.cell == cell && c.metric == metric) {
            return Err(bad(format!("{what} is already in the table")));
        }
        if let Some(c) = other.iter().find(|c| c.cell == cell && c.metric == metric) {
            return Err(bad(format!(
                "{what} is {} here and {} on row {}; a cell is fitted or held out, not both",
                if hold { "held out" } else { "fitted" },
                if hold { "fitted" } else { "held out" },
                c.row.unwrap_or(0)
            )));
        }
        // A spread counts only with its number of subjects (its weight).
        let log = sd.filter(|&sd| sd > 0.0 && n.is_some()).map(|sd| {
            let s2 = (1.0 + (sd / mean).powi(2)).ln();
            (mean.ln() - 0.5 * s2, s2.sqrt())
        });
        let t = TargetCell {
            cell,
            metric,
            mean,
            sd,
            n,
            log,
            row: Some(row),
        };
        if hold {
            held_out.push(t);
        } else {
            cells.push(t);
        }
    }
    Ok(Target {
        cells,
        subjects: None,
        held_out,
    })
}

/// The study's cell of `controller` at `station` as a table row or a hold-out item names
/// them, or what is wrong with them.
fn cell_of(
    params: &StudyParams,
    controller: &str,
    station: &str,
) -> std::result::Result<(CompensatorKind, Cell), String> {
    let kind: CompensatorKind = controller.parse().map_err(|_| {
        format!(
            "controller {controller:?} is not one of {}",
            CompensatorKind::STUDY.map(|k| k.name()).join(", ")
        )
    })?;
    let seat: Seat = station
        .parse()
        .map_err(|_| format!("station {station:?}: allowed on, off"))?;
    let compensator = params
        .compensators
        .iter()
        .position(|c| c.kind() == kind)
        .filter(|_| params.seats.contains(&seat))
        .ok_or_else(|| {
            format!(
                "the study runs no {} test at the {} station",
                kind.name(),
                seat.as_str()
            )
        })?;
    Ok((kind, Cell { compensator, seat }))
}

/// The table's header, as messages give it.
const HEADER_FORM: &str = "controller,station,metric,mean with optional sd,n,unit,use (unit: the metric's, e.g. mm2 or 1e5mm2/s4; use: fit or hold-out)";

/// Moves the target's rows that `spec` names out of the fit, into `held_out`. `spec`:
/// comma-separated items `controller:station[:metric]` (without the metric: every metric of
/// the cell), e.g. `lqr:on,pid:on:ms_cab_accel`. An item that does not parse, names a cell
/// the study does not run, a metric it does not record, or no row of the target (nothing
/// to hold out: the cell is not in the target, or is held out already) is refused (422),
/// naming the item.
pub fn hold_out(params: &StudyParams, target: &mut Target, spec: &str) -> Result<()> {
    for (i, item) in spec
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .enumerate()
    {
        let bad = |what: String| {
            AppError::BadRequest(format!("hold_out item {} {item:?}: {what}", i + 1))
        };
        let parts: Vec<&str> = item.split(':').map(str::trim).collect();
        if !(2..=3).contains(&parts.len()) {
            return Err(bad(
                "expected controller:station or controller:station:metric, e.g. lqr:on or pid:on:ms_cab_accel"
                    .into(),
            ));
        }
        let (kind, cell) = cell_of(params, parts[0], parts[1]).map_err(bad)?;
        let seat = cell.seat;
        let metric = parts
            .get(2)
            .map(|m| Metric::parse(m))
            .transpose()
            .map_err(bad)?;
        let named = |t: &TargetCell| t.cell == cell && metric.is_none_or(|m| m == t.metric);
        let (out, kept): (Vec<TargetCell>, Vec<TargetCell>) = std::mem::take(&mut target.cells)
            .into_iter()
            .partition(named);
        target.cells = kept;
        if out.is_empty() {
            let what = match metric {
                Some(m) => format!("{} at {} ({})", kind.name(), seat.as_str(), m.name()),
                None => format!("{} at {}", kind.name(), seat.as_str()),
            };
            return Err(bad(if target.held_out.iter().any(named) {
                format!("{what} is held out already (an earlier item, or the table's use column)")
            } else {
                format!(
                    "the target has no {what} to hold out (its fitted rows are the ones to name)"
                )
            }));
        }
        target.held_out.extend(out);
    }
    Ok(())
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
                row: None,
            });
        }
    }
    Target {
        cells: out,
        subjects: Some(rows),
        held_out: Vec::new(),
    }
}

/// Mean and sample standard deviation.
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}
