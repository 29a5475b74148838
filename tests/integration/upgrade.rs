//! Upgrades: every fixture under `tests/fixtures/upgrade/` is a database made by an earlier
//! release, with every export that release made of it. This build's server opens a copy
//! (its start-up migrates it), and every export made now must equal the stored one
//! (`bdft_tests::exports::compare`: equal bytes; Parquet as columns, types and values; a
//! column a later release added on purpose is declared in the fixture's
//! `accepted-changes.txt`). README, "Upgrades", says how a release adds its own fixture.

use std::path::{Path, PathBuf};

use bdft_tests::exports::compare;
use bdft_tests::server::{Api, Server, with_db};
use bdft_tests::{TempDir, server_cmd};
use serde_json::Value;

fn fixtures() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/upgrade");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap_or_else(|e| panic!("{}: {e}", root.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("bdft-lab.db").is_file())
        .collect();
    dirs.sort();
    dirs
}

/// `FILE COLUMN` lines: columns a later release added to an export on purpose.
fn accepted_added(fixture: &Path, file: &str) -> Vec<String> {
    std::fs::read_to_string(fixture.join("accepted-changes.txt"))
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .filter_map(|l| {
            let mut words = l.split_whitespace();
            (words.next() == Some(file)).then(|| words.next().map(str::to_string))?
        })
        .collect()
}

/// What differs between the exports of `fixture` and the ones this build makes of it.
fn differences(fixture: &Path) -> Vec<String> {
    let name = fixture.file_name().unwrap().to_string_lossy().into_owned();
    let server = Server::start_on_copy("upgrade", &fixture.join("bdft-lab.db"), &[]);
    let out = TempDir::new("upgrade-exports");
    let listed = std::fs::read_to_string(fixture.join("exports.txt")).unwrap();
    let lines: Vec<(&str, Vec<&str>)> = listed
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let mut words = l.split_whitespace();
            (words.next().unwrap(), words.collect())
        })
        .collect();
    assert!(!lines.is_empty(), "{name}: exports.txt lists no export");
    let mut found = Vec::new();
    found.extend(audit_chained_late(fixture, &server));
    let check = |file: &str, now: Vec<u8>| -> Option<String> {
        let stored = std::fs::read(fixture.join("exports").join(file))
            .unwrap_or_else(|e| panic!("{name}: exports/{file}: {e}"));
        compare(file, &stored, &now, &accepted_added(fixture, file))
            .err()
            .map(|report| format!("{name}: {report}"))
    };
    // The command line's exports first: the log-in below adds to the audit log.
    for (file, args) in lines.iter().filter(|(_, a)| a.first() != Some(&"GET")) {
        let path = out.path().join(file);
        let made = server_cmd(["export", "--db"])
            .arg(&server.db)
            .args(args)
            .arg("--out")
            .arg(&path)
            .output()
            .unwrap();
        if !made.status.success() {
            found.push(format!(
                "{name}: `bdft-server export {}` failed: {}",
                args.join(" "),
                String::from_utf8_lossy(&made.stderr)
            ));
            continue;
        }
        found.extend(check(file, std::fs::read(&path).unwrap()));
    }
    let http: Vec<_> = lines
        .iter()
        .filter(|(_, a)| a.first() == Some(&"GET"))
        .collect();
    if !http.is_empty() {
        let login: Value =
            serde_json::from_str(&std::fs::read_to_string(fixture.join("login.json")).unwrap())
                .unwrap();
        let api: Api = server.login(
            login["username"].as_str().unwrap(),
            login["password"].as_str().unwrap(),
        );
        for (file, args) in http {
            let (code, bytes) = api.get_bytes(args[1]);
            assert_eq!(code, 200, "{name}: GET {}", args[1]);
            found.extend(check(file, bytes));
        }
    }
    found
}

/// The audit entries of a database made before the hash chain are chained at its first
/// start under this release, each marked as chained late, and the log verifies.
fn audit_chained_late(fixture: &Path, server: &Server) -> Option<String> {
    let name = fixture.file_name().unwrap().to_string_lossy().into_owned();
    let copy = TempDir::new("upgrade-audit");
    let before = copy.path().join("bdft-lab.db");
    std::fs::copy(fixture.join("bdft-lab.db"), &before).unwrap();
    // The fixture's entries without a chain row: all of them before the chain existed.
    let held: i64 = with_db(&before, async |pool| {
        let has_chain: i64 =
            sqlx::query_scalar("SELECT COUNT(*) FROM sqlite_master WHERE name = 'audit_chain'")
                .fetch_one(pool)
                .await
                .unwrap();
        let unchained = if has_chain > 0 {
            "SELECT COUNT(*) FROM audit_log WHERE id NOT IN (SELECT entry_id FROM audit_chain)"
        } else {
            "SELECT COUNT(*) FROM audit_log"
        };
        sqlx::query_scalar(unchained).fetch_one(pool).await.unwrap()
    });
    let chained: i64 = with_db(&server.db, async |pool| {
        sqlx::query_scalar("SELECT COUNT(*) FROM audit_chain WHERE chained_late = 1")
            .fetch_one(pool)
            .await
            .unwrap()
    });
    let verified = server_cmd(["audit", "verify", "--db"])
        .arg(&server.db)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&verified.stdout).into_owned();
    let late_said = held == 0 || said.contains(&format!("({held} entries chained late"));
    (!verified.status.success() || !said.contains("intact: ") || !late_said || chained != held)
    .then(|| {
        format!(
            "{name}: the fixture's {held} unchained audit entries, chained late: {chained}; `audit verify` said: {said}{}",
            String::from_utf8_lossy(&verified.stderr)
        )
    })
}

#[test]
fn every_earlier_releases_database_migrates_and_exports_the_same() {
    let fixtures = fixtures();
    assert!(
        !fixtures.is_empty(),
        "no fixture under tests/fixtures/upgrade/"
    );
    let found: Vec<String> = fixtures.iter().flat_map(|f| differences(f)).collect();
    assert!(found.is_empty(), "{}", found.join("\n\n"));
}
