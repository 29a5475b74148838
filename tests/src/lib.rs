//! Helpers shared by the end-to-end tests: locating the product's binaries and running them.
//!
//! This crate is the one integration-test package: it runs the product's binaries as real
//! processes. One integration binary (`integration/main.rs`), one module per area; unit tests of
//! the maths live next to the code.
//!
//! - The root: `binary`, `controller` (runs `bdft-controller`), `server_command` (runs
//!   `bdft-server` and checks it succeeded; `server_output` whatever its status, `server_cmd` and
//!   `succeeded` for a run with a path, a directory or an environment), `TempDir`, `send_signal`,
//!   `read_timed_out`; `controller_link`: `Proc` spawns a process on port 0 and reads its address,
//!   `Link` speaks the protocol as the server does.
//! - `server`: `Server` starts `bdft-server` on a fresh database — and restarts it on its port
//!   after SIGKILL or SIGTERM —, `Api` calls it with cookies, CSRF and bearer tokens (`try_call`
//!   when a refused connection is an answer); `HeldWrite` holds the store's write lock from a
//!   connection of its own (the contention tests, the bench and the soak's store-held fault);
//!   `CpuMeter` gives the benches each process's CPU share.
//! - `station`: a station's page as tests and benchmarks play it — its socket, input fed at a rate
//!   with each input timed to its echo, a flood until the server closes it.
//! - `webdriver`: a minimal W3C WebDriver client for Debian's headless Chromium through
//!   chromedriver, used by `integration/browser.rs`, which runs over HTTPS.
//! - `exports`: exports read back as tables and compared — equal bytes, or a report of what
//!   differs.
//! - `postgres`: a database of its own on the test command's PostgreSQL server (`PgDatabase`, also
//!   made from another as its template), and `BDFT_TEST_STORE=postgres`, which starts every
//!   `Server` on one — the test command's second pass of the end-to-end tests.
//! - `raw`: HTTP by hand from a loopback address of its own (a socket bound to 127.0.0.2 before
//!   connecting), so the server's per-address limits tell two clients on one machine apart.
//! - `audit_chain`: the tests' own implementation of the audit chain's formats, independent of the
//!   server's.
//! - `soak` (`src/bin/soak.rs`): the lab-day soak; `integration/soak.rs` runs 2 minutes in CI and
//!   20 minutes in the slow set, `#[ignore]`d, which `scripts/test.sh --slow` includes.
//!
//! Benchmarks (`benches/`): `echo` (input-to-echo latency), `estop_latency`, `isolation` (a victim
//! station, the API and the E-stop while another station floods from its own process),
//! `estop_contention` (the E-stop's answer with the store's write lock held, during a pilot, an
//! export and a calibration, and its latch across a controller kill), `audit_verify`, and
//! `bounded_clients` (a new client's login and API and the E-stop while one address floods with
//! slow bodies and reconnecting idle connections).
//!
//! Fixtures and areas worth knowing: `tests/fixtures/exposure/`: scipy's analog W_d at the
//! one-third-octave centres and its a_w and VDV of two recorded tests the product exported
//! (`make.sh`, `make_fixture.py`), which `integration/exposure.rs` holds the Rust weighting and the
//! loop's figures to. `integration/lsl.rs` runs the LSL streams in a loopback-only network
//! namespace of its own (the test re-runs itself under `unshare -n` after `ip link set lo up`, and
//! refuses to run where another interface exists), read by `tests/scripts/lsl_client.py` with
//! pylsl's bundled liblsl. `tests/fixtures/upgrade/`: one directory per release — a database it
//! made, every export it made of it, and the script that made them — which the `upgrade` test opens
//! with the code under test. `integration/structure.rs` reads the sources instead of running them:
//! the server's layers, the engine's rooms and their one direction, and no import cycle between two
//! modules.

use std::ffi::OsStr;
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

/// Runs `bdft-controller` with `args` (a command with `--json`), as another tool calls it,
/// and returns the JSON it printed; panics with its standard error if it failed.
pub fn controller_json(args: &[&str]) -> serde_json::Value {
    let out = controller(args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("bdft-controller printed JSON")
}

/// `bdft-server` with `args`, not yet run: for a run that spawns, sets a directory or an
/// environment, or adds a path (then [`succeeded`] runs it).
pub fn server_cmd<I, S>(args: I) -> Command
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    let mut cmd = Command::new(binary("bdft-server"));
    cmd.args(args);
    cmd
}

/// Runs `bdft-server` with `args` to its end and returns its output, whatever its status
/// (for a test that expects a refusal).
pub fn server_output<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    server_cmd(args).output().expect("spawn bdft-server")
}

/// Runs `bdft-server` with `args` and returns its output; panics, with the command and its
/// standard error, when it fails.
pub fn server_command<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    succeeded(&mut server_cmd(args))
}

/// Runs `cmd` to its end and returns its output; panics, with the command and its standard
/// error, when it fails.
pub fn succeeded(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("spawn {cmd:?}: {e}"));
    assert!(
        out.status.success(),
        "{cmd:?}: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    out
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
