//! Command-line interface. Other tools call these commands; the names and JSON fields are a
//! contract.
//!
//! Here: the command list (each command's help text), the dispatch, and `write_result`,
//! how every command with `--json` prints its result. Each command's options, its run and
//! what it prints are in a module of its own: `analyze`, `robustness`, `frequency`,
//! `simulate`, `conditions`, and `realtime` for `keygen`, `rig-sim` and `bench-rt` (`serve`'s options are
//! `runtime::ServeArgs`, shared with the server). `values` parses the numbers among the
//! options with their ranges; `params` reads a parameter file and design names.

mod analyze;
mod conditions;
mod frequency;
mod params;
mod realtime;
mod robustness;
mod simulate;
mod values;

use std::io::Write;
use std::process::ExitCode;

use bdft_controller::param_set::ParamSet;
use bdft_controller::runtime;
use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "bdft-controller",
    version,
    about = "Biodynamic-feedthrough controller: design analysis and simulation of the five compensators"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Stability of every compensator with the feedthrough loop closed at K_BF: verdict,
    /// largest stable K_BF and closed-loop poles.
    Analyze(analyze::AnalyzeArgs),
    /// Robustness of designs: the largest stable K_BF over a K_H × structure-frequency map,
    /// and the Monte-Carlo pass rate at the study's K_BF with K_H, both structure
    /// frequencies and dampings and the valve parameters drawn within the ranges.
    Robustness(robustness::RobustnessArgs),
    /// Frequency domain of the sampled loop as it runs: Bode data of the rig's parts, the
    /// body, each compensator and each closed loop (on and off the machine); the Nyquist
    /// curve with the feedthrough loop opened (encirclements of −1, verdict, largest stable
    /// K_BF); the closed-loop pole table in both views.
    Frequency(frequency::FrequencyArgs),
    /// Machine conditions: each design, made for the parameters' rig, on that rig on tires,
    /// outriggers, with a loaded bucket, driving the stick, …: its bench cab-acceleration
    /// reduction against its twin and its largest stable K_BF with the body.
    Conditions(conditions::ConditionsArgs),
    /// Simulate one compensator on the validated rig model, faster than real time.
    Simulate(simulate::SimulateArgs),
    /// Print every parameter with its default value as JSON (edit it and pass it back with
    /// --params).
    Defaults,
    /// Run the real-time controller: the server connects here and runs trials at 1 kHz on
    /// the simulated rig (default) or a real rig over UDP.
    Serve(runtime::ServeArgs),
    /// Make a new link key file (readable only by you) for `serve --key-file` and the
    /// server's `--controller-key-file`; an existing file is never overwritten.
    Keygen(realtime::KeygenArgs),
    /// Play a rig over UDP with the validated model: each command datagram steps the model
    /// one sample and is answered with the sensors.
    RigSim(realtime::RigSimArgs),
    /// Run simulated trials in real time and report the loop's timing.
    BenchRt(realtime::BenchRtArgs),
}

pub fn run() -> ExitCode {
    let cli = Cli::parse();
    bdft_controller::logging::init();
    match execute(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

/// What a command with `--json` prints: its result as one line of JSON (the contract other
/// tools read), or else the summary `summary` writes of it.
fn write_result<W: Write, T: serde::Serialize>(
    out: &mut W,
    json: bool,
    result: &T,
    summary: impl FnOnce(&mut W, &T) -> std::io::Result<()>,
) -> anyhow::Result<()> {
    if json {
        serde_json::to_writer(&mut *out, result)?;
        writeln!(out)?;
    } else {
        summary(out, result)?;
    }
    Ok(())
}

fn execute(command: Command) -> anyhow::Result<()> {
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    match command {
        Command::Serve(args) => runtime::serve_announcing(&args)?,
        Command::Keygen(args) => realtime::keygen(args, &mut out)?,
        Command::RigSim(args) => realtime::rig_sim(args)?,
        Command::BenchRt(args) => realtime::bench_rt(args, &mut out)?,
        Command::Defaults => {
            serde_json::to_writer_pretty(&mut out, &ParamSet::default())?;
            writeln!(out)?;
        }
        Command::Analyze(args) => analyze::run(args, &mut out)?,
        Command::Robustness(args) => robustness::run(args, &mut out)?,
        Command::Frequency(args) => frequency::run(args, &mut out)?,
        Command::Simulate(args) => simulate::run(args, &mut out)?,
        Command::Conditions(args) => conditions::run(args, &mut out)?,
    }
    Ok(())
}
