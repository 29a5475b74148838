//! `bdft-server audit verify`: the audit log's hash chain and signed checkpoints checked.

use clap::Subcommand;

use crate::config::{DbConfig, KeysConfig};
use crate::engine::operations::audit_signing;

#[derive(Debug, Subcommand)]
pub enum AuditCommand {
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

pub async fn run(command: AuditCommand) -> anyhow::Result<()> {
    let AuditCommand::Verify {
        db,
        keys,
        public_key,
    } = command;
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
    Ok(())
}
