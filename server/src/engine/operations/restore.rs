//! `bdft-server restore`: a backup put back as the database of a stopped server. Nothing is
//! replaced until the copy has passed every check: the file is copied next to the database,
//! its SHA-256 and row counts compared with its manifest, checked (`checks`: integrity,
//! migrations this program knows, protocol hashes), migrated and given its audit row; only
//! then does it take the database's name, in one rename. The database it replaces is kept
//! beside it (`DB.replaced-TIME`), so a restore never destroys what was recorded since.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::json;

use super::checks::check_file;
use super::manifest::{self, io_error};
use super::presence::refuse_if_held;
use crate::error::{AppError, Result};
use crate::store::{self, Change};

/// Who the audit log names for a restore (always from the command line, onto a stopped
/// server).
pub const COMMAND_LINE: &str = "system:restore-command";

#[derive(Debug, Clone, Serialize)]
pub struct Restored {
    pub db: PathBuf,
    pub from: PathBuf,
    pub sha256: String,
    /// When the backup was taken.
    pub backup_created_at: String,
    /// The migration the backup had, and the one the database has now.
    pub schema_version_of_backup: i64,
    pub schema_version: i64,
    /// Where the database that was replaced is kept (none if there was none).
    pub replaced_kept_as: Option<PathBuf>,
}

/// Restores the backup `from` (with its manifest beside it) as the database `db`.
pub async fn restore(from: &Path, db: &Path) -> Result<Restored> {
    let manifest = manifest::read(from)?;
    super::checks::refuse_newer(from, &manifest)?;
    if let Some(dir) = db
        .parent()
        .filter(|d| !d.as_os_str().is_empty() && !d.is_dir())
    {
        return Err(AppError::BadRequest(format!(
            "--db {}: no such directory {}",
            db.display(),
            dir.display()
        )));
    }
    refuse_if_held(db).await?;
    let staging = sibling(db, ".restoring");
    let outcome = stage(from, &manifest, db, &staging).await;
    if outcome.is_err() {
        let _ = std::fs::remove_file(&staging);
    }
    let schema_version = outcome?;
    // The server may have started while the copy was checked.
    refuse_if_held(db).await?;
    let replaced_kept_as = if db.exists() {
        let kept = sibling(
            db,
            &format!(
                ".replaced-{}",
                store::db::rfc3339(store::db::now_ms()).replace(':', "-")
            ),
        );
        // Its last transactions are folded in from its write-ahead log first: a log left
        // beside the new file would be read as the new file's.
        store::db::fold_into_one_file(db)
            .await
            .map_err(|e| AppError::Unavailable(format!("{}: {e:#}", db.display())))?;
        std::fs::hard_link(db, &kept)
            .map_err(|e| io_error(&kept, "keeping the replaced database as", e))?;
        Some(kept)
    } else {
        None
    };
    std::fs::rename(&staging, db).map_err(|e| io_error(db, "renaming the restored copy to", e))?;
    Ok(Restored {
        db: db.to_path_buf(),
        from: from.to_path_buf(),
        sha256: manifest.sha256,
        backup_created_at: manifest.created_at,
        schema_version_of_backup: manifest.schema_version,
        schema_version,
        replaced_kept_as,
    })
}

/// `DB` + suffix, in the database's directory (so the final rename stays on one file system).
fn sibling(db: &Path, suffix: &str) -> PathBuf {
    let mut name = db.file_name().unwrap_or_default().to_os_string();
    name.push(suffix);
    db.with_file_name(name)
}

/// Copies, verifies, migrates and audits the backup at `staging`; returns its schema version
/// after migration.
async fn stage(
    from: &Path,
    manifest: &manifest::Manifest,
    db: &Path,
    staging: &Path,
) -> Result<i64> {
    let _ = std::fs::remove_file(staging);
    std::fs::copy(from, staging).map_err(|e| io_error(from, "copying", e))?;
    let hashed = staging.to_path_buf();
    let (sha256, bytes) = tokio::task::spawn_blocking(move || manifest::sha256_of(&hashed))
        .await
        .map_err(|e| AppError::Internal(anyhow::anyhow!("hashing the backup: {e}")))??;
    if sha256 != manifest.sha256 || bytes != manifest.bytes {
        return Err(AppError::BadRequest(format!(
            "{} is damaged: its SHA-256 is {sha256} ({bytes} bytes), its manifest says {} ({} bytes)",
            from.display(),
            manifest.sha256,
            manifest.bytes
        )));
    }
    let checked = check_file(staging, from).await?;
    if checked.row_counts != manifest.row_counts {
        let differing: Vec<String> = checked
            .row_counts
            .iter()
            .filter(|(t, n)| manifest.row_counts.get(*t) != Some(n))
            .map(|(t, n)| {
                format!(
                    "{t}: {n} in the file, {:?} in the manifest",
                    manifest.row_counts.get(t)
                )
            })
            .collect();
        return Err(AppError::BadRequest(format!(
            "{}: its rows are not the ones its manifest lists ({})",
            from.display(),
            differing.join("; ")
        )));
    }
    let pool = store::db::open_alone(staging)
        .await
        .map_err(|e| AppError::Internal(e.context("migrating the restored copy")))?;
    let mut change = Change::begin(&pool, COMMAND_LINE).await?;
    let schema_version = store::backups::schema_version(change.db()).await?;
    // The servers the backup saw ran on the database it was taken from, not on this one.
    store::server_runs::end_all(change.db()).await?;
    change
        .commit(
            "backup.restore",
            None,
            json!({
                "from": from.display().to_string(),
                "into": db.display().to_string(),
                "sha256": manifest.sha256,
                "backup_created_at": manifest.created_at,
                "schema_version_of_backup": manifest.schema_version,
            }),
        )
        .await?;
    let left = store::db::leave_wal(&pool).await;
    pool.close().await;
    left.map_err(|e| AppError::Internal(e.context("closing the restored copy")))?;
    Ok(schema_version)
}
