//! The server's audit signing key (Ed25519): made at the first start and kept beside the
//! database (`bdft-lab.audit-key`, readable by its owner only), or in `--keys-dir`; it signs
//! a checkpoint of the audit chain's head at every start, then every 5 minutes while the
//! head moves, and within a second of an entry written without the key
//! (`store::audit_chain`). The chain's HMAC key is derived from it
//! (`audit_chain::ChainKey`): a process that loads the key file keys every entry it writes,
//! and `audit verify` needs it to check them. Its public half is printed at start and in the
//! ethics board's package, so whoever verifies a copy of the database can check that its
//! checkpoints are this server's.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use bdft_protocol::hex;
use ed25519_dalek::{SigningKey, VerifyingKey};
use sqlx::{AnyPool, Connection};

use crate::error::{AppError, Result};
use crate::store::audit_chain::{ChainKey, Verdict};
use crate::store::{self, audit_chain};

/// How often the running server signs the head (when it moved).
pub const CHECKPOINT_EVERY: Duration = Duration::from_secs(300);

/// How often it looks for entries written without the key, which only a checkpoint covers.
pub const UNKEYED_CHECK_EVERY: Duration = Duration::from_secs(1);

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

/// The key beside `db`, made (mode 0600) when there is none; its chain key becomes this
/// process's, so every audit entry it writes from now on is keyed.
pub fn load_or_create(db: &Path) -> anyhow::Result<SigningKey> {
    let key = load_or_create_file(db)?;
    audit_chain::use_key(ChainKey::from_signing_key(&key))
        .map_err(|e| anyhow::anyhow!(e.describe()))?;
    Ok(key)
}

/// The key file named after `stem`, if there is one: its chain key becomes this process's
/// (a command that writes audit entries: `pilot`, `calibrate`, `backup`, `restore`, …). The
/// stem is the SQLite file, or `bdft-lab` in `BDFT_KEYS_DIR` for a PostgreSQL store; without
/// a key the command's entries are unkeyed, and count once the server signs them.
pub fn use_key_if_present(db: &store::db::Location) -> anyhow::Result<()> {
    let stem = match db {
        store::db::Location::File(path) => path.clone(),
        store::db::Location::Postgres(_) => match std::env::var_os("BDFT_KEYS_DIR") {
            Some(dir) => PathBuf::from(dir).join("bdft-lab"),
            None => return Ok(()),
        },
    };
    let path = key_path(&stem);
    if !path.exists() {
        return Ok(());
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let key = parse_key(&text, &path)?;
    audit_chain::use_key(ChainKey::from_signing_key(&key))
        .map_err(|e| anyhow::anyhow!(e.describe()))
}

fn load_or_create_file(db: &Path) -> anyhow::Result<SigningKey> {
    let path = key_path(db);
    if path.exists() {
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        return parse_key(&text, &path);
    }
    let mut bytes = [0u8; 32];
    getrandom::fill(&mut bytes).map_err(|e| anyhow::anyhow!("random audit key: {e}"))?;
    let text = hex::encode(&bytes);
    use std::io::Write;
    let mut file = crate::files::new_private()
        .open(&path)
        .with_context(|| format!("creating {}", path.display()))?;
    file.write_all(format!("{text}\n").as_bytes())?;
    file.sync_all()?;
    Ok(SigningKey::from_bytes(&bytes))
}

/// The keys to verify with, from the key file named after `db` (beside the SQLite file, or
/// in --keys-dir): the public key to trust and the chain key; none without the file (then
/// each checkpoint's own key is taken, which proves less, and keyed entries go unchecked).
pub fn verifying_keys(db: &Path) -> anyhow::Result<Option<(VerifyingKey, ChainKey)>> {
    let path = key_path(db);
    if !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let key = parse_key(&text, &path)?;
    Ok(Some((
        key.verifying_key(),
        ChainKey::from_signing_key(&key),
    )))
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
/// once already), and within [`UNKEYED_CHECK_EVERY`] of an entry written without the key
/// (only a checkpoint vouches for such an entry).
pub async fn run_checkpoints(pool: AnyPool, key: SigningKey) {
    let mut last = tokio::time::Instant::now();
    loop {
        tokio::time::sleep(UNKEYED_CHECK_EVERY).await;
        let due = if last.elapsed() >= CHECKPOINT_EVERY {
            Ok(true)
        } else {
            unkeyed_waiting(&pool).await
        };
        let signed = match due {
            Ok(true) => checkpoint_now(&pool, &key).await.map(|()| true),
            other => other,
        };
        match signed {
            Ok(true) => last = tokio::time::Instant::now(),
            Ok(false) => {}
            Err(e) => tracing::error!("signing the audit chain's head: {}", e.describe()),
        }
    }
}

async fn unkeyed_waiting(pool: &AnyPool) -> Result<bool> {
    let mut conn = pool.acquire().await?;
    audit_chain::unkeyed_after_checkpoint(&mut conn).await
}

/// Verifies the store at `location` as it is, read-only (a server may be running on it):
/// refuses one that is no bdft-lab database, or one whose log was never chained.
pub async fn verify_store(
    location: &store::db::Location,
    trusted: Option<&VerifyingKey>,
    chain_key: Option<&ChainKey>,
) -> Result<Verdict> {
    let mut conn = store::db::connect_read_only(location)
        .await
        .map_err(|e| AppError::BadRequest(format!("not a database: {e:#}")))?;
    let tables = store::db::tables_named(&mut conn, &["audit_log", "audit_chain", "audit_salts"])
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
    if !tables.iter().any(|t| t == "audit_salts") {
        return Err(AppError::BadRequest(
            "its audit log predates keyed hashes (an earlier release's database): start this release's server on it once".into(),
        ));
    }
    // One read transaction: the log, the chain and the checkpoints of one moment.
    let mut tx = conn.begin().await?;
    audit_chain::verify_with(&mut tx, trusted, chain_key).await
}
