//! `bdft-server export`: a study's export as CSV or Parquet, or the study as a BIDS dataset.

use std::path::PathBuf;

use anyhow::Context;

use super::{newest_study, open_store};
use crate::config::DbConfig;
use crate::engine::results::export;
use crate::engine::results::export::{ExportFormat, ExportKind, ExportRequest, SampleCut, bids};

#[derive(Debug, clap::Args)]
pub struct Args {
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

pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        db,
        study,
        kind,
        format,
        subject,
        trial,
        out,
    } = args;
    match kind {
        ExportTarget::Bids => {
            if format != ExportFormat::Csv || subject.is_some() || trial.is_some() {
                anyhow::bail!(
                    "--format, --subject, --trial: a BIDS dataset is every recorded test of the study, as TSV; give none of them with --kind bids"
                );
            }
            let pool = open_store(&db).await?;
            let study = newest_study(&pool, study).await?;
            let mut sink = bids::DirSink::create(&out)?;
            let written = bids::write(&pool, study, &mut sink).await?;
            sink.finish()?;
            println!("{}", serde_json::to_string_pretty(&written)?);
        }
        ExportTarget::Table(kind) => {
            let req = ExportRequest {
                kind,
                format,
                cut: SampleCut::from_options(subject, trial)?,
            };
            let pool = open_store(&db).await?;
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
