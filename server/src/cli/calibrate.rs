//! `bdft-server calibrate`: the study's synthetic population fitted to a table or its own tests.

use std::path::PathBuf;

use anyhow::Context;

use super::{newest_study, progress_ticker};
use crate::config::DbConfig;
use crate::engine::dry_runs::calibration::run::{CalibrateRequest, calibrate};
use crate::engine::operations::audit_signing;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    db: DbConfig,
    /// Study to calibrate [default: the newest].
    #[arg(long)]
    study: Option<i64>,
    /// CSV table `controller,station,metric,mean[,sd,n]` [default: the study's own
    /// completed tests].
    #[arg(long)]
    table: Option<PathBuf>,
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
        subjects,
        seed,
    } = args;
    audit_signing::use_key_if_present(&db.db)?;
    let pool = db.db.open().await?;
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
    println!("{}", serde_json::to_string(&report?)?);
    tracing::info!(
        elapsed_s = started.elapsed().as_secs_f64(),
        "calibration finished"
    );
    Ok(())
}
