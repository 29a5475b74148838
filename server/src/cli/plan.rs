//! `bdft-server plan`: the power planner's report for a study.

use bdft_protocol::study::CancellationArm;

use super::{newest_study, open_store, progress_ticker};
use crate::config::DbConfig;
use crate::engine::dry_runs::power::{self, PlanRequest, PlanSource};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    db: DbConfig,
    /// Study to plan [default: the newest].
    #[arg(long)]
    study: Option<i64>,
    /// Candidate numbers of subjects, comma-separated (2 to 200 each).
    #[arg(long, value_delimiter = ',', required = true)]
    subjects: Vec<usize>,
    /// The seat: `on` or `off`.
    #[arg(
        long = "station",
        visible_alias = "seat",
        value_name = "STATION",
        default_value = "on"
    )]
    seat: String,
    /// `mse_tracking_mm2` or `ms_cab_accel`.
    #[arg(long, default_value = "mse_tracking_mm2")]
    metric: String,
    /// `population` (the study's synthetic subjects run full trials) or `pilot` (the
    /// spread of the study's own data).
    #[arg(long, value_enum, default_value = "population")]
    source: PlanSourceArg,
    /// Simulated studies per candidate.
    #[arg(long, default_value_t = 200)]
    draws: usize,
    #[arg(long, default_value_t = 0.05)]
    alpha: f64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Plan the cancellation factor's comparisons instead of the compensators' pairs: each
    /// compensator on the machine against itself cancelled with this arm (`personal`,
    /// `generic` or `wrong`), from a pilot's data (`--source pilot`).
    #[arg(long, value_name = "ARM", value_parser = parse_arm)]
    cancellation: Option<CancellationArm>,
}

fn parse_arm(s: &str) -> Result<CancellationArm, String> {
    CancellationArm::parse(s).ok_or_else(|| format!("{s:?}; valid: personal, generic, wrong"))
}

/// `plan --source`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PlanSourceArg {
    Population,
    Pilot,
}

pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        db,
        study,
        subjects,
        seat,
        metric,
        source,
        draws,
        alpha,
        seed,
        cancellation,
    } = args;
    let pool = open_store(&db).await?;
    let study = newest_study(&pool, study).await?;
    let req = PlanRequest {
        source: match source {
            PlanSourceArg::Population => PlanSource::Population,
            PlanSourceArg::Pilot => PlanSource::Pilot,
        },
        subjects,
        metric,
        seat,
        draws,
        alpha,
        seed,
        cancellation,
    };
    let progress = std::sync::Arc::new(crate::engine::dry_runs::job::Progress::default());
    let ticker = progress_ticker(progress.clone(), "planning");
    let started = std::time::Instant::now();
    let report = power::plan_study(&pool, study, req, progress).await;
    ticker.abort();
    println!("{}", serde_json::to_string(&report?)?);
    tracing::info!(elapsed_s = started.elapsed().as_secs_f64(), "plan finished");
    Ok(())
}
