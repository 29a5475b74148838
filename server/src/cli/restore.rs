//! `bdft-server restore`: a backup put back as a stopped server's database.

use std::path::PathBuf;

use crate::config::DbConfig;
use crate::engine::operations::{audit_signing, restore};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The backup (its manifest FILE.manifest.json beside it).
    #[arg(long)]
    from: PathBuf,
    #[command(flatten)]
    db: DbConfig,
}

pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args { from, db } = args;
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
    Ok(())
}
