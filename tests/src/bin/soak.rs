//! The lab-day soak (`bdft_tests::soak`): eight browser-like stations run a whole study on
//! the real server and controller over loopback while faults are injected on a seeded
//! schedule; the end compares the soak's journal with the exports and the audit log and
//! the server's memory and descriptors with their baseline.
//!
//! `cargo build --workspace --bins && cargo run -p bdft-tests --bin soak -- --hours 0.5`
//! (`--minutes M` instead; `--seed N`; `--keep` keeps the run's directory even when it
//! passes). Exits 1 with the list of violations when a rule was broken.

use std::process::ExitCode;
use std::time::Duration;

use bdft_tests::soak::{self, Config};

const USAGE: &str = "usage: soak (--hours H | --minutes M) [--seed N] [--keep]";

fn parse(args: &[String]) -> Result<Config, String> {
    let mut config = Config {
        length: Duration::from_secs(120),
        seed: 1,
        keep: false,
    };
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        let mut value = |what: &str| {
            it.next()
                .ok_or_else(|| format!("{arg} needs {what}; {USAGE}"))
                .cloned()
        };
        match arg.as_str() {
            "--hours" | "--minutes" => {
                let v: f64 = value("a number")?
                    .parse()
                    .map_err(|_| format!("{arg}: a number of {}; {USAGE}", &arg[2..]))?;
                let secs = if arg == "--hours" {
                    v * 3600.0
                } else {
                    v * 60.0
                };
                // At least a minute (the first round of faults needs it), at most a day.
                if !(60.0..=86_400.0).contains(&secs) {
                    return Err(format!(
                        "{arg} {v}: the soak lasts from 1 minute to 24 hours"
                    ));
                }
                config.length = Duration::from_secs_f64(secs);
            }
            "--seed" => {
                config.seed = value("a number")?
                    .parse()
                    .map_err(|_| format!("--seed: a whole number from 0 to 2^64-1; {USAGE}"))?;
            }
            "--keep" => config.keep = true,
            "--help" | "-h" => return Err(USAGE.into()),
            other => return Err(format!("unknown argument {other:?}; {USAGE}")),
        }
    }
    Ok(config)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = match parse(&args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    let verdict = soak::run(config);
    println!("{verdict}");
    if verdict.passed() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
