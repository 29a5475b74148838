//! The lab-day soak (`bdft_tests::soak`, also `cargo run -p bdft-tests --bin soak`): eight
//! browser-like stations run the study on the real server and controller while faults are
//! injected on a seeded schedule — two minutes in CI's run, with every kind of fault at
//! least once; twenty minutes in the slow set (`bash scripts/test.sh --slow`). The soak
//! checks every test filed with a status and reason, nothing lost or duplicated between its
//! journal, the exports and the audit log, the database's integrity, and the server's
//! memory and descriptors back to their baseline; it fails with the list of what broke.
//! `BDFT_SOAK_SEED` picks another schedule.

use std::time::Duration;

use bdft_tests::soak::{self, Config};

fn soak_for(minutes: u64) {
    let _turn = bdft_tests::machine_load_turn();
    let seed = std::env::var("BDFT_SOAK_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let verdict = soak::run(Config {
        length: Duration::from_secs(minutes * 60),
        seed,
        keep: false,
    });
    assert!(verdict.passed(), "seed {seed}:\n{verdict}");
}

#[test]
fn a_two_minute_lab_day_with_every_fault_files_every_test_and_leaks_nothing() {
    soak_for(2);
}

#[test]
#[ignore = "slow set (20 minutes): bash scripts/test.sh --slow"]
fn a_twenty_minute_lab_day_with_faults_files_every_test_and_leaks_nothing() {
    soak_for(20);
}
