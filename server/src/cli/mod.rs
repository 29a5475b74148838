//! The `bdft-server` command line: `Cli` lists the commands and `run` dispatches them;
//! each command's options and its run are a module of its own (`serve` takes
//! `config::ServeConfig`, every setting of the server; the hidden `controller` the real-time
//! controller's own arguments).

use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};

use crate::config::ServeConfig;
use crate::store;

mod audit;
mod backup;
mod calibrate;
mod export;
mod findings;
mod pilot;
mod plan;
mod replay;
mod restore;
mod serve;

#[derive(Debug, Parser)]
#[command(
    name = "bdft-server",
    version,
    about = "bdft-lab experiment server: runs the study protocol, stores and exports its data"
)]
struct Cli {
    /// What to do [default: serve, with its defaults].
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The real-time controller (as `bdft-controller serve`); what `serve` starts.
    #[command(hide = true)]
    Controller(bdft_controller::runtime::ServeArgs),
    /// Run the experiment server: the API and pages on --listen, a supervised controller.
    Serve(Box<ServeConfig>),
    /// Run the whole protocol for N synthetic subjects, faster than real time, into the
    /// database (subjects flagged synthetic, each with its own drawn parameters, answering
    /// the surveys).
    Pilot(pilot::Args),
    /// The power planner: for candidate numbers of subjects, the chance that each pair of
    /// compensators differs significantly at one seat (exact Wilcoxon, Holm), from whole
    /// simulated studies; the report (JSON) on standard output, progress on standard error.
    Plan(plan::Args),
    /// Calibrate the study's synthetic population: fit its medians (and its people's spread,
    /// where the target has spreads) by simulated moments to a table of cell means or to the
    /// study's own completed tests; stores the result as the study's next population version
    /// (what its pilots and planner then use); the report (JSON) on standard output,
    /// progress on standard error.
    Calibrate(calibrate::Args),
    /// Run a stored test again through the controller's code on the simulated rig (a
    /// synthetic subject's from its seed, a person's from the recorded hand) and compare its
    /// record with the stored one bit for bit; with the offline bound of cancellation (the
    /// device's power in 0.5–5 Hz before and after the test's or the subject's model). The
    /// report (JSON) on standard output; exit 1 when the records differ.
    Replay(replay::Args),
    /// The default study's synthetic population against the thesis's findings: per cell the
    /// median tracking error and cab acceleration, tests the interlock stopped, the riding
    /// effect per controller and the ICC of log tracking error (a Markdown table; the model
    /// card's validation table, docs/synthetic-subjects.md).
    Findings(findings::Args),
    /// Back the database up to FILE, also while a server uses it: a consistent copy,
    /// checked (SQLite's integrity check, row counts, protocol hashes), with its manifest
    /// FILE.manifest.json beside it (printed too).
    Backup(backup::Args),
    /// Put a backup back as the database of a stopped server: checked against its manifest
    /// and by SQLite first, then migrated; the database it replaces is kept beside it as
    /// DB.replaced-TIME.
    Restore(restore::Args),
    /// The audit log: `audit verify` checks its hash chain and signed checkpoints.
    Audit {
        #[command(subcommand)]
        command: audit::AuditCommand,
    },
    /// Write an export of a study as CSV or Parquet, or the study as a BIDS dataset.
    Export(export::Args),
}

/// Prints `what`'s progress (simulated trials) on standard error every 2 s until aborted.
fn progress_ticker(
    progress: std::sync::Arc<crate::engine::dry_runs::job::Progress>,
    what: &'static str,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut every = tokio::time::interval(std::time::Duration::from_secs(2));
        loop {
            every.tick().await;
            let (done, total) = (
                progress.done.load(std::sync::atomic::Ordering::Relaxed),
                progress.total.load(std::sync::atomic::Ordering::Relaxed),
            );
            if total > 0 {
                eprintln!("{what}: {done} of {total} simulated trials");
            }
        }
    })
}

pub fn run() -> ExitCode {
    let cli = Cli::parse();
    let command = cli.command.unwrap_or_else(|| {
        // `bdft-server` alone serves with every default (and the environment's settings).
        match Cli::parse_from(["bdft-server", "serve"]).command {
            Some(c) => c,
            None => unreachable!("serve parses"),
        }
    });
    bdft_controller::logging::init();
    if let Command::Controller(args) = &command {
        // The controller builds its own runtime beside its real-time thread.
        return match bdft_controller::runtime::serve_announcing(args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e:#}");
                ExitCode::from(2)
            }
        };
    }
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
    match rt.block_on(execute(command)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

/// A study's parameters from a JSON file (as `GET /api/defaults` gives them).
fn read_params(path: &std::path::Path) -> anyhow::Result<bdft_protocol::study::StudyParams> {
    serde_json::from_str(
        &std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?,
    )
    .with_context(|| format!("{}: study parameters", path.display()))
}

/// The store `db` names, opened, with the audit key file beside it (if there is one) as this
/// process's chain key, so the command's audit entries are keyed as the server's are.
async fn open_store(db: &crate::config::DbConfig) -> anyhow::Result<sqlx::AnyPool> {
    crate::engine::operations::audit_signing::use_key_if_present(&db.db)?;
    db.db.open().await
}

async fn newest_study(pool: &sqlx::AnyPool, study: Option<i64>) -> anyhow::Result<i64> {
    match study {
        Some(id) => Ok(id),
        None => store::studies::all(pool)
            .await?
            .last()
            .map(|s| s.id)
            .context("the database has no study yet"),
    }
}

async fn execute(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Serve(config) => serve::run(*config).await,
        Command::Controller(_) => unreachable!("handled before the runtime starts"),
        Command::Pilot(args) => pilot::run(args).await,
        Command::Plan(args) => plan::run(args).await,
        Command::Calibrate(args) => calibrate::run(args).await,
        Command::Replay(args) => replay::run(args).await,
        Command::Findings(args) => findings::run(args).await,
        Command::Audit { command } => audit::run(command).await,
        Command::Backup(args) => backup::run(args).await,
        Command::Restore(args) => restore::run(args).await,
        Command::Export(args) => export::run(args).await,
    }
}
