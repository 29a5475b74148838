//! The server's audit signing key (Ed25519): made at the first start and kept beside the
//! database (`bdft-lab.audit-key`, readable by its owner only); it signs a checkpoint of the
//! audit chain's head at every start and then every few minutes (`store::audit_chain`). Its
//! public half is printed at start and in the ethics board's package, so whoever verifies a
//! copy of the database can check that its checkpoints are this server's.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use bdft_protocol::hex;
use ed25519_dalek::{SigningKey, VerifyingKey};
use sqlx::{AnyPool, Connection};

use crate::error::{AppError, Result};
use crate::store::audit_chain::Verdict;
use crate::store::{self, audit_chain};

/// How often the running server signs the head (when it moved).
pub const CHECKPOINT_EVERY: Duration = Duration::from_secs(300);

/// `bdft-lab.db` → `bdft-lab.audit-key`.
pub fn key_path(db: &Path) -> PathBuf {
    db.with_extension("audit-key")
}

fn parse_key(text: &str, path: &Path) -> anyhow::Result<SigningKey> {
    let bytes = hex::decode::<32>(text.trim()).with_context(|| {
        format!(
            "{}: not an audit signing key (64 hex digits)",
            path.display()
        )
    })?;
    Ok(SigningKey::from_bytes(&bytes))
}

/// The key beside `db`, made (mode 0600) when there is none.
pub fn load_or_create(db: &Path) -> anyhow::Result<SigningKey> {
    let path = key_path(db);
    if path.exists() {
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        return parse_key(&text, &path);
    }
    let mut bytes = [0u8; 32];
    getrandom::fill(&mut bytes).map_err(|e| anyhow::anyhow!("random audit key: {e}"))?;
    let text = hex::encode(&bytes);
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    use std::io::Write;
    let mut file = options
        .open(&path)
        .with_context(|| format!("creating {}", path.display()))?;
    file.write_all(format!("{text}\n").as_bytes())?;
    file.sync_all()?;
    Ok(SigningKey::from_bytes(&bytes))
}

/// The public key to trust when verifying: the key file's named after `db` (beside the
/// SQLite file, or in --keys-dir), else none (each checkpoint's own key, which proves less).
pub fn trusted_key(db: &Path) -> anyhow::Result<Option<VerifyingKey>> {
    let path = key_path(db);
    if !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    Ok(Some(parse_key(&text, &path)?.verifying_key()))
}

/// The public key given as `--public-key` (64 hex digits, as the server prints it).
pub fn given_key(given: &str) -> anyhow::Result<VerifyingKey> {
    let bytes = hex::decode::<32>(given.trim())
        .context("--public-key: 64 hex digits (the key the server prints at start)")?;
    VerifyingKey::from_bytes(&bytes).context("--public-key: not an Ed25519 public key")
}

/// Signs the chain's head unless the newest checkpoint holds it already.
pub async fn checkpoint_now(pool: &AnyPool, key: &SigningKey) -> crate::error::Result<()> {
    let mut tx = store::db::write_transaction(pool).await?;
    audit_chain::checkpoint(&mut tx, key, store::db::now_ms()).await?;
    tx.commit().await?;
    Ok(())
}

/// Signs the head every [`CHECKPOINT_EVERY`] while the server runs (the start signed it
/// once already).
pub async fn run_checkpoints(pool: AnyPool, key: SigningKey) {
    loop {
        tokio::time::sleep(CHECKPOINT_EVERY).await;
        if let Err(e) = checkpoint_now(&pool, &key).await {
            tracing::error!("signing the audit chain's head: {}", e.describe());
        }
    }
}

/// Verifies the store at `location` as it is, read-only (a server may be running on it):
/// refuses one that is no bdft-lab database, or one whose log was never chained.
pub async fn verify_store(
    location: &store::db::Location,
    trusted: Option<&VerifyingKey>,
) -> Result<Verdict> {
    let mut conn = store::db::connect_read_only(location)
        .await
        .map_err(|e| AppError::BadRequest(format!("not a database: {e:#}")))?;
    let tables = store::db::tables_named(&mut conn, &["audit_log", "audit_chain"])
        .await
        .map_err(|e| AppError::BadRequest(format!("not a bdft-lab database: {e}")))?;
    if !tables.iter().any(|t| t == "audit_log") {
        return Err(AppError::BadRequest(
            "not a bdft-lab database: it has no audit log".into(),
        ));
    }
    if !tables.iter().any(|t| t == "audit_chain") {
        return Err(AppError::BadRequest(
            "its audit log is not chained yet (an earlier release's database): start this release's server on it once".into(),
        ));
    }
    // One read transaction: the log, the chain and the checkpoints of one moment.
    let mut tx = conn.begin().await?;
    audit_chain::verify(&mut tx, trusted).await
}
