//! A backup's manifest: the JSON file beside it (`FILE.manifest.json`) that says what the
//! file is — its SHA-256 and size, the program and schema that made it, when, and what it
//! held — so a restore can tell a damaged or foreign file from a good one before anything is
//! replaced.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::error::{AppError, Result};

/// The manifest's own format; a restore refuses one it does not know.
pub const FORMAT: &str = "bdft-backup/1";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// `bdft-backup/1`.
    pub format: String,
    /// The backup's file name (beside this manifest).
    pub file: String,
    /// SHA-256 of the file, hex.
    pub sha256: String,
    pub bytes: u64,
    /// The version of bdft-server that made it.
    pub program_version: String,
    /// The last migration the file has applied: its number and description.
    pub schema_version: i64,
    pub schema_migration: String,
    /// When the copy was taken (RFC 3339 UTC) and in ms since the Unix epoch.
    pub created_at: String,
    pub created_at_ms: i64,
    /// How long the copy and its checks took (ms).
    pub took_ms: u64,
    /// Who made it: an account, `system:backup-schedule` or `system:backup-command`.
    pub made_by: String,
    /// Every table's rows in the copy.
    pub row_counts: BTreeMap<String, i64>,
    /// Locked studies whose protocol hash was recomputed from their parameters and matched,
    /// and trials checked to carry their study's hash.
    pub protocol_hashes_verified: ProtocolHashes,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ProtocolHashes {
    pub studies: usize,
    pub trials: i64,
}

/// What a backup's file name is followed by in its manifest's.
const SUFFIX: &str = ".manifest.json";

/// Where the manifest of `file` is: `FILE.manifest.json` beside it.
pub fn path_of(file: &Path) -> PathBuf {
    let mut name = file.file_name().unwrap_or_default().to_os_string();
    name.push(SUFFIX);
    file.with_file_name(name)
}

/// Writes the manifest of `file` beside it, whole or not at all (a temporary name, renamed).
pub fn write(file: &Path, manifest: &Manifest) -> Result<()> {
    let path = path_of(file);
    let tmp = path.with_extension("partial");
    let text = serde_json::to_string_pretty(manifest)
        .map_err(|e| AppError::Internal(anyhow::anyhow!("manifest: {e}")))?;
    crate::files::replace_private(&tmp)
        .and_then(|mut f| std::io::Write::write_all(&mut f, (text + "\n").as_bytes()))
        .and_then(|()| std::fs::rename(&tmp, &path))
        .map_err(|e| io_error(&path, "writing", e))
}

/// Reads the manifest beside `file`; an error names what is wrong with it.
pub fn read(file: &Path) -> Result<Manifest> {
    let path = path_of(file);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        AppError::BadRequest(format!(
            "{}: cannot read the backup's manifest ({e}); a backup is its file and the manifest beside it, FILE.manifest.json",
            path.display()
        ))
    })?;
    let manifest: Manifest = serde_json::from_str(&text).map_err(|e| {
        AppError::BadRequest(format!(
            "{}: not a backup manifest of this program ({e})",
            path.display()
        ))
    })?;
    if manifest.format != FORMAT {
        return Err(AppError::BadRequest(format!(
            "{}: manifest format {:?}; this program reads {FORMAT:?}",
            path.display(),
            manifest.format
        )));
    }
    Ok(manifest)
}

/// The backups in `dir`, found by their manifests (`FILE.manifest.json`), in file-name order:
/// each backup's file name, and its manifest or what is wrong with it.
pub fn in_dir(dir: &Path) -> Result<Vec<(String, Result<Manifest>)>> {
    let entries = std::fs::read_dir(dir).map_err(|e| io_error(dir, "listing", e))?;
    let mut found: Vec<(String, Result<Manifest>)> = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let file = name.strip_suffix(SUFFIX)?.to_string();
            let manifest = read(&dir.join(&file));
            Some((file, manifest))
        })
        .collect();
    found.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(found)
}

/// SHA-256 (hex) and size of a file, read in 1 MiB blocks.
pub fn sha256_of(file: &Path) -> Result<(String, u64)> {
    let mut f = std::fs::File::open(file).map_err(|e| io_error(file, "reading", e))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut bytes = 0u64;
    loop {
        let n = f.read(&mut buf).map_err(|e| io_error(file, "reading", e))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
        bytes += n as u64;
    }
    Ok((bdft_protocol::hex::encode(&hasher.finalize()), bytes))
}

/// A file-system error on `path`, saying what was being done (a user can act on it: a full
/// disk, a missing directory, no permission).
pub fn io_error(path: &Path, doing: &str, e: std::io::Error) -> AppError {
    AppError::Unavailable(format!("{doing} {}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_manifest_sits_beside_its_file() {
        assert_eq!(
            path_of(Path::new("/b/bdft-backup-1.db")),
            Path::new("/b/bdft-backup-1.db.manifest.json")
        );
    }

    #[test]
    fn the_hash_is_sha256_of_the_bytes() {
        let dir = std::env::temp_dir().join(format!("bdft-manifest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("abc");
        std::fs::write(&f, b"abc").unwrap();
        // FIPS 180-2, appendix B.1.
        assert_eq!(
            sha256_of(&f).unwrap(),
            (
                "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad".to_string(),
                3
            )
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
