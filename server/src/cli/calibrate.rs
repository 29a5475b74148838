//! `bdft-server calibrate`: the study's synthetic population fitted to a table or its own tests.

use std::path::PathBuf;

use anyhow::Context;

use super::{newest_study, open_store, progress_ticker};
use crate::config::DbConfig;
use crate::engine::dry_runs::calibration::fit::FitReport;
use crate::engine::dry_runs::calibration::run::{CalibrateRequest, calibrate};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    db: DbConfig,
    /// Study to calibrate [default: the newest].
    #[arg(long)]
    study: Option<i64>,
    /// CSV table `controller,station,metric,mean[,sd,n[,unit[,use]]]` [default: the
    /// study's own completed tests]. unit: the metric's unit, one per metric in a table
    /// (mse_tracking_mm2: mm2, cm2, m2; ms_cab_accel: mm2/s4, 1e5mm2/s4, m2/s4); use: fit
    /// (the default) or hold-out (left out of the fit and predicted).
    #[arg(long)]
    table: Option<PathBuf>,
    /// Rows of the target to leave out of the fit and predict, each with its 95 %
    /// prediction interval beside its target: comma-separated controller:station[:metric]
    /// (without the metric, every metric of the cell), e.g.
    /// `--hold-out lqr:on,pid:on:ms_cab_accel`. An item naming no fitted row of the target
    /// is refused.
    #[arg(long, value_name = "CELLS")]
    hold_out: Option<String>,
    /// Simulated subjects per evaluation (8 to 512).
    #[arg(long, default_value_t = 48)]
    subjects: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

/// Who the audit log names for a calibration from the command line.
const COMMAND_LINE_CALIBRATION: &str = "system:calibrate-command";

pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        db,
        study,
        table,
        hold_out,
        subjects,
        seed,
    } = args;
    let pool = open_store(&db).await?;
    let study = newest_study(&pool, study).await?;
    let table = match table {
        Some(path) => Some(
            std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?,
        ),
        None => None,
    };
    let req = CalibrateRequest {
        table,
        hold_out,
        simulated_subjects: subjects,
        seed,
    };
    let progress = std::sync::Arc::new(crate::engine::dry_runs::job::Progress::default());
    let ticker = progress_ticker(progress.clone(), "calibrating");
    let started = std::time::Instant::now();
    let report = calibrate(
        &pool,
        COMMAND_LINE_CALIBRATION,
        study,
        req,
        progress,
        std::sync::Arc::default(),
    )
    .await;
    ticker.abort();
    let report = report?;
    eprint!("{}", summary(&report.fit));
    println!("{}", serde_json::to_string(&report)?);
    tracing::info!(
        elapsed_s = started.elapsed().as_secs_f64(),
        "calibration finished"
    );
    Ok(())
}

/// A calibration's verdict, parameters at a bound and held-out rows, as text for standard
/// error (the report itself is JSON on standard output).
fn summary(fit: &FitReport) -> String {
    let num = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.4}"));
    let mut out = format!("verdict: {}\n", fit.goodness_of_fit.verdict);
    if !fit.at_bound.is_empty() {
        out += &format!("at a bound: {}\n", fit.at_bound.join(", "));
    }
    for c in &fit.held_out {
        out += &format!(
            "held out {} {} {}: predicted {:.4} [{}, {}], target {}: {}\n",
            c.compensator,
            c.seat,
            c.metric,
            c.prediction,
            num(c.low),
            num(c.high),
            num(c.target),
            match c.inside {
                Some(true) => "inside",
                Some(false) => "OUTSIDE",
                None => "no interval",
            }
        );
    }
    out
}
