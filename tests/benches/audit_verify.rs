//! Verifying the audit log's hash chain (issue 25: a million entries in ≤ 5 s; issue 37: a
//! million keyed entries in ≤ 1 s): a server makes a database and its first entries, then a
//! million more entries of a lab's usual size are written behind its back, and
//! `bdft-server audit verify` reads the whole chain back. `CHAIN=keyed` (the default): the
//! entries are written as this release writes them — salted, their chain an HMAC under the
//! key file's chain key (computed by `bdft_tests::audit_chain`, the tests' own reading of the
//! format), in batches with the triggers on; `CHAIN=late`: in one statement without chain
//! rows, the next start chaining them as an upgrade from before the chain would (issue 25's
//! bench).
//!
//! `cargo build --workspace --bins && ENTRIES=1000000 RUNS=3 cargo bench --profile dev -p bdft-tests --bench audit_verify`
//! (`KEEP=DIR` keeps the database and its key file in DIR; `RUNS=0` only makes them).

use std::time::{Duration, Instant};

use sha2::Digest;

use bdft_tests::audit_chain as chain;
use bdft_tests::server::{Server, Stop, with_db};
use bdft_tests::{server_cmd, setting, succeeded};

fn main() {
    let entries: i64 = setting("ENTRIES", 1_000_000);
    let runs: usize = setting("RUNS", 3);
    let keyed = setting::<String>("CHAIN", "keyed".into()) == "keyed";
    let mut server = Server::start("audit-verify-bench");
    if keyed {
        // Behind the idle server's back (it appends nothing while nobody uses it).
        write_keyed(&server, entries);
    } else {
        write_unchained(&server, entries);
    }
    let started = Instant::now();
    server.restart(Stop::Term, Duration::from_secs(30)).unwrap();
    let chain_s = started.elapsed().as_secs_f64();
    server.stop(Stop::Term, Duration::from_secs(30)).unwrap();
    let size_mb = std::fs::metadata(&server.db).unwrap().len() as f64 / 1e6;
    let mut times = Vec::new();
    let mut cpu = Vec::new();
    for _ in 0..runs {
        let cpu_before = children_cpu_s();
        let t = Instant::now();
        let out = succeeded(server_cmd(["audit", "verify", "--db"]).arg(&server.db));
        times.push(t.elapsed().as_secs_f64());
        cpu.push(children_cpu_s() - cpu_before);
        let said = String::from_utf8_lossy(&out.stdout);
        assert!(said.contains("intact: "), "{said}");
        assert!(
            keyed || said.contains(&format!("({entries} entries chained late")),
            "{said}"
        );
    }
    // KEEP=DIR: the database and its key file copied there, to time `bdft-server audit
    // verify --db DIR/bdft-lab.db` by hand (or another build of it).
    if let Some(dir) = std::env::var_os("KEEP") {
        let dir = std::path::PathBuf::from(dir);
        std::fs::create_dir_all(&dir).unwrap();
        // VACUUM INTO: one whole file, whatever the write-ahead log still held.
        let kept = dir.join("bdft-lab.db");
        let _ = std::fs::remove_file(&kept);
        with_db(&server.db, async |pool| {
            sqlx::query(&format!("VACUUM INTO '{}'", kept.display()))
                .execute(pool)
                .await
                .unwrap();
        });
        std::fs::copy(
            server.db.with_extension("audit-key"),
            dir.join("bdft-lab.audit-key"),
        )
        .unwrap();
        println!("kept in {}", dir.display());
    }
    if runs == 0 {
        return;
    }
    times.sort_by(f64::total_cmp);
    cpu.sort_by(f64::total_cmp);
    println!(
        "{entries} {} entries ({size_mb:.0} MB database): the next start in {chain_s:.2} s; \
         audit verify median {:.2} s wall (min {:.2}, max {:.2}), {:.2} s CPU (user + system), {runs} runs",
        if keyed { "keyed" } else { "late-chained" },
        times[times.len() / 2],
        times[0],
        times[times.len() - 1],
        cpu[cpu.len() / 2],
    );
}

/// The details of an entry shaped like a trial's filing (~100 bytes), as SQLite's
/// json_object writes them.
fn details(i: i64) -> String {
    format!(
        r#"{{"status":"complete","reason":"completed","rms_error_mm":{},"samples":140000}}"#,
        i % 97
    )
}

/// `entries` entries after the server's own, salted and keyed as the server writes them,
/// in statements of 1,000 rows (the triggers stay on: appending is allowed).
fn write_keyed(server: &Server, entries: i64) {
    let key =
        chain::chain_key(&std::fs::read_to_string(server.db.with_extension("audit-key")).unwrap());
    with_db(&server.db, async |pool| {
        let (mut last, mut prev): (i64, String) =
            sqlx::query_as("SELECT entry_id, hash FROM audit_chain ORDER BY entry_id DESC LIMIT 1")
                .fetch_one(pool)
                .await
                .unwrap();
        let end = last + entries;
        while last < end {
            let (mut log, mut links, mut salts) = (Vec::new(), Vec::new(), Vec::new());
            for id in last + 1..=(last + 1000).min(end) {
                let row = chain::Row {
                    id,
                    at: 1_796_000_000_000 + id,
                    actor: "station:bench".into(),
                    actor_id: None,
                    action: "trial.end".into(),
                    target: Some(format!("trial:{id}")),
                    detail: Some(details(id)),
                };
                let salt = sha2::Sha256::digest(id.to_le_bytes())[..16].to_vec();
                let (detail_hash, hash) = chain::hashes(&row, 2, &prev, &salt, &key);
                log.push(format!(
                    "({id}, {}, '{}', '{}', '{}', '{}')",
                    row.at,
                    row.actor,
                    row.action,
                    row.target.as_deref().unwrap_or_default(),
                    row.detail.as_deref().unwrap_or_default()
                ));
                links.push(format!("({id}, '{prev}', '{detail_hash}', '{hash}', 2)"));
                salts.push(format!("({id}, '{}')", chain::hex(&salt)));
                prev = hash;
                last = id;
            }
            let mut tx = pool.begin().await.unwrap();
            for sql in [
                format!(
                    "INSERT INTO audit_log (id, at, actor, action, target, detail_json) VALUES {}",
                    log.join(",")
                ),
                format!(
                    "INSERT INTO audit_chain (entry_id, prev_hash, detail_hash, hash, format) VALUES {}",
                    links.join(",")
                ),
                format!(
                    "INSERT INTO audit_salts (entry_id, salt) VALUES {}",
                    salts.join(",")
                ),
            ] {
                sqlx::query(&sql).execute(&mut *tx).await.unwrap();
            }
            tx.commit().await.unwrap();
        }
    });
}

/// `entries` entries written without chain rows, in one statement (issue 25's bench).
fn write_unchained(server: &Server, entries: i64) {
    // Entries shaped like a trial's filing: an actor, an action, a target and ~100 bytes of
    // details.
    with_db(&server.db, async |pool| {
        sqlx::query(
            "WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < ?) \
             INSERT INTO audit_log (at, actor, action, target, detail_json) \
             SELECT 1796000000000 + i, 'station:bench', 'trial.end', 'trial:' || i, \
             json_object('status', 'complete', 'reason', 'completed', 'rms_error_mm', i % 97, 'samples', 140000) \
             FROM n",
        )
        .bind(entries)
        .execute(pool)
        .await
        .unwrap();
    });
}

/// The CPU time (user + system, s) of this process's waited-for children: on a shared
/// machine the verifier's own work, apart from the time others took the cores.
fn children_cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap();
    // Fields after the command's closing parenthesis; cutime and cstime are fields 16 and
    // 17 of the whole line (proc(5)), in clock ticks (USER_HZ, 100 on Linux).
    let rest = &stat[stat.rfind(')').unwrap() + 2..];
    let fields: Vec<f64> = rest
        .split_whitespace()
        .map(|f| f.parse().unwrap_or(0.0))
        .collect();
    (fields[13] + fields[14]) / 100.0
}
