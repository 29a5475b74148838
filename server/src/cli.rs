//! The `bdft-server` command line.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};

use crate::config::{DbConfig, KeysConfig, ServeConfig};
use crate::engine::accounts;
use crate::engine::accounts::login_limiter::LoginLimiter;
use crate::engine::dry_runs::calibration::run::{CalibrateRequest, calibrate};
use crate::engine::dry_runs::pilot;
use crate::engine::dry_runs::power::{self, PlanRequest, PlanSource};
use crate::engine::machine::sites::{self, Sites};
use crate::engine::machine::{controller_link, estop_latch};
use crate::engine::operations::schedule::{Backups, Policy};
use crate::engine::operations::{audit_signing, backup, presence, restore};
use crate::engine::procedure::filing;
use crate::engine::results::export;
use crate::engine::results::export::{ExportFormat, ExportKind, ExportRequest, SampleCut, bids};
use crate::files::Holds;
use crate::store;
use crate::store::accounts::Role;
use bdft_protocol::link_auth::LinkKey;

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
    Pilot {
        #[command(flatten)]
        db: DbConfig,
        /// Study to add the subjects to [default: the newest; a default study if none].
        #[arg(long)]
        study: Option<i64>,
        /// Number of synthetic subjects.
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=500))]
        subjects: u32,
        /// Seed of a study created for the pilot.
        #[arg(long)]
        seed: Option<u64>,
        /// Parameters of the study created for the pilot (JSON, as `GET /api/defaults` gives
        /// them; e.g. another population) [default: the default study's]; only into a
        /// database with no study yet.
        #[arg(long, conflicts_with = "study")]
        params: Option<PathBuf>,
        /// Add an identification test (the default multisine, hold-still) to the study the
        /// pilot creates, at the start of each subject's block on the machine; a study given
        /// with --study must have one in its parameters already.
        #[arg(long)]
        identification: bool,
        /// As --identification, with the study's LQR designs tuned to each subject's fitted
        /// body (`identification.personalized`).
        #[arg(long)]
        personalized: bool,
    },
    /// The power planner: for candidate numbers of subjects, the chance that each pair of
    /// compensators differs significantly at one seat (exact Wilcoxon, Holm), from whole
    /// simulated studies; the report (JSON) on standard output, progress on standard error.
    Plan {
        #[command(flatten)]
        db: DbConfig,
        /// Study to plan [default: the newest].
        #[arg(long)]
        study: Option<i64>,
        /// Candidate numbers of subjects, comma-separated (2 to 200 each).
        #[arg(long, value_delimiter = ',', required = true)]
        subjects: Vec<usize>,
        /// `on` or `off`.
        #[arg(long, default_value = "on")]
        station: String,
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
    },
    /// Calibrate the study's synthetic population: fit its medians (and its people's spread,
    /// where the target has spreads) by simulated moments to a table of cell means or to the
    /// study's own completed tests; stores the result as the study's next population version
    /// (what its pilots and planner then use); the report (JSON) on standard output,
    /// progress on standard error.
    Calibrate {
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
    },
    /// The default study's synthetic population against the thesis's findings: per cell the
    /// median tracking error and cab acceleration, tests the interlock stopped, the riding
    /// effect per controller and the ICC of log tracking error (a Markdown table; the model
    /// card's validation table, docs/synthetic-subjects.md).
    Findings {
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
    },
    /// Back the database up to FILE, also while a server uses it: a consistent copy,
    /// checked (SQLite's integrity check, row counts, protocol hashes), with its manifest
    /// FILE.manifest.json beside it (printed too).
    Backup {
        #[command(flatten)]
        db: DbConfig,
        /// The backup to write (must not exist).
        #[arg(long)]
        out: PathBuf,
    },
    /// Put a backup back as the database of a stopped server: checked against its manifest
    /// and by SQLite first, then migrated; the database it replaces is kept beside it as
    /// DB.replaced-TIME.
    Restore {
        /// The backup (its manifest FILE.manifest.json beside it).
        #[arg(long)]
        from: PathBuf,
        #[command(flatten)]
        db: DbConfig,
    },
    /// The audit log: `audit verify` checks its hash chain and signed checkpoints.
    Audit {
        #[command(subcommand)]
        command: AuditCommand,
    },
    /// Write an export of a study as CSV or Parquet, or the study as a BIDS dataset.
    Export {
        #[command(flatten)]
        db: DbConfig,
        /// Study to export [default: the newest].
        #[arg(long)]
        study: Option<i64>,
        /// trials (one row per test attempt, with valid and latest flags), samples (1 kHz
        /// records, long format, with join keys), subjects (one row per subject, with the
        /// drawn parameters and the identified body), codebook (every column of every export:
        /// meaning, unit, type), summary (statistics per controller × station), stats
        /// (Friedman, pairwise exact Wilcoxon with Holm, on vs off, RM-ANOVA), notes (notes
        /// and reasons about tests), identification (the feedthrough each identification
        /// test measured, per excited frequency, with bounds and coherence) or audit (the whole audit log; --study is not used), or bids (the study as a BIDS
        /// dataset: a directory, --out names it; --format, --subject, --trial are not used).
        #[arg(long)]
        kind: ExportTarget,
        /// csv or parquet.
        #[arg(long, default_value = "csv")]
        format: ExportFormat,
        /// Samples only: one subject's, by code (S01).
        #[arg(long, conflicts_with = "trial")]
        subject: Option<String>,
        /// Samples only: one test attempt's, by its trial_id.
        #[arg(long)]
        trial: Option<i64>,
        /// Output file, or directory for bids (written under a temporary name and renamed
        /// when complete).
        #[arg(long)]
        out: PathBuf,
    },
}

/// Who the audit log names for a calibration from the command line.
const COMMAND_LINE_CALIBRATION: &str = "system:calibrate-command";

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

#[derive(Debug, Subcommand)]
enum AuditCommand {
    /// Checks that no audit entry was edited, deleted, reordered, inserted, appended, falsely
    /// redacted or cut off: prints "intact: N entries, head H, last checkpoint K", or the
    /// first entry that fails and why (exit status 1). Needs the audit key (beside the
    /// database, or in --keys-dir) to check keyed entries; without it, says what it could
    /// not check and exits 1. Opens the store read-only; a server may be running on it.
    Verify {
        #[command(flatten)]
        db: DbConfig,
        #[command(flatten)]
        keys: KeysConfig,
        /// The server's audit public key (64 hex digits, printed at its start) [default:
        /// the key file beside the database, or in --keys-dir].
        #[arg(long)]
        public_key: Option<String>,
    },
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

/// What `export --kind` names: one of the tables, or the BIDS dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportTarget {
    Table(ExportKind),
    Bids,
}

impl std::str::FromStr for ExportTarget {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "bids" {
            return Ok(Self::Bids);
        }
        s.parse().map(Self::Table).map_err(|e| format!("{e}, bids"))
    }
}

/// A study's parameters from a JSON file (as `GET /api/defaults` gives them).
fn read_params(path: &std::path::Path) -> anyhow::Result<bdft_protocol::study::StudyParams> {
    serde_json::from_str(
        &std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?,
    )
    .with_context(|| format!("{}: study parameters", path.display()))
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
        Command::Serve(config) => serve(*config).await?,
        Command::Controller(_) => unreachable!("handled before the runtime starts"),
        Command::Pilot {
            db,
            study,
            subjects,
            seed,
            params,
            identification,
            personalized,
        } => {
            audit_signing::use_key_if_present(&db.db)?;
            let pool = db.db.open().await?;
            let identification = identification || personalized;
            let with_identification = |mut p: bdft_protocol::study::StudyParams| {
                if identification && p.identification.is_none() {
                    p.identification = Some(Default::default());
                }
                if let Some(id) = p.identification.as_mut() {
                    id.personalized |= personalized;
                }
                p
            };
            let study = match (params, study) {
                (Some(path), _) => Some(
                    pilot::new_study(&pool, &with_identification(read_params(&path)?), seed)
                        .await?,
                ),
                (None, None) if identification && store::studies::all(&pool).await?.is_empty() => {
                    Some(
                        pilot::new_study(
                            &pool,
                            &with_identification(crate::engine::study::schedule::default_params()),
                            seed,
                        )
                        .await?,
                    )
                }
                (None, study) => {
                    if identification {
                        let s = newest_study(&pool, study).await?;
                        let params = store::studies::get(&pool, s).await?.params;
                        if params.identification.is_none() {
                            anyhow::bail!(
                                "--identification: study {s} has no identification test; add \"identification\" to its parameters"
                            );
                        }
                        if personalized && !params.identification.is_some_and(|id| id.personalized)
                        {
                            anyhow::bail!(
                                "--personalized: study {s} does not personalize its designs; set \"identification\": {{\"personalized\": true}} in its parameters"
                            );
                        }
                    }
                    study
                }
            };
            let started = std::time::Instant::now();
            let report = pilot::run(&pool, study, subjects, seed).await?;
            println!("{}", serde_json::to_string(&report)?);
            tracing::info!(
                elapsed_s = started.elapsed().as_secs_f64(),
                "pilot finished"
            );
        }
        Command::Plan {
            db,
            study,
            subjects,
            station,
            metric,
            source,
            draws,
            alpha,
            seed,
        } => {
            audit_signing::use_key_if_present(&db.db)?;
            let pool = db.db.open().await?;
            let study = newest_study(&pool, study).await?;
            let req = PlanRequest {
                source: match source {
                    PlanSourceArg::Population => PlanSource::Population,
                    PlanSourceArg::Pilot => PlanSource::Pilot,
                },
                subjects,
                metric,
                station,
                draws,
                alpha,
                seed,
            };
            let progress = std::sync::Arc::new(crate::engine::dry_runs::job::Progress::default());
            let ticker = progress_ticker(progress.clone(), "planning");
            let started = std::time::Instant::now();
            let report = power::plan_study(&pool, study, req, progress).await;
            ticker.abort();
            println!("{}", serde_json::to_string(&report?)?);
            tracing::info!(elapsed_s = started.elapsed().as_secs_f64(), "plan finished");
        }
        Command::Calibrate {
            db,
            study,
            table,
            hold_out,
            subjects,
            seed,
        } => {
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
            eprint!("{}", calibration_summary(&report.fit));
            println!("{}", serde_json::to_string(&report)?);
            tracing::info!(
                elapsed_s = started.elapsed().as_secs_f64(),
                "calibration finished"
            );
        }
        Command::Findings {
            subjects,
            surveys,
            params,
            seed,
            trial_s,
        } => {
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
        }
        Command::Audit {
            command:
                AuditCommand::Verify {
                    db,
                    keys,
                    public_key,
                },
        } => {
            let keys = match keys.stem(&db.db) {
                Ok(stem) => audit_signing::verifying_keys(&stem)?,
                Err(_) => None,
            };
            let trusted = match public_key {
                Some(given) => Some(audit_signing::given_key(&given)?),
                None => keys.as_ref().map(|(public, _)| *public),
            };
            let chain_key = keys.as_ref().map(|(_, chain)| chain);
            let verdict = audit_signing::verify_store(&db.db, trusted.as_ref(), chain_key)
                .await
                .map_err(|e| anyhow::anyhow!("{}: {}", db.db, e.describe()))?;
            if keys.is_none() {
                println!(
                    "(no key file beside the database or in --keys-dir: keyed entries cannot be checked{})",
                    if trusted.is_none() {
                        ", and checkpoints are checked against the key each names"
                    } else {
                        ""
                    }
                );
            }
            println!("{verdict}");
            if verdict.failure.is_some() {
                anyhow::bail!("the audit log of {} is not intact", db.db);
            }
            if !verdict.intact {
                anyhow::bail!("the audit log of {} could not be checked whole", db.db);
            }
        }
        Command::Backup { db, out } => {
            let path = db.db.file("a backup")?;
            if !path.is_file() {
                anyhow::bail!("--db {}: no such database", path.display());
            }
            audit_signing::use_key_if_present(&db.db)?;
            let pool = db.db.open().await?;
            let made = backup::make(&pool, &out, backup::COMMAND_LINE)
                .await
                .map_err(|e| anyhow::anyhow!(e.describe()))?;
            println!("{}", serde_json::to_string_pretty(&made)?);
        }
        Command::Restore { from, db } => {
            audit_signing::use_key_if_present(&db.db)?;
            let restored = restore::restore(&from, db.db.file("a restore")?)
                .await
                .map_err(|e| anyhow::anyhow!(e.describe()))?;
            println!("{}", serde_json::to_string_pretty(&restored)?);
            for e in &restored.erasures_undone {
                eprintln!(
                    "the backup predates the erasure of {} (subject {}, by {}): it holds their data again; erase them again",
                    e.code, e.subject_id, e.by
                );
            }
            if let Some(why) = &restored.erasures_unchecked {
                eprintln!(
                    "the replaced database's erasures could not be read ({why}): look for subject.erase in its audit log and erase those subjects again"
                );
            }
        }
        Command::Export {
            db,
            study,
            kind: ExportTarget::Bids,
            format,
            subject,
            trial,
            out,
        } => {
            if format != ExportFormat::Csv || subject.is_some() || trial.is_some() {
                anyhow::bail!(
                    "--format, --subject, --trial: a BIDS dataset is every recorded test of the study, as TSV; give none of them with --kind bids"
                );
            }
            audit_signing::use_key_if_present(&db.db)?;
            let pool = db.db.open().await?;
            let study = newest_study(&pool, study).await?;
            let mut sink = bids::DirSink::create(&out)?;
            let written = bids::write(&pool, study, &mut sink).await?;
            sink.finish()?;
            println!("{}", serde_json::to_string_pretty(&written)?);
        }
        Command::Export {
            db,
            study,
            kind: ExportTarget::Table(kind),
            format,
            subject,
            trial,
            out,
        } => {
            let req = ExportRequest {
                kind,
                format,
                cut: SampleCut::from_options(subject, trial)?,
            };
            audit_signing::use_key_if_present(&db.db)?;
            let pool = db.db.open().await?;
            let study = if kind.per_study() {
                newest_study(&pool, study).await?
            } else {
                0
            };
            let tmp = out.with_extension("partial");
            // Subject data: the owner's only, as the database is (`crate::files`).
            let file = crate::files::replace_private(&tmp)
                .map(tokio::fs::File::from_std)
                .with_context(|| format!("creating {}", tmp.display()))?;
            if let Err(e) = export::write(&pool, study, &req, file).await {
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

/// Opens the database, files trials left running as incomplete, makes sure an account or a
/// set-up link exists, starts the controller link and serves until a signal.
async fn serve(config: ServeConfig) -> anyhow::Result<()> {
    // The backup directory is checked before anything starts.
    let backups = match &config.backup.backup_dir {
        Some(_) if matches!(config.db.db, store::db::Location::Postgres(_)) => {
            anyhow::bail!("--backup-dir: a backup {}", store::db::ONLY_SQLITE_BACKUPS)
        }
        Some(dir) => std::sync::Arc::new(Backups::new(Policy {
            dir: dir.clone(),
            every: config.backup.backup_every,
            keep: config.backup.backup_keep as usize,
        })?),
        None => std::sync::Arc::default(),
    };
    // So are the sites and their key files.
    let site_links = site_links(&config)?;
    let keys = config.keys.stem(&config.db.db)?;
    let pool = store::db::open_location(&config.db.db, config.db_max_pages).await?;
    let audit_key = audit_signing::load_or_create(&keys)?;
    let audit_public = audit_key.verifying_key();
    let interrupted = filing::interrupt_running(&pool, "server restart").await?;
    if !interrupted.is_empty() {
        tracing::warn!(trials = ?interrupted, "trials that were running when the server stopped are marked incomplete");
    }
    crate::engine::machine::bench::fail_interrupted(&pool).await?;
    // A pilot process killed while it ran leaves its trials running: they are filed as soon
    // as its heartbeat stops, not at the next restart.
    tokio::spawn(filing::watch_pilots(pool.clone()));
    let listener = tokio::net::TcpListener::bind(config.listen)
        .await
        .with_context(|| format!("listening on {}", config.listen))?;
    let addr = listener.local_addr()?;
    let tls = match (&config.tls.tls_cert, &config.tls.tls_key) {
        (Some(cert), Some(key)) => Some(crate::tls::from_files(cert, key)?),
        _ if config.tls.tls_self_signed => Some(crate::tls::self_signed(
            &keys,
            &crate::tls::machine_names(addr),
        )?),
        _ => None,
    };
    let scheme = if tls.is_some() { "https" } else { "http" };
    if store::accounts::experimenter_count(&pool).await? == 0 {
        match &config.admin_password {
            Some(pw) => {
                accounts::create_experimenter(&pool, "system:startup", "admin", pw, Role::Admin)
                    .await
                    .map_err(|e| anyhow::anyhow!("--admin-password: {e}"))?;
                println!("Created the admin account \"admin\".");
            }
            None => {
                let token = accounts::new_setup_token(&pool).await?;
                println!(
                    "First start: create the experimenter account at {scheme}://{addr}/setup?token={token}"
                );
            }
        }
    }
    if config.lsl {
        crate::engine::procedure::lsl::enable(config.lsl_scope);
        tracing::info!(
            scope = config.lsl_scope.as_str(),
            "LSL: each station's signal and marker streams are published"
        );
    }
    // The E-stop latch before any controller connects: each is told it.
    let latch = estop_latch::EStopLatch::open(&keys, &pool).await?;
    // Every file is made by now: those an older release, a copy or a hand left open to
    // other users are named, with the command that closes them.
    crate::files::warn_open(&kept_files(&config, &keys));
    let events = controller_link::event_channel();
    let filing = filing::LinkFiling::start(pool.clone(), events.clone());
    let links = site_links
        .into_iter()
        .map(|site| {
            controller_link::ControllerLink::start(
                site,
                events.clone(),
                filing.clone(),
                latch.clone(),
            )
        })
        .collect();
    let sites = Sites::new(links, events, latch.clone());
    tokio::spawn(estop_latch::record_pending(latch, pool.clone()));
    tokio::spawn(crate::engine::procedure::lsl::republish_on_reconnect(
        pool.clone(),
        sites.clone(),
    ));
    tokio::spawn(backups.clone().run_schedule(pool.clone()));
    // A restore refuses to replace the database while this beats.
    let presence = presence::announce(&pool, &addr.to_string()).await?;
    let mut state = crate::state::AppState::new(pool, sites);
    state.web_dir = config.web_dir;
    state.login = std::sync::Arc::new(LoginLimiter::new(config.login.limits()));
    state.pairing = std::sync::Arc::new(crate::engine::procedure::stations::Pairing::new(
        config.connections.pairing_limits(),
    ));
    state.https = tls.is_some();
    state.audit_public = Some(audit_public);
    state.backups = backups;
    // The head after the start's own entries is signed before anyone is served.
    audit_signing::checkpoint_now(&state.pool, &audit_key)
        .await
        .map_err(|e| anyhow::anyhow!("signing the audit chain's head: {}", e.describe()))?;
    tokio::spawn(audit_signing::run_checkpoints(
        state.pool.clone(),
        audit_key,
    ));
    if let Some(t) = &tls {
        // Printed before the address line: whoever reads the address has the fingerprint.
        println!("TLS certificate SHA-256 fingerprint: {}", t.fingerprint);
    }
    println!(
        "Audit log signing key (Ed25519, public): {}",
        store::audit_chain::public_key_hex(&audit_public)
    );
    println!("bdft-lab server on {scheme}://{addr}");
    use std::io::Write;
    let _ = std::io::stdout().flush();
    crate::run(state, listener, &config.connections, tls, shutdown_signal()).await?;
    presence.end().await?;
    Ok(())
}

/// The files `serve` keeps that hold keys or subject data, for the check of who else may
/// read them (`crate::files`): the database's, the keys, the E-stop latch, the backups.
fn kept_files(config: &ServeConfig, keys: &std::path::Path) -> Vec<(PathBuf, Holds)> {
    let mut files = vec![
        (audit_signing::key_path(keys), Holds::Secret),
        (estop_latch::latch_path(keys), Holds::Data),
    ];
    if let store::db::Location::File(db) = &config.db.db {
        files.extend(
            crate::files::database_files(db)
                .into_iter()
                .map(|f| (f, Holds::Data)),
        );
    }
    match &config.tls.tls_key {
        Some(key) => files.push((key.clone(), Holds::Secret)),
        None if config.tls.tls_self_signed => {
            files.push((crate::tls::self_signed_paths(keys).1, Holds::Secret));
        }
        None => {}
    }
    if let Some(dir) = &config.backup.backup_dir {
        files.push((dir.clone(), Holds::DataDir));
        if let Ok(entries) = std::fs::read_dir(dir) {
            files.extend(entries.flatten().map(|e| (e.path(), Holds::Data)));
        }
    }
    files
}

/// Each site's controller: where it comes from and its link key. Without --site, the one
/// site "main" with --controller or a started controller.
fn site_links(config: &ServeConfig) -> anyhow::Result<Vec<controller_link::LinkConfig>> {
    let silence = std::time::Duration::from_millis(config.controller_silence_ms);
    // A controller this server starts: this executable's own (or --controller-bin), with
    // --lsl when the server publishes streams and the --controller-arg given.
    let spawn = || -> anyhow::Result<controller_link::ControllerSource> {
        let (bin, sub) = match &config.controller_bin {
            Some(bin) => (bin.clone(), "serve"),
            None => (
                std::env::current_exe().context("locating this executable")?,
                "controller",
            ),
        };
        let lsl = config.lsl.then(|| {
            [
                "--lsl".to_string(),
                format!("--lsl-scope={}", config.lsl_scope.as_str()),
            ]
        });
        let args = std::iter::once(sub.to_string())
            .chain(lsl.into_iter().flatten())
            .chain(config.controller_args.iter().cloned())
            .collect();
        Ok(controller_link::ControllerSource::Spawn { bin, args })
    };
    // A started controller gets --controller-key-file's key, or a new one at every start.
    let started_key = || match &config.controller_key_file {
        Some(path) => LinkKey::load(path),
        None => LinkKey::generate(),
    };
    if config.sites.is_empty() {
        let (source, key) = match config.controller {
            Some(a) => {
                let Some(path) = &config.controller_key_file else {
                    anyhow::bail!(
                        "--controller {a} needs --controller-key-file FILE: the key the controller was started with (`bdft-controller keygen FILE`, then `bdft-controller serve --key-file FILE` there)"
                    )
                };
                (
                    controller_link::ControllerSource::Connect(a),
                    LinkKey::load(path)?,
                )
            }
            None => (spawn()?, started_key()?),
        };
        return Ok(vec![controller_link::LinkConfig {
            site: sites::DEFAULT.to_string(),
            source,
            key,
            silence,
        }]);
    }
    let mut seen = std::collections::BTreeSet::new();
    let mut links = Vec::new();
    for site in &config.sites {
        if !seen.insert(site.name.as_str()) {
            anyhow::bail!("--site {}: given twice; each site once", site.name);
        }
        let (source, key) = match &site.remote {
            Some((addr, key_file)) => (
                controller_link::ControllerSource::Connect(*addr),
                LinkKey::load(key_file)
                    .with_context(|| format!("--site {}: its key file", site.name))?,
            ),
            None => (spawn()?, started_key()?),
        };
        links.push(controller_link::LinkConfig {
            site: site.name.clone(),
            source,
            key,
            silence,
        });
    }
    Ok(links)
}

async fn shutdown_signal() {
    bdft_controller::runtime::shutdown_signal().await;
    tracing::info!("shutting down");
}

/// `plan --source`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum PlanSourceArg {
    Population,
    Pilot,
}

/// A calibration's verdict, parameters at a bound and held-out rows, as text for standard
/// error (the report itself is JSON on standard output).
fn calibration_summary(fit: &crate::engine::dry_runs::calibration::fit::FitReport) -> String {
    let num = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.4}"));
    let mut out = format!("verdict: {}\n", fit.goodness_of_fit.verdict);
    if !fit.at_bound.is_empty() {
        out += &format!("at a bound: {}\n", fit.at_bound.join(", "));
    }
    for c in &fit.held_out {
        out += &format!(
            "held out {} {} {}: predicted {:.4} [{}, {}], target {}: {}\n",
            c.controller,
            c.station,
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
