//! What a database file must pass to be kept as a backup or put back by a restore: SQLite's
//! integrity check, migrations that this program knows (the same ones, not only the same
//! numbers), and every locked study's protocol hash recomputed from its parameters, with each
//! trial carrying its study's hash, and the hash of the consent form its lock kept. Read-only: the file is never changed by a check.

use std::collections::BTreeMap;
use std::path::Path;

use bdft_protocol::study::StudyParams;
use sqlx::Connection;

use super::manifest::{Manifest, ProtocolHashes};
use crate::engine::study::schedule::protocol_hash;
use crate::error::{AppError, Result};
use crate::store;
use crate::store::backups::AppliedMigration;

/// What a checked file holds.
#[derive(Debug, Clone)]
pub struct Checked {
    /// The last migration it has applied.
    pub schema: AppliedMigration,
    pub row_counts: BTreeMap<String, i64>,
    pub hashes: ProtocolHashes,
}

/// Checks the database file `file` (see the module doc); the error names it as `named` (the
/// name the user knows: a backup's, while its copy is checked) and says what is wrong.
pub async fn check_file(file: &Path, named: &Path) -> Result<Checked> {
    let shown = named.display();
    let unreadable = |e: AppError| {
        AppError::BadRequest(format!(
            "{shown} is damaged or not a database: {}",
            e.describe()
        ))
    };
    let mut db = store::db::open_read_only(file)
        .await
        .map_err(|e| AppError::BadRequest(format!("{shown}: cannot be opened: {e:#}")))?;
    let problems = store::backups::integrity_check(&mut db)
        .await
        .map_err(unreadable)?;
    if problems != ["ok"] {
        return Err(AppError::BadRequest(format!(
            "{shown} is damaged: SQLite's integrity check found {} problem(s): {}",
            problems.len(),
            problems
                .iter()
                .take(5)
                .cloned()
                .collect::<Vec<_>>()
                .join("; ")
        )));
    }
    let applied = store::backups::applied_migrations(&mut db)
        .await
        .map_err(unreadable)?;
    let schema = known_schema(named, &applied)?;
    let hashes = protocol_hashes(named, &mut db).await?;
    if schema.version >= LOCKED_CONSENT_MIGRATION {
        consent_hashes(named, &mut db).await?;
    }
    let row_counts = store::backups::row_counts(&mut db)
        .await
        .map_err(unreadable)?;
    // Closed before the caller renames or rewrites the file (a dropped connection closes
    // later, on its own thread).
    db.close().await?;
    Ok(Checked {
        schema,
        row_counts,
        hashes,
    })
}

/// Refuses a backup whose manifest says it was made with a schema newer than this program's,
/// before anything is copied.
pub fn refuse_newer(file: &Path, manifest: &Manifest) -> Result<()> {
    let ours = store::db::MIGRATOR
        .iter()
        .map(|m| m.version)
        .max()
        .unwrap_or(0);
    if manifest.schema_version > ours {
        return Err(AppError::BadRequest(format!(
            "{} was made by a newer bdft-server ({}, schema {:04} {}); this program ({}) knows schemas up to {ours:04}. Restore it with the release that made it, or a newer one",
            file.display(),
            manifest.program_version,
            manifest.schema_version,
            manifest.schema_migration,
            env!("CARGO_PKG_VERSION"),
        )));
    }
    Ok(())
}

/// The file's last migration, if every migration it has applied is one of this program's,
/// byte for byte; a file with migrations this program does not know was made by a newer one.
fn known_schema(file: &Path, applied: &[AppliedMigration]) -> Result<AppliedMigration> {
    let shown = file.display();
    let ours: Vec<AppliedMigration> = store::db::MIGRATOR
        .iter()
        .map(|m| AppliedMigration {
            version: m.version,
            description: m.description.to_string(),
            checksum: m.checksum.to_vec(),
        })
        .collect();
    let newest_ours = ours.last().map_or_else(String::new, named);
    let Some(last) = applied.last() else {
        return Err(AppError::BadRequest(format!(
            "{shown} is not a bdft-lab database: it has no migrations applied"
        )));
    };
    let unknown: Vec<String> = applied
        .iter()
        .filter(|a| !ours.iter().any(|o| o.version == a.version))
        .map(named)
        .collect();
    if !unknown.is_empty() {
        return Err(AppError::BadRequest(format!(
            "{shown} was made by a newer bdft-server: it has migrations this program does not know ({}); this program knows up to {newest_ours}. Restore it with the release that made it, or a newer one",
            unknown.join(", ")
        )));
    }
    if let Some(changed) = applied.iter().find(|a| {
        ours.iter()
            .any(|o| o.version == a.version && o.checksum != a.checksum)
    }) {
        return Err(AppError::BadRequest(format!(
            "{shown}: its migration {} is not this program's (the SQL differs): it was made by another build of bdft-server",
            named(changed)
        )));
    }
    Ok(last.clone())
}

/// The migration from which a lock keeps the consent form's text with its hash.
const LOCKED_CONSENT_MIGRATION: i64 = 30;

/// Recomputes the SHA-256 of each consent form a lock kept: what subjects agreed to must
/// still be the text their decisions' hashes name.
async fn consent_hashes(file: &Path, db: &mut sqlx::AnyConnection) -> Result<()> {
    for (id, text, stored) in store::backups::locked_consent_forms(&mut *db).await? {
        let recomputed = bdft_protocol::hex::sha256(text.as_bytes());
        if recomputed != stored {
            return Err(AppError::BadRequest(format!(
                "{}: study {id}'s consent form does not match its hash (stored {stored}, recomputed {recomputed}): the text was changed after the lock",
                file.display()
            )));
        }
    }
    Ok(())
}

/// `0013 target step change`.
fn named(m: &AppliedMigration) -> String {
    format!("{:04} {}", m.version, m.description)
}

/// Recomputes each locked study's protocol hash from its stored parameters and checks that
/// every trial carries its study's hash.
async fn protocol_hashes(file: &Path, db: &mut sqlx::AnyConnection) -> Result<ProtocolHashes> {
    let shown = file.display();
    let studies = store::backups::locked_studies(&mut *db).await?;
    for (id, params, stored) in &studies {
        let params: StudyParams = serde_json::from_str(params).map_err(|e| {
            AppError::BadRequest(format!(
                "{shown}: the parameters of study {id} cannot be read by this program: {e}"
            ))
        })?;
        let recomputed = protocol_hash(&params);
        if &recomputed != stored {
            return Err(AppError::BadRequest(format!(
                "{shown}: study {id}'s protocol hash does not match its parameters (stored {stored}, recomputed {recomputed}): the parameters were changed after the lock"
            )));
        }
    }
    let off = store::backups::trials_off_their_protocol(&mut *db).await?;
    if let Some((trial, study)) = off.first() {
        return Err(AppError::BadRequest(format!(
            "{shown}: {} trial(s) carry a protocol hash other than their study's (first: trial {trial} of study {study})",
            off.len()
        )));
    }
    Ok(ProtocolHashes {
        studies: studies.len(),
        trials: store::backups::hashed_trials(&mut *db).await?,
    })
}
