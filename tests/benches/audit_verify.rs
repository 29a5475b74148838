//! Verifying the audit log's hash chain (issue 25: a million entries in ≤ 5 s): a server
//! makes a database and its first entries, a million more entries of a lab's usual size are
//! written behind its back in one statement, the next start chains them (each marked chained
//! late, as an upgrade would), and `bdft-server audit verify` reads the whole chain back.
//!
//! `cargo build --workspace --bins && ENTRIES=1000000 RUNS=3 cargo bench --profile dev -p bdft-tests --bench audit_verify`

use std::process::Command;
use std::time::{Duration, Instant};

use bdft_tests::server::{Server, Stop, with_db};
use bdft_tests::{binary, setting};

fn main() {
    let entries: i64 = setting("ENTRIES", 1_000_000);
    let runs: usize = setting("RUNS", 3);
    let mut server = Server::start("audit-verify-bench");
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
        let out = Command::new(binary("bdft-server"))
            .args(["audit", "verify", "--db"])
            .arg(&server.db)
            .output()
            .unwrap();
        times.push(t.elapsed().as_secs_f64());
        cpu.push(children_cpu_s() - cpu_before);
        let said = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success() && said.contains("intact: "),
            "{said}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            said.contains(&format!("({entries} entries chained late")),
            "{said}"
        );
    }
    times.sort_by(f64::total_cmp);
    cpu.sort_by(f64::total_cmp);
    println!(
        "{entries} entries ({size_mb:.0} MB database): chained at the next start in {chain_s:.2} s (the start included); \
         audit verify median {:.2} s wall (min {:.2}, max {:.2}), {:.2} s CPU (user + system), {runs} runs",
        times[times.len() / 2],
        times[0],
        times[times.len() - 1],
        cpu[cpu.len() / 2],
    );
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
