//! `bdft-server findings`: the default study's synthetic population against the thesis's findings.

use std::path::PathBuf;

use super::{progress_ticker, read_params};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Simulated subjects (enrolled as a study seeded --seed would enrol them).
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u32).range(2..=100_000))]
    subjects: u32,
    /// How many of them (the first) answer the surveys: their tests run with records,
    /// a pilot's cost per test [0: no surveys].
    #[arg(long, default_value_t = 8)]
    surveys: u32,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// A study's parameters (JSON, as `GET /api/defaults` gives them) [default: the
    /// default study's]; --trial-s still sets the test length.
    #[arg(long)]
    params: Option<PathBuf>,
    /// Test length (s); practice as long, at most 120 s.
    #[arg(long, default_value_t = 140.0)]
    trial_s: f64,
}

pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        subjects,
        surveys,
        seed,
        params,
        trial_s,
    } = args;
    let base = match params {
        Some(path) => read_params(&path)?,
        None => crate::engine::study::schedule::default_params(),
    };
    let params = bdft_protocol::study::StudyParams {
        trial_s,
        practice_s: trial_s.min(120.0),
        ..base
    };
    params.validate()?;
    let progress = std::sync::Arc::new(crate::engine::dry_runs::job::Progress::default());
    let ticker = progress_ticker(progress.clone(), "simulating");
    let table = tokio::task::spawn_blocking(move || {
        let mut table = crate::engine::dry_runs::calibration::findings::table(
            &params, subjects, seed, &progress,
        )?;
        if surveys > 0 {
            table += &crate::engine::dry_runs::calibration::surveys::table(
                &params,
                surveys.min(subjects),
                seed,
            )?;
        }
        Ok::<_, crate::error::AppError>(table)
    })
    .await?;
    ticker.abort();
    println!("{}", table?);
    Ok(())
}
