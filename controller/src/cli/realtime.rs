//! The real-time side's own commands besides `serve` (whose options, shared with the
//! server's controller, are `runtime::ServeArgs`): `keygen` makes the link key both ends
//! prove, `rig-sim` plays a rig over UDP, `bench-rt` measures the loop's timing.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use bdft_controller::params::{LoopParams, PlantParams};
use bdft_controller::runtime;

use super::values::parse_duration;
use super::write_result;

#[derive(Debug, clap::Args)]
pub(super) struct KeygenArgs {
    /// Where to write the key.
    file: PathBuf,
}

pub(super) fn keygen(args: KeygenArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let KeygenArgs { file } = args;
    bdft_protocol::link_auth::LinkKey::create_file(&file)?;
    writeln!(out, "wrote a new link key to {}", file.display())?;
    Ok(())
}

#[derive(Debug, clap::Args)]
pub(super) struct RigSimArgs {
    #[arg(long, default_value = "127.0.0.1:7071")]
    listen: SocketAddr,
    /// Seed of the accelerometer noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub(super) fn rig_sim(args: RigSimArgs) -> anyhow::Result<()> {
    let RigSimArgs { listen, seed } = args;
    runtime::rig_udp::run_rig_sim(
        listen,
        PlantParams::default(),
        LoopParams::default().dt,
        seed,
        Duration::from_millis(500),
        |addr| {
            println!("rig-sim listening on {addr}");
            let _ = std::io::stdout().flush();
        },
    )?;
    Ok(())
}

#[derive(Debug, clap::Args)]
pub(super) struct BenchRtArgs {
    /// Seconds to run.
    #[arg(long, default_value_t = 140.0, value_parser = parse_duration)]
    duration: f64,
    /// Trials at once.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=64))]
    trials: u64,
    #[arg(long)]
    cpu: Option<usize>,
    #[arg(long, default_value_t = 80, value_parser = clap::value_parser!(i32).range(1..=99))]
    priority: i32,
    #[arg(long)]
    json: bool,
    /// Also hand every tick's signals to an LSL stream, as `serve --lsl` does (opens LSL
    /// sockets, machine scope: run it in its own network namespace, `unshare -rn`).
    #[arg(long)]
    lsl: bool,
}

pub(super) fn bench_rt(args: BenchRtArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let BenchRtArgs {
        duration,
        trials,
        cpu,
        priority,
        json,
        lsl,
    } = args;
    let r = runtime::bench_rt(
        duration,
        trials as usize,
        cpu.or_else(runtime::default_cpu),
        priority,
        lsl,
    )?;
    write_result(out, json, &r, |out, r| {
        writeln!(
            out,
            "{} trials for {} s: {} ticks, {} overruns",
            r.trials, r.duration_s, r.timing.ticks, r.timing.overruns
        )?;
        let (w, c) = (r.timing.wake_latency_us, r.timing.compute_us);
        writeln!(
            out,
            "wake latency µs: p50 {:.1}  p99 {:.1}  max {:.1}",
            w.p50, w.p99, w.max
        )?;
        writeln!(
            out,
            "compute µs:      p50 {:.2}  p99 {:.2}  max {:.2}",
            c.p50, c.p99, c.max
        )?;
        if let Some(dropped) = r.lsl_dropped {
            writeln!(out, "LSL hand-over: {dropped} rows dropped")?;
        }
        writeln!(out, "real-time: {:?}", r.realtime)?;
        Ok(())
    })
}
