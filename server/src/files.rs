//! Files that hold secrets or subject data: the server creates them for its own account only,
//! and at `serve`'s start names those it finds open to other users.
//!
//! A lab's machine has other accounts (students, a shared analysis login): the database, its
//! backups and exports hold pseudonymous subjects' data, and the audit and TLS keys would let
//! someone forge the audit log or impersonate the server. The permissions are set when a file
//! is created (never created open, then narrowed: that leaves a moment when it can be
//! opened). SQLite makes a database's `-wal`, `-shm` and `-journal` files with the mode of
//! the database file, so the database file is created by us, empty, before SQLite opens it.

use std::fs::{DirBuilder, OpenOptions, Permissions};
use std::io;
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

/// The mode of every file the server creates with secrets or data: its owner's alone.
pub const FILE_MODE: u32 = 0o600;
/// The mode of every directory the server creates for them.
pub const DIR_MODE: u32 = 0o700;

/// Options that create a new file (never an existing one) readable and writable by its owner
/// only; for `tokio::fs::OpenOptions::from` too.
pub fn new_private() -> OpenOptions {
    let mut options = OpenOptions::new();
    options.write(true).create_new(true).mode(FILE_MODE);
    options
}

/// Creates `path` new and private, removing first what an interrupted run left there (a
/// temporary file only ever of ours: its permissions are not to be trusted).
pub fn replace_private(path: &Path) -> io::Result<std::fs::File> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    new_private().open(path)
}

/// Creates `dir` and its missing parents for their owner only (an existing one is left as
/// it is; [`warn_open`] names it when others may use it).
pub fn create_private_dirs(dir: &Path) -> io::Result<()> {
    DirBuilder::new().recursive(true).mode(DIR_MODE).create(dir)
}

/// Makes `path` its owner's only: a file SQLite or a hard link made, which our options did
/// not create.
pub fn make_private(path: &Path) -> io::Result<()> {
    std::fs::set_permissions(path, Permissions::from_mode(FILE_MODE))
}

/// Creates the SQLite file `path` empty and private when it does not exist yet, so that
/// SQLite (which creates a missing file with the umask's mode, 0644 on most systems) opens
/// ours; an empty file is an empty database to SQLite.
pub fn create_database_file(path: &Path) -> io::Result<()> {
    match new_private().open(path) {
        Ok(_) => Ok(()),
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => Err(e),
    }
}

/// What a file the server keeps holds, and so which permission bits others may not have.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Holds {
    /// A private key: nobody but the owner (at most 0600).
    Secret,
    /// Subject data: the owner, and reading by the owner's group (at most 0640).
    Data,
    /// A directory of data: the owner, and listing by the group (at most 0750).
    DataDir,
}

impl Holds {
    /// The permission bits it may not have.
    fn forbidden(self) -> u32 {
        match self {
            Self::Secret => 0o077,
            Self::Data => 0o037,
            Self::DataDir => 0o027,
        }
    }

    fn what(self) -> &'static str {
        match self {
            Self::Secret => "a private key",
            Self::Data => "subject data",
            Self::DataDir => "a directory of subject data",
        }
    }

    fn fix(self) -> &'static str {
        match self {
            Self::Secret | Self::Data => "chmod 600",
            Self::DataDir => "chmod 700",
        }
    }
}

/// A file of the server's that other users may read or write.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OpenFile {
    pub path: PathBuf,
    pub mode: u32,
    pub holds: Holds,
}

impl std::fmt::Display for OpenFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{path} holds {what} and other users may read or write it (mode {mode:04o}): run `{fix} {path}`",
            path = self.path.display(),
            what = self.holds.what(),
            mode = self.mode & 0o7777,
            fix = self.holds.fix(),
        )
    }
}

/// The files among `files` that exist and give others more than what they hold allows.
pub fn open_to_others(files: &[(PathBuf, Holds)]) -> Vec<OpenFile> {
    files
        .iter()
        .filter_map(|(path, holds)| {
            let mode = std::fs::metadata(path).ok()?.permissions().mode();
            (mode & holds.forbidden() != 0).then(|| OpenFile {
                path: path.clone(),
                mode,
                holds: *holds,
            })
        })
        .collect()
}

/// Logs a warning for each of `files` that others may read or write, with what to run.
pub fn warn_open(files: &[(PathBuf, Holds)]) {
    for open in open_to_others(files) {
        tracing::warn!("{open}");
    }
}

/// A file's name with `suffix` added (`bdft-lab.db` → `bdft-lab.db-wal`), in its directory.
pub fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(suffix);
    PathBuf::from(name)
}

/// The files of a database beside it that hold its data: the file, its write-ahead log and
/// shared memory, and the copies a restore kept (`DB.replaced-TIME`).
pub fn database_files(db: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = ["", "-wal", "-shm", "-journal"]
        .iter()
        .map(|s| with_suffix(db, s))
        .collect();
    let kept = format!(
        "{}.replaced-",
        db.file_name().unwrap_or_default().to_string_lossy()
    );
    let dir = match db.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if let Ok(entries) = std::fs::read_dir(dir) {
        files.extend(
            entries
                .flatten()
                .filter(|e| e.file_name().to_string_lossy().starts_with(&kept))
                .map(|e| e.path()),
        );
    }
    files
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mode(path: &Path) -> u32 {
        std::fs::metadata(path).unwrap().permissions().mode() & 0o777
    }

    #[test]
    fn files_and_directories_are_made_for_their_owner_and_open_ones_are_named() {
        let dir = std::env::temp_dir().join(format!("bdft-files-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let nested = dir.join("a/b");
        create_private_dirs(&nested).unwrap();
        assert_eq!(mode(&dir.join("a")), DIR_MODE, "the parents too");
        assert_eq!(mode(&nested), DIR_MODE);

        let db = nested.join("lab.db");
        create_database_file(&db).unwrap();
        assert_eq!(mode(&db), FILE_MODE);
        std::fs::write(&db, b"data").unwrap();
        create_database_file(&db).unwrap();
        assert_eq!(
            std::fs::read(&db).unwrap(),
            b"data",
            "an existing one is kept"
        );

        // A temporary file left open by an older run is replaced by a private one.
        let tmp = nested.join("x.new");
        std::fs::write(&tmp, b"old").unwrap();
        std::fs::set_permissions(&tmp, Permissions::from_mode(0o644)).unwrap();
        drop(replace_private(&tmp).unwrap());
        assert_eq!(mode(&tmp), FILE_MODE);
        assert!(std::fs::read(&tmp).unwrap().is_empty());

        // Group reading is allowed for data, not for a key; anything for others is not.
        let kept = nested.join("lab.db.replaced-2025-01-01T00-00-00.000Z");
        std::fs::write(&kept, b"").unwrap();
        let key = nested.join("lab.audit-key");
        std::fs::write(&key, b"").unwrap();
        let set = |p: &Path, m: u32| std::fs::set_permissions(p, Permissions::from_mode(m));
        set(&db, 0o640).unwrap();
        set(&key, 0o640).unwrap();
        set(&kept, 0o604).unwrap();
        set(&nested, 0o750).unwrap();
        let mut files: Vec<(PathBuf, Holds)> = database_files(&db)
            .into_iter()
            .map(|f| (f, Holds::Data))
            .collect();
        assert!(files.iter().any(|(f, _)| *f == kept), "{files:?}");
        files.push((key.clone(), Holds::Secret));
        files.push((nested.clone(), Holds::DataDir));
        let open = open_to_others(&files);
        let named: Vec<&Path> = open.iter().map(|o| o.path.as_path()).collect();
        assert_eq!(named, [kept.as_path(), key.as_path()], "{open:?}");
        let said = open[1].to_string();
        assert!(
            said.contains(&format!("run `chmod 600 {}`", key.display())),
            "{said}"
        );
        assert!(said.contains("(mode 0640)"), "{said}");
        set(&nested, 0o755).unwrap();
        let said = open_to_others(&[(nested.clone(), Holds::DataDir)])[0].to_string();
        assert!(said.contains("chmod 700"), "{said}");

        make_private(&kept).unwrap();
        assert_eq!(mode(&kept), FILE_MODE);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
