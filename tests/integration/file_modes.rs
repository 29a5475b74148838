//! Who else may read what the server keeps on disk: a real server started in a fresh
//! directory, then every file it made — the database and its write-ahead files, the audit and
//! TLS keys, the E-stop latch, a backup and its manifest, the backup directory, a restore's
//! kept copy — is its owner's only and ignored by git (the repository's `.gitignore`, as
//! `cargo run` in a checkout leaves them beside it); and `serve` names, with the command to
//! run, a database it finds open to others. The mode bits are checked, not access by another
//! user (as root every file is readable anyway).

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use bdft_tests::server::{Server, Stop, eventually};
use bdft_tests::{TempDir, server_cmd, succeeded};

fn mode(path: &Path) -> u32 {
    std::fs::metadata(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .permissions()
        .mode()
        & 0o7777
}

fn set_mode(path: &Path, mode: u32) {
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
}

/// Every file under `dir`, by its path from `dir`, but `left_out`.
fn files_under(dir: &Path, left_out: &[&str]) -> Vec<PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                out.push(path.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.retain(|p| !left_out.iter().any(|l| p == Path::new(l)));
    out.sort();
    out
}

/// Those of `files` (paths from a checkout's root) that the repository's `.gitignore` does
/// not ignore, asked of git itself in a scratch repository holding only that file.
fn not_ignored(files: &[PathBuf]) -> Vec<PathBuf> {
    let repo = TempDir::new("gitignore");
    let git = |args: &[&str]| {
        Command::new("git")
            .current_dir(repo.path())
            .args(args)
            .output()
            .expect("git runs")
    };
    assert!(git(&["init", "-q"]).status.success());
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../.gitignore"),
        repo.path().join(".gitignore"),
    )
    .unwrap();
    files
        .iter()
        .filter(|f| {
            let out = git(&["check-ignore", "--no-index", "-q", f.to_str().unwrap()]);
            // 0: ignored, 1: not ignored, anything else: git failed.
            assert!(matches!(out.status.code(), Some(0 | 1)), "{out:?}");
            !out.status.success()
        })
        .cloned()
        .collect()
}

#[test]
fn a_servers_keys_and_data_are_its_own_and_ignored_by_git() {
    let dir = TempDir::new("file-modes");
    let backups = dir.path().join("backups");
    let mut server = Server::start_logged(
        dir,
        &[
            "--tls-self-signed",
            "--backup-dir",
            backups.to_str().unwrap(),
        ],
    );
    let root = server.dir.path().to_path_buf();
    // The first scheduled backup is made at start; it is there once its manifest is.
    let backup = eventually(Duration::from_secs(120), || {
        let names = std::fs::read_dir(&backups).ok()?;
        names.flatten().map(|e| e.path()).find(|p| {
            p.extension().is_some_and(|e| e == "db")
                && Path::new(&format!("{}.manifest.json", p.display())).exists()
        })
    });
    let stem = root.join("bdft-lab");
    let private = [
        server.db.clone(),
        root.join("bdft-lab.db-wal"),
        root.join("bdft-lab.db-shm"),
        stem.with_extension("audit-key"),
        stem.with_extension("tls-key.pem"),
        root.join("bdft-lab.db.estop-latch"),
        backup.clone(),
        PathBuf::from(format!("{}.manifest.json", backup.display())),
    ];
    for file in &private {
        assert_eq!(mode(file), 0o600, "{}", file.display());
    }
    assert_eq!(mode(&backups), 0o700, "the backup directory");
    let log = std::fs::read_to_string(server.log().unwrap()).unwrap();
    assert!(
        !log.contains("chmod"),
        "no warning about files the server made itself:\n{log}"
    );

    // A restore onto a database an older release left readable by everyone: the restored
    // database and the kept copy of the replaced one are private.
    server.stop(Stop::Term, Duration::from_secs(30)).unwrap();
    set_mode(&server.db, 0o644);
    let out = succeeded(
        server_cmd(["restore", "--from"])
            .arg(&backup)
            .arg("--db")
            .arg(&server.db),
    );
    let restored: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let kept = PathBuf::from(restored["replaced_kept_as"].as_str().unwrap());
    assert_eq!(mode(&server.db), 0o600, "the restored database");
    assert_eq!(mode(&kept), 0o600, "{}", kept.display());

    // Everything the server and its commands made is ignored by git, as it would lie in a
    // checkout (the test's own log aside).
    let made = files_under(&root, &["server.log"]);
    for expected in ["bdft-lab.audit-key", "bdft-lab.tls-cert.pem", "backups"] {
        assert!(
            made.iter().any(|f| f.starts_with(expected)),
            "{expected} in {made:?}"
        );
    }
    assert_eq!(not_ignored(&made), Vec::<PathBuf>::new(), "of {made:?}");
}

#[test]
fn serve_names_a_database_others_may_read_and_the_command_that_closes_it() {
    let dir = TempDir::new("file-modes-open");
    // A database made by an older release (or copied in): readable by everyone.
    let db = dir.path().join("bdft-lab.db");
    std::fs::write(&db, b"").unwrap();
    set_mode(&db, 0o644);
    let backups = dir.path().join("backups");
    std::fs::create_dir(&backups).unwrap();
    set_mode(&backups, 0o755);
    let server = Server::start_logged(dir, &["--backup-dir", backups.to_str().unwrap()]);
    // Logged before the address line the start waited for.
    let log = std::fs::read_to_string(server.log().unwrap()).unwrap();
    let warned = |path: &Path, fix: &str| {
        log.lines()
            .any(|l| l.contains("WARN") && l.contains(&format!("run `{fix} {}`", path.display())))
    };
    assert!(warned(&db, "chmod 600"), "{log}");
    assert!(warned(&backups, "chmod 700"), "{log}");
    assert!(log.contains("(mode 0644)"), "{log}");
    // A log written to a file is plain text: no terminal colour codes.
    assert!(
        !log.contains('\u{1b}'),
        "escape codes in a log file: {log:?}"
    );
    // The files it made itself are not named.
    let key = server.dir.path().join("bdft-lab.audit-key");
    assert!(!log.contains(&key.display().to_string()), "{log}");
}
