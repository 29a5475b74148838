//! One backup: a consistent copy of the live database written while trials go on being
//! filed (`VACUUM INTO`: one read transaction, so the copy is the database at one moment),
//! checked after writing (`checks`), hashed, and described by its manifest. The file appears
//! under its name only once it passed; a failed backup leaves nothing behind but its audit
//! row.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;
use sqlx::AnyPool;

use super::checks::check_file;
use super::manifest::{self, FORMAT, Manifest, io_error};
use crate::error::{AppError, Result};
use crate::store::{self, Change};

/// A conflict when `pool` is not a SQLite store: a backup is a copy of its file.
pub fn only_of_sqlite(pool: &AnyPool) -> Result<()> {
    if store::db::Dialect::of_pool(pool) == store::db::Dialect::Postgres {
        return Err(AppError::Conflict(format!(
            "a backup {}",
            store::db::ONLY_SQLITE_BACKUPS
        )));
    }
    Ok(())
}

/// Who the audit log names for a backup made from the command line.
pub const COMMAND_LINE: &str = "system:backup-command";

/// Backs the database of `pool` up to `out` (which must not exist) with its manifest beside
/// it; `made_by` is who asked (an account or a `system:` actor). Audited as `backup.create`,
/// or `backup.fail` with the reason.
pub async fn make(pool: &AnyPool, out: &Path, made_by: &str) -> Result<Manifest> {
    only_of_sqlite(pool)?;
    refuse_to_overwrite(out)?;
    let partial = partial_of(out);
    let outcome = write_checked(pool, out, &partial, made_by).await;
    if outcome.is_err() {
        // Nothing half-written stays behind.
        let _ = std::fs::remove_file(&partial);
    }
    let file = out.display().to_string();
    let change = Change::begin(pool, made_by).await?;
    match &outcome {
        Ok(m) => {
            let detail = Made {
                file,
                sha256: &m.sha256,
                bytes: m.bytes,
                schema_version: m.schema_version,
                took_ms: m.took_ms,
            };
            change.commit("backup.create", None, detail).await?;
        }
        Err(e) => {
            let detail = Failed {
                file,
                error: e.describe(),
            };
            change.commit("backup.fail", None, detail).await?;
        }
    }
    outcome
}

/// The audit detail of `backup.create`.
#[derive(Serialize)]
struct Made<'a> {
    file: String,
    sha256: &'a str,
    bytes: u64,
    schema_version: i64,
    took_ms: u64,
}

/// The audit detail of `backup.fail`.
#[derive(Serialize)]
struct Failed {
    file: String,
    error: String,
}

fn refuse_to_overwrite(out: &Path) -> Result<()> {
    for p in [out.to_path_buf(), manifest::path_of(out)] {
        if p.exists() {
            return Err(AppError::Conflict(format!(
                "{} exists: a backup never overwrites a file; choose a new name",
                p.display()
            )));
        }
    }
    match out.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(dir) if !dir.is_dir() => Err(AppError::BadRequest(format!(
            "{}: no such directory for the backup",
            dir.display()
        ))),
        _ => Ok(()),
    }
}

/// `FILE.partial`: where the copy is written and checked before it takes its name.
fn partial_of(out: &Path) -> PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    out.with_file_name(name)
}

async fn write_checked(
    pool: &AnyPool,
    out: &Path,
    partial: &Path,
    made_by: &str,
) -> Result<Manifest> {
    // A partial file is only ever one of ours that a crash left behind. The copy is made
    // into an empty file of ours (SQLite takes an empty one), so it is private from its
    // first byte: SQLite would create it with the umask's mode.
    crate::files::replace_private(partial).map_err(|e| io_error(partial, "creating", e))?;
    let audit_before = store::backups::audit_rows(pool).await?;
    let started = Instant::now();
    let created_at_ms = store::db::now_ms();
    store::backups::vacuum_into(pool, partial).await?;
    let checked = check_file(partial, out).await?;
    // Every change is committed with its audit row and the log is append-only: a copy with
    // fewer rows than the log had before the copy began would have lost changes.
    let copied = checked.row_counts.get("audit_log").copied().unwrap_or(0);
    if copied < audit_before {
        return Err(AppError::Internal(anyhow::anyhow!(
            "the copy holds {copied} audit rows, the database had {audit_before} before the copy began"
        )));
    }
    let hashed = partial.to_path_buf();
    let (sha256, bytes) = tokio::task::spawn_blocking(move || manifest::sha256_of(&hashed))
        .await
        .map_err(|e| AppError::Internal(anyhow::anyhow!("hashing the backup: {e}")))??;
    std::fs::rename(partial, out).map_err(|e| io_error(out, "naming the backup", e))?;
    let manifest = Manifest {
        format: FORMAT.into(),
        file: out
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned(),
        sha256,
        bytes,
        program_version: env!("CARGO_PKG_VERSION").into(),
        schema_version: checked.schema.version,
        schema_migration: checked.schema.description,
        created_at: store::db::rfc3339(created_at_ms),
        created_at_ms,
        took_ms: started.elapsed().as_millis() as u64,
        made_by: made_by.into(),
        row_counts: checked.row_counts,
        protocol_hashes_verified: checked.hashes,
    };
    if let Err(e) = manifest::write(out, &manifest) {
        let _ = std::fs::remove_file(out);
        return Err(e);
    }
    Ok(manifest)
}
