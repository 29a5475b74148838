//! Helpers shared by the end-to-end tests: locating the product's binaries and running them.

use std::path::PathBuf;
use std::process::{Command, Output};

/// Path of a workspace binary built next to this test executable (`cargo test --workspace`
/// builds every member's binaries into the same target directory).
pub fn binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("current test executable");
    // target/<profile>/deps/integration-<hash> → target/<profile>/<name>
    let dir = exe
        .parent()
        .and_then(|d| d.parent())
        .expect("target profile directory");
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} not built; run the tests with `cargo test --workspace`",
        path.display()
    );
    path
}

/// Runs `bdft-controller` with `args` and returns its output.
pub fn controller(args: &[&str]) -> Output {
    Command::new(binary("bdft-controller"))
        .args(args)
        .output()
        .expect("spawn bdft-controller")
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
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub mod controller_link;
pub mod exports;

pub mod server;
pub mod webdriver;
