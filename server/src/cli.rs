//! The `bdft-server` command line.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};

use crate::export::ExportKind;

#[derive(Debug, Parser)]
#[command(
    name = "bdft-server",
    version,
    about = "bdft-lab experiment server: runs the study protocol, stores and exports its data"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the whole protocol for N synthetic subjects, faster than real time, into the
    /// database (subjects flagged synthetic, surveys left empty).
    Pilot {
        /// SQLite database file (created if missing).
        #[arg(long, env = "BDFT_DB", default_value = "bdft-lab.db")]
        db: PathBuf,
        /// Study to add the subjects to [default: the newest; a default study if none].
        #[arg(long)]
        study: Option<i64>,
        /// Number of synthetic subjects.
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=500))]
        subjects: u32,
        /// Seed of a study created for the pilot.
        #[arg(long)]
        seed: Option<u64>,
    },
    /// Write a CSV export of a study.
    Export {
        #[arg(long, env = "BDFT_DB", default_value = "bdft-lab.db")]
        db: PathBuf,
        /// Study to export [default: the newest].
        #[arg(long)]
        study: Option<i64>,
        /// trials (one row per test), samples (1 kHz records, long format) or summary
        /// (statistics per controller × station).
        #[arg(long)]
        kind: ExportKind,
        /// Output file (written to a temporary name and renamed when complete).
        #[arg(long)]
        out: PathBuf,
    },
}

pub fn run() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: starting the runtime: {e}");
            return ExitCode::from(2);
        }
    };
    match rt.block_on(execute(cli.command)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

async fn newest_study(pool: &sqlx::SqlitePool, study: Option<i64>) -> anyhow::Result<i64> {
    match study {
        Some(id) => Ok(id),
        None => crate::store::studies(pool)
            .await?
            .last()
            .map(|s| s.id)
            .context("the database has no study yet"),
    }
}

async fn execute(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Pilot {
            db,
            study,
            subjects,
            seed,
        } => {
            let pool = crate::db::open(&db).await?;
            let started = std::time::Instant::now();
            let report = crate::pilot::run(&pool, study, subjects, seed).await?;
            println!("{}", serde_json::to_string(&report)?);
            tracing::info!(
                elapsed_s = started.elapsed().as_secs_f64(),
                "pilot finished"
            );
        }
        Command::Export {
            db,
            study,
            kind,
            out,
        } => {
            let pool = crate::db::open(&db).await?;
            let study = newest_study(&pool, study).await?;
            let tmp = out.with_extension("partial");
            let file = tokio::fs::File::create(&tmp)
                .await
                .with_context(|| format!("creating {}", tmp.display()))?;
            if let Err(e) = crate::export::write(&pool, study, kind, file).await {
                let _ = tokio::fs::remove_file(&tmp).await;
                return Err(e.into());
            }
            tokio::fs::rename(&tmp, &out)
                .await
                .with_context(|| format!("renaming to {}", out.display()))?;
        }
    }
    Ok(())
}
