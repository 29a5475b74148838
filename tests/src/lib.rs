//! Helpers shared by the end-to-end tests: locating the product's binaries and running them.

use std::path::PathBuf;
use std::process::{Command, Output};

/// Path of a workspace binary built next to this executable (`cargo test --workspace`
/// builds every member's binaries into the same target directory).
pub fn binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("current executable");
    // A test: target/<profile>/deps/integration-<hash>; the soak binary:
    // target/<profile>/soak. Either way the product's binaries are in target/<profile>.
    let mut dir = exe.parent().expect("target profile directory");
    if dir.file_name().is_some_and(|n| n == "deps") {
        dir = dir.parent().expect("target profile directory");
    }
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} not built; run the tests with `cargo test --workspace`",
        path.display()
    );
    path
}

/// A program scripts/test.sh installs into the Python venv `target/tools/<venv>` with
/// `pip install <package>`.
pub fn venv_tool(venv: &str, bin: &str, package: &str) -> PathBuf {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../target/tools")
        .join(venv);
    let path = dir.join("bin").join(bin);
    assert!(
        path.is_file(),
        "{} is missing: scripts/test.sh installs it (python3 -m venv {} && pip install {package})",
        path.display(),
        dir.display()
    );
    path
}

/// `unshare` with the option for a new network namespace: as root it needs nothing more,
/// otherwise a user namespace maps us to root inside it.
pub fn unshare_network() -> Command {
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout == b"0\n");
    let mut c = Command::new("unshare");
    c.arg(if root { "-n" } else { "-rn" });
    c
}

/// Runs `bdft-controller` with `args` and returns its output.
pub fn controller(args: &[&str]) -> Output {
    Command::new(binary("bdft-controller"))
        .args(args)
        .output()
        .expect("spawn bdft-controller")
}

/// A benchmark's setting: environment variable `name` read as a `T`, or `default` when it
/// is unset or not one.
pub fn setting<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// A benchmark's list setting: the comma-separated values of environment variable `name`
/// (`default` when it is unset), those that are not a `T` left out.
pub fn setting_list<T: std::str::FromStr>(name: &str, default: &str) -> Vec<T> {
    std::env::var(name)
        .unwrap_or_else(|_| default.into())
        .split(',')
        .filter_map(|v| v.trim().parse().ok())
        .collect()
}

/// Sends signal `name` (`KILL`, `STOP`, `CONT`, `TERM`) to process `pid` with kill(1).
pub fn send_signal(pid: u32, name: &str) -> Result<(), String> {
    let out = Command::new("kill")
        .arg(format!("-{name}"))
        .arg(pid.to_string())
        .output()
        .map_err(|e| format!("kill -{name} {pid}: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "kill -{name} {pid}: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// The CPU that named processes use over a stretch of time: [`CpuMeter::start`] reads their
/// counters, [`CpuMeter::shares`] gives each one's use since, in % of one core.
#[derive(Debug)]
pub struct CpuMeter {
    processes: Vec<(&'static str, u32, f64)>,
    since: std::time::Instant,
}

impl CpuMeter {
    pub fn start(processes: &[(&'static str, u32)]) -> Self {
        Self {
            processes: processes
                .iter()
                .map(|&(name, pid)| (name, pid, cpu_seconds(pid)))
                .collect(),
            since: std::time::Instant::now(),
        }
    }

    /// Each process's CPU since the start, % of one core (one decimal).
    pub fn shares(&self) -> serde_json::Map<String, serde_json::Value> {
        let wall = self.since.elapsed().as_secs_f64();
        self.processes
            .iter()
            .map(|&(name, pid, before)| {
                let share = (cpu_seconds(pid) - before) / wall * 100.0;
                (
                    name.to_string(),
                    serde_json::json!((share * 10.0).round() / 10.0),
                )
            })
            .collect()
    }
}

/// CPU seconds (user + system) process `pid` has used (0 if it is gone).
fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // After the command name in parentheses: state is field 3, utime and stime 14 and 15.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map_or(vec![], |(_, rest)| rest.split_whitespace().collect());
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|f| f.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // Clock ticks are 1/100 s on Linux (USER_HZ).
    (ticks(11) + ticks(12)) / 100.0
}

/// Whether a WebSocket read failed only because the socket's read timeout passed (nothing
/// to read yet; the socket is still good).
pub fn read_timed_out(e: &tungstenite::Error) -> bool {
    matches!(e, tungstenite::Error::Io(e) if matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
    ))
}

/// A scratch directory unique to one test, removed when dropped.
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "bdft-test-{tag}-{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0)
        ));
        std::fs::create_dir_all(&dir).expect("create temp dir");
        Self(dir)
    }
    pub fn path(&self) -> &std::path::Path {
        &self.0
    }

    /// Keeps the directory and its files (it is not removed); its path.
    pub fn keep(self) -> PathBuf {
        std::mem::ManuallyDrop::new(self).0.clone()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Held by the tests that load the machine on purpose (a flood, the soak's eight stations):
/// on 2 cores two of them at once starve the real-time loop they are judging, so they take
/// turns (the other tests still run beside each one).
pub fn machine_load_turn() -> std::sync::MutexGuard<'static, ()> {
    static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
    // A test that failed while holding it poisoned it; the turn is still free.
    TURN.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

pub mod audit_chain;
pub mod controller_link;
pub mod exports;
pub mod postgres;
pub mod raw;
pub mod server;
pub mod soak;
pub mod station;
pub mod webdriver;
