//! `bdft-server replay`: a stored test run again through the controller's code, its record
//! compared with the stored one bit for bit, and the offline bound of cancellation.

use super::open_store;
use crate::config::DbConfig;
use crate::engine::dry_runs::replay;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    db: DbConfig,
    /// The test attempt to replay, by its trial_id (the trials export's).
    #[arg(long)]
    trial: i64,
}

pub async fn run(args: Args) -> anyhow::Result<()> {
    let pool = open_store(&args.db).await?;
    let report = replay::replay(&pool, args.trial).await?;
    println!("{}", serde_json::to_string(&report)?);
    if !report.identical {
        anyhow::bail!(
            "trial {}'s replay differs from its stored record (see the channels above)",
            args.trial
        );
    }
    Ok(())
}
