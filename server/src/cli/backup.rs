//! `bdft-server backup`: a checked copy of the database, with its manifest.

use std::path::PathBuf;

use super::open_store;
use crate::config::DbConfig;
use crate::engine::operations::backup;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    db: DbConfig,
    /// The backup to write (must not exist).
    #[arg(long)]
    out: PathBuf,
}

pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args { db, out } = args;
    let path = db.db.file("a backup")?;
    if !path.is_file() {
        anyhow::bail!("--db {}: no such database", path.display());
    }
    let pool = open_store(&db).await?;
    let made = backup::make(&pool, &out, backup::COMMAND_LINE)
        .await
        .map_err(|e| anyhow::anyhow!(e.describe()))?;
    println!("{}", serde_json::to_string_pretty(&made)?);
    Ok(())
}
