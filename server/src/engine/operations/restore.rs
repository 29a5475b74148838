//! `bdft-server restore`: a backup put back as the database of a stopped server. Nothing is
//! replaced until the copy has passed every check: the file is copied next to the database,
//! its SHA-256 and row counts compared with its manifest, checked (`checks`: integrity,
//! migrations this program knows, protocol hashes), migrated and given its audit row; only
//! then does it take the database's name, in one rename. The database it replaces is kept
//! beside it (`DB.replaced-TIME`), so a restore never destroys what was recorded since.
//!
//! A backup taken before an erasure holds the erased subject's data: a restore lists the
//! erasures of the replaced database whose subjects the restored one holds again
//! (`erasures_undone`), so that they are erased again.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::checks::check_file;
use super::manifest::{self, io_error};
use super::presence::refuse_if_held;
use crate::error::{AppError, Result};
use crate::files::with_suffix;
use crate::store::erasure::ErasureRow;
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
    /// The erasures recorded in the replaced database whose subjects' data the restored one
    /// holds again (the backup was taken before them): erase these subjects again.
    pub erasures_undone: Vec<ErasureRow>,
    /// Why the replaced database's erasures could not be read, when they could not (then
    /// check them by hand in the kept file's audit log, action `subject.erase`).
    pub erasures_unchecked: Option<String>,
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
    // Beside the database, so the final rename stays on one file system.
    let staging = with_suffix(db, ".restoring");
    let outcome = stage(from, &manifest, db, &staging).await;
    if outcome.is_err() {
        let _ = std::fs::remove_file(&staging);
    }
    let schema_version = outcome?;
    // The server may have started while the copy was checked.
    refuse_if_held(db).await?;
    let replaced_kept_as = if db.exists() {
        let kept = with_suffix(
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
        // A link shares the database's permissions: an older release's database was made
        // readable by everyone, and the kept copy is one more file of subject data.
        crate::files::make_private(&kept).map_err(|e| io_error(&kept, "making private", e))?;
        Some(kept)
    } else {
        None
    };
    std::fs::rename(&staging, db).map_err(|e| io_error(db, "renaming the restored copy to", e))?;
    // The restore is done: what follows reports, and fails nothing.
    let (erasures_undone, erasures_unchecked) = match &replaced_kept_as {
        None => (Vec::new(), None),
        Some(kept) => match undone_erasures(kept, db).await {
            Ok(undone) => (undone, None),
            Err(e) => (Vec::new(), Some(e.describe())),
        },
    };
    Ok(Restored {
        db: db.to_path_buf(),
        from: from.to_path_buf(),
        sha256: manifest.sha256,
        backup_created_at: manifest.created_at,
        schema_version_of_backup: manifest.schema_version,
        schema_version,
        replaced_kept_as,
        erasures_undone,
        erasures_unchecked,
    })
}

/// The erasures recorded in the database `replaced` whose subject the database `restored`
/// holds again, not erased (same id and code).
async fn undone_erasures(replaced: &Path, restored: &Path) -> Result<Vec<ErasureRow>> {
    let open = |path: &Path| {
        let path = path.to_path_buf();
        async move {
            store::db::open_read_only(&path)
                .await
                .map_err(|e| AppError::Unavailable(format!("{}: {e:#}", path.display())))
        }
    };
    let (mut replaced, mut restored) = (open(replaced).await?, open(restored).await?);
    let mut undone = Vec::new();
    for erasure in store::erasure::erasures(&mut replaced).await? {
        let held = match store::subjects::get(&mut restored, erasure.subject_id).await {
            Ok(s) => s.code == erasure.code && s.erased_at.is_none(),
            Err(AppError::NotFound(_)) => false,
            Err(e) => return Err(e),
        };
        if held {
            undone.push(erasure);
        }
    }
    Ok(undone)
}

/// Copies, verifies, migrates and audits the backup at `staging`; returns its schema version
/// after migration.
async fn stage(
    from: &Path,
    manifest: &manifest::Manifest,
    db: &Path,
    staging: &Path,
) -> Result<i64> {
    // Copied into a private file of ours, not by `fs::copy`, which would give the copy the
    // backup's permissions (an older release's were readable by everyone), and the copy
    // becomes the database.
    std::fs::File::open(from)
        .and_then(|mut backup| {
            let mut copy = crate::files::replace_private(staging)?;
            std::io::copy(&mut backup, &mut copy)
        })
        .map_err(|e| io_error(from, "copying", e))?;
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
            RestoreDetail {
                from: from.display().to_string(),
                into: db.display().to_string(),
                sha256: &manifest.sha256,
                backup_created_at: &manifest.created_at,
                schema_version_of_backup: manifest.schema_version,
            },
        )
        .await?;
    let left = store::db::leave_wal(&pool).await;
    pool.close().await;
    left.map_err(|e| AppError::Internal(e.context("closing the restored copy")))?;
    Ok(schema_version)
}

/// The audit detail of `backup.restore`.
#[derive(Serialize)]
struct RestoreDetail<'a> {
    from: String,
    into: String,
    sha256: &'a str,
    backup_created_at: &'a str,
    schema_version_of_backup: i64,
}
