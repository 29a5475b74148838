//! Command-line interface. Other tools call these commands; the names and JSON fields are a
//! contract.

use anyhow::Context;
use clap::{Parser, Subcommand};
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use bdft_controller::analysis::AnalysisReport;
use bdft_controller::analysis::design_view::{Model, compare};
use bdft_controller::analysis::frequency;
use bdft_controller::analysis::robustness::{Range, RobustnessSpec, robustness};
use bdft_controller::compensator::CompensatorKind;
use bdft_controller::compensator::variants::variant;
use bdft_controller::interlock::DEFAULT_LIMIT_MM_S2;
use bdft_controller::param_set::ParamSet;
use bdft_controller::params::{LoopParams, MAX_KBF, NOMINAL_KBF, PlantParams, Seat};
use bdft_controller::runtime;
use bdft_controller::simulate::{SignalKind, SimConfig, simulate};
use bdft_protocol::numbers::format_number;
use bdft_protocol::trial::{RECORD_CHANNELS, RECORD_TIME};

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
    Analyze {
        /// JSON file of parameters (as printed by `defaults`; keys left out keep their default).
        #[arg(long)]
        params: Option<PathBuf>,
        /// Device-to-cylinder gain K_BF at which to close the feedthrough loop.
        #[arg(long, default_value_t = NOMINAL_KBF, value_parser = parse_kbf)]
        kbf: f64,
        /// The loop the table reports: design (the textbook structure, ideal measurements,
        /// continuous time) or implemented (the sampled loop as it runs). Both are shown
        /// side by side after it.
        #[arg(long, default_value = "implemented")]
        model: Model,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Robustness of designs: the largest stable K_BF over a K_H × structure-frequency map,
    /// and the Monte-Carlo pass rate at the study's K_BF with K_H, both structure
    /// frequencies and dampings and the valve parameters drawn within the ranges.
    Robustness {
        /// Designs: compensator names (the --params file's design of it), optionally with an
        /// option after a colon (pid-shaper:zvd, pid-shaper:ei, pid-shaper:two-hump-ei,
        /// …-per-mode, lqr:kalman, …: that variant of the default design).
        #[arg(required = true)]
        designs: Vec<String>,
        /// JSON file of parameters (as printed by `defaults`); its plant is the nominal one
        /// the designs are made for.
        #[arg(long)]
        params: Option<PathBuf>,
        /// K_H deviation from nominal, percent: LO,HI.
        #[arg(long, default_value = "-50,50", value_parser = parse_range, allow_hyphen_values = true)]
        kh_range: Range,
        /// Structure-frequency deviation (both modes), percent: LO,HI.
        #[arg(long, default_value = "-20,20", value_parser = parse_range, allow_hyphen_values = true)]
        freq_range: Range,
        /// Structure damping deviation (both modes), percent: LO,HI.
        #[arg(long, default_value = "-30,30", value_parser = parse_range, allow_hyphen_values = true)]
        damping_range: Range,
        /// Valve/cylinder K_VC, ω_VC, ζ_VC deviation, percent: LO,HI.
        #[arg(long, default_value = "-10,10", value_parser = parse_range, allow_hyphen_values = true)]
        valve_range: Range,
        /// Map cells per axis.
        #[arg(long, default_value_t = 50)]
        grid: usize,
        /// Monte-Carlo draws.
        #[arg(long, default_value_t = 1000)]
        draws: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// The study's K_BF: a draw passes if the loop is stable there.
        #[arg(long, default_value_t = 0.78, value_parser = parse_kbf)]
        kbf: f64,
        /// Print JSON instead of a summary.
        #[arg(long)]
        json: bool,
    },
    /// Frequency domain of the sampled loop as it runs: Bode data of the rig's parts, the
    /// body, each compensator and each closed loop (on and off the machine); the Nyquist
    /// curve with the feedthrough loop opened (encirclements of −1, verdict, largest stable
    /// K_BF); the closed-loop pole table in both views.
    Frequency {
        /// JSON file of parameters (as printed by `defaults`).
        #[arg(long)]
        params: Option<PathBuf>,
        /// A design to report (repeatable; names as for `robustness`) [default: the six
        /// compensators].
        #[arg(long = "compensator")]
        compensators: Vec<String>,
        /// K_BF at which the loops are closed and the Nyquist curve is drawn.
        #[arg(long, default_value_t = NOMINAL_KBF, value_parser = parse_kbf)]
        kbf: f64,
        /// Print JSON instead of a summary.
        #[arg(long)]
        json: bool,
    },
    /// Simulate one compensator on the validated rig model, faster than real time.
    Simulate {
        /// JSON file of parameters (as printed by `defaults`; keys left out keep their default).
        #[arg(long)]
        params: Option<PathBuf>,
        /// pid, pid-notch, pid-shaper, lqr, lqr-cabvel or lqr-cabacc.
        #[arg(long)]
        compensator: CompensatorKind,
        /// swept-sine (0.01→8 Hz, 5 mm) and trapezoid (±25 mm, 6 s) drive the cylinder
        /// reference directly; steps runs the protocol's random-step target tracked by the
        /// synthetic operator through the input device.
        #[arg(long)]
        signal: SignalKind,
        /// Length in seconds [default: 30 for bench signals, 140 for steps].
        #[arg(long, value_parser = parse_duration)]
        duration: Option<f64>,
        /// Operator station: on (feedthrough loop closed) or off [default: on for steps,
        /// off for bench signals, which have no operator].
        #[arg(long)]
        station: Option<Seat>,
        /// Device-to-cylinder gain K_BF.
        #[arg(long, default_value_t = NOMINAL_KBF, value_parser = parse_kbf_positive)]
        kbf: f64,
        /// Seed of the target, the accelerometer noise and the operator's remnant.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Cab-vibration interlock for steps (an operator in the cab): stop when the RMS
        /// cab acceleration over 1 s exceeds this (mm/s²). Bench signals run without it.
        #[arg(long, default_value_t = DEFAULT_LIMIT_MM_S2)]
        max_cab_rms: f64,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Write the full 1 kHz record as CSV to this file.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Print every parameter with its default value as JSON (edit it and pass it back with
    /// --params).
    Defaults,
    /// Run the real-time controller: the server connects here and runs trials at 1 kHz on
    /// the simulated rig (default) or a real rig over UDP.
    Serve(runtime::ServeArgs),
    /// Make a new link key file (readable only by you) for `serve --key-file` and the
    /// server's `--controller-key-file`; an existing file is never overwritten.
    Keygen {
        /// Where to write the key.
        file: PathBuf,
    },
    /// Play a rig over UDP with the validated model: each command datagram steps the model
    /// one sample and is answered with the sensors.
    RigSim {
        #[arg(long, default_value = "127.0.0.1:7071")]
        listen: SocketAddr,
        /// Seed of the accelerometer noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Run simulated trials in real time and report the loop's timing.
    BenchRt {
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
    },
}

fn parse_finite(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s} is not a finite number"))
    }
}

fn parse_kbf(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if (0.0..=MAX_KBF).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{v} is out of range: K_BF must be in [0, {MAX_KBF}]"
        ))
    }
}

fn parse_range(s: &str) -> Result<Range, String> {
    let (lo, hi) = s
        .split_once(',')
        .ok_or_else(|| format!("{s:?} is not a range: write LO,HI in percent, e.g. -20,20"))?;
    let (lo, hi) = (parse_finite(lo.trim())?, parse_finite(hi.trim())?);
    if lo <= hi {
        Ok(Range::pct(lo, hi))
    } else {
        Err(format!("{s}: LO must not exceed HI"))
    }
}

fn parse_kbf_positive(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if v > 0.0 && v <= MAX_KBF {
        Ok(v)
    } else {
        Err(format!(
            "{v} is out of range: K_BF must be in (0, {MAX_KBF}]"
        ))
    }
}

fn parse_duration(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if v > 0.0 && v <= 3600.0 {
        Ok(v)
    } else {
        Err(format!(
            "{v} is out of range: the duration must be in (0, 3600] seconds"
        ))
    }
}

/// The design a workbench name stands for: a compensator's name is the parameter file's
/// design of it (its default when the file lists none), a name with an option that variant
/// of the default design.
fn design(
    params: &ParamSet,
    name: &str,
) -> anyhow::Result<bdft_controller::compensator::CompensatorSpec> {
    Ok(match name.parse::<CompensatorKind>() {
        Ok(kind) => params.compensator(kind),
        Err(_) => variant(name, &params.plant, params.dt)?,
    })
}

fn load_params(path: Option<&PathBuf>) -> anyhow::Result<ParamSet> {
    let Some(path) = path else {
        return Ok(ParamSet::default());
    };
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let params: ParamSet = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a valid parameter file", path.display()))?;
    params
        .validate()
        .with_context(|| format!("in {}", path.display()))?;
    Ok(params)
}

pub fn run() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match execute(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn execute(command: Command) -> anyhow::Result<()> {
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    match command {
        Command::Serve(args) => runtime::serve_announcing(&args)?,
        Command::Keygen { file } => {
            bdft_protocol::link_auth::LinkKey::create_file(&file)?;
            writeln!(out, "wrote a new link key to {}", file.display())?;
        }
        Command::RigSim { listen, seed } => {
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
        }
        Command::BenchRt {
            duration,
            trials,
            cpu,
            priority,
            json,
        } => {
            let r = runtime::bench_rt(
                duration,
                trials as usize,
                cpu.or_else(runtime::default_cpu),
                priority,
            )?;
            if json {
                serde_json::to_writer(&mut out, &r)?;
                writeln!(out)?;
            } else {
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
                writeln!(out, "real-time: {:?}", r.realtime)?;
            }
        }
        Command::Defaults => {
            serde_json::to_writer_pretty(&mut out, &ParamSet::default())?;
            writeln!(out)?;
        }
        Command::Analyze {
            params,
            kbf,
            model,
            json,
        } => {
            let params = load_params(params.as_ref())?;
            let comparison = CompensatorKind::ALL
                .into_iter()
                .map(|k| {
                    compare(&params.setup(k, Seat::On, kbf))
                        .with_context(|| format!("analysing {k}"))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            let compensators = comparison
                .iter()
                .map(|c| match model {
                    Model::Design => c.design.clone(),
                    Model::Implemented => c.implemented.clone(),
                })
                .collect();
            let report = AnalysisReport {
                kbf,
                model,
                compensators,
                comparison,
            };
            if json {
                serde_json::to_writer(&mut out, &report)?;
                writeln!(out)?;
            } else {
                print_analysis(&mut out, &report)?;
            }
        }
        Command::Robustness {
            designs,
            params,
            kh_range,
            freq_range,
            damping_range,
            valve_range,
            grid,
            draws,
            seed,
            kbf,
            json,
        } => {
            let params = load_params(params.as_ref())?;
            let spec = RobustnessSpec {
                kh: kh_range,
                freq: freq_range,
                damping: damping_range,
                valve: valve_range,
                grid,
                draws,
                seed,
                kbf,
            };
            spec.validate()?;
            let reports = designs
                .iter()
                .map(|name| {
                    let mut setup = params.setup(CompensatorKind::Pid, Seat::On, kbf);
                    setup.compensator = design(&params, name)?;
                    robustness(name, &setup, &spec).with_context(|| format!("analysing {name}"))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            if json {
                serde_json::to_writer(&mut out, &reports)?;
                writeln!(out)?;
            } else {
                writeln!(
                    out,
                    "{:<26} {:>14} {:>14} {:>10}",
                    "design", "min max K_BF", "max max K_BF", "pass rate"
                )?;
                for r in &reports {
                    let cells = r.max_stable_kbf.iter().flatten();
                    let lo = cells
                        .clone()
                        .map(|c| c.unwrap_or(MAX_KBF))
                        .fold(f64::INFINITY, f64::min);
                    let hi = cells.map(|c| c.unwrap_or(MAX_KBF)).fold(0.0, f64::max);
                    let rate = r
                        .pass_rate
                        .map_or_else(|| "—".into(), |p| format!("{:.1} %", 100.0 * p));
                    writeln!(out, "{:<26} {lo:>14.4} {hi:>14.4} {rate:>10}", r.design)?;
                }
            }
        }
        Command::Frequency {
            params,
            compensators,
            kbf,
            json,
        } => {
            let params = load_params(params.as_ref())?;
            let names = if compensators.is_empty() {
                CompensatorKind::ALL
                    .iter()
                    .map(|k| k.name().to_string())
                    .collect()
            } else {
                compensators
            };
            let designs = names
                .into_iter()
                .map(|name| -> anyhow::Result<_> {
                    let spec = design(&params, &name)?;
                    Ok((name, spec))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            let base = params.setup(CompensatorKind::Pid, Seat::On, kbf);
            let r = frequency::report(&base, &designs)?;
            if json {
                serde_json::to_writer(&mut out, &r)?;
                writeln!(out)?;
            } else {
                writeln!(
                    out,
                    "K_BF {kbf}: the feedthrough loop opened (Nyquist), {} frequencies {:.2}–{:.0} Hz",
                    r.freqs_hz.len(),
                    r.freqs_hz[0],
                    r.freqs_hz[r.freqs_hz.len() - 1]
                )?;
                writeln!(
                    out,
                    "{:<26} {:>8} {:>14} {:>12} {:>14}",
                    "design", "stable", "encirclements", "open-loop P", "max K_BF"
                )?;
                for c in &r.compensators {
                    let n = &c.nyquist;
                    let max = n
                        .max_stable_kbf
                        .map_or_else(|| format!("> {MAX_KBF}"), |k| format!("{k:.4}"));
                    writeln!(
                        out,
                        "{:<26} {:>8} {:>14} {:>12} {max:>14}",
                        c.name, n.stable, n.encirclements, n.open_loop_unstable
                    )?;
                }
            }
        }
        Command::Simulate {
            params,
            compensator,
            signal,
            duration,
            station,
            kbf,
            seed,
            max_cab_rms,
            json,
            out: record,
        } => {
            let station = station.unwrap_or(if signal == SignalKind::Steps {
                Seat::On
            } else {
                Seat::Off
            });
            let params = load_params(params.as_ref())?;
            let cfg = SimConfig {
                setup: params.setup(compensator, station, kbf),
                signal,
                duration_s: duration.unwrap_or(signal.default_duration_s()),
                seed,
                operator: params.operator,
                steps: params.steps,
                max_cab_rms_mm_s2: (signal == SignalKind::Steps).then_some(max_cab_rms),
            };
            let summary = match record {
                Some(path) => write_record(&cfg, &path)?,
                None => simulate(&cfg, |_| {})?,
            };
            if json {
                serde_json::to_writer(&mut out, &summary)?;
                writeln!(out)?;
            } else {
                writeln!(out, "compensator       {}", summary.compensator)?;
                writeln!(
                    out,
                    "signal            {} ({} s, seed {})",
                    summary.signal, summary.duration_s, summary.seed
                )?;
                writeln!(
                    out,
                    "station           {} (K_BF {})",
                    summary.station, summary.kbf
                )?;
                writeln!(out, "tracking MSE      {:.3} mm²", summary.mse_tracking_mm2)?;
                writeln!(
                    out,
                    "cab accel MS      {:.1} (mm/s²)²",
                    summary.ms_cab_accel
                )?;
                if let (Some(m), Some(s)) = (summary.target_mean_mm, summary.target_std_mm) {
                    writeln!(out, "target            mean {m:.3} mm, std {s:.3} mm")?;
                }
                match (summary.stopped_at_s, summary.stop_rms_mm_s2) {
                    (Some(t), Some(rms)) => writeln!(
                        out,
                        "outcome           STOPPED by the cab-vibration interlock at t = {t:.3} s ({rms:.0} mm/s² RMS over 1 s, limit {max_cab_rms:.0})"
                    )?,
                    _ => writeln!(out, "outcome           {}", summary.outcome)?,
                }
            }
        }
    }
    Ok(())
}

/// Simulates while streaming the record to a CSV file; the file only appears complete
/// (written to a temporary name, renamed at the end) so a failed run leaves no half file.
fn write_record(
    cfg: &SimConfig,
    path: &PathBuf,
) -> anyhow::Result<bdft_controller::simulate::SimSummary> {
    let tmp = path.with_extension("partial");
    let file =
        std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    let mut w = std::io::BufWriter::new(file);
    // The columns, names and number format of the server's samples export (less its join
    // keys): one definition in bdft_protocol::trial. No real-time loop here: latency 0.
    let header: Vec<&str> = std::iter::once(&RECORD_TIME)
        .chain(&RECORD_CHANNELS)
        .map(|c| c.name)
        .collect();
    writeln!(w, "{}", header.join(","))?;
    let mut line = String::with_capacity(128);
    let mut io_err = None;
    let summary = simulate(cfg, |s| {
        if io_err.is_some() {
            return;
        }
        line.clear();
        line.push_str(&format_number(s.t, RECORD_TIME.decimals));
        for (v, c) in s.record_row(0.0).into_iter().zip(&RECORD_CHANNELS) {
            line.push(',');
            line.push_str(&format_number(v, c.decimals));
        }
        line.push('\n');
        let res = w.write_all(line.as_bytes());
        if let Err(e) = res {
            io_err = Some(e);
        }
    });
    let summary = match (summary, io_err) {
        (Ok(s), None) => s,
        (Err(e), _) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e.into());
        }
        (_, Some(e)) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(anyhow::Error::from(e).context(format!("writing {}", tmp.display())));
        }
    };
    w.flush()?;
    drop(w);
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(summary)
}

fn print_analysis(out: &mut impl Write, r: &AnalysisReport) -> std::io::Result<()> {
    writeln!(
        out,
        "Feedthrough loop closed at K_BF = {} (station on), loop rate {:.0} Hz, {} model",
        r.kbf,
        1.0 / LoopParams::default().dt,
        r.model.name()
    )?;
    writeln!(
        out,
        "{:<12} {:<7} {:>16} {:>16}   least-damped pole (rad/s)",
        "compensator", "stable", "max stable K_BF", "spectral radius"
    )?;
    for c in &r.compensators {
        let max = match c.max_stable_kbf {
            Some(k) => format!("{k:.4}"),
            None => format!("> {MAX_KBF}"),
        };
        let pole = c
            .poles
            .iter()
            .max_by(|a, b| {
                a[0].total_cmp(&b[0])
                    .then(a[1].abs().total_cmp(&b[1].abs()))
            })
            .map(|p| format!("{:.3} ± {:.3}j", p[0], p[1].abs()))
            .unwrap_or_else(|| "(delays: see spectral radius)".into());
        writeln!(
            out,
            "{:<12} {:<7} {:>16} {:>16.6}   {}",
            c.name,
            if c.stable { "yes" } else { "NO" },
            max,
            c.spectral_radius,
            pole
        )?;
    }
    print_comparison(out, r)
}

fn print_comparison(out: &mut impl Write, r: &AnalysisReport) -> std::io::Result<()> {
    let pole = |p: Option<[f64; 2]>| match p {
        Some([re, im]) if im.abs() > 1e-9 => format!("{re:.3} ± {:.3}j", im.abs()),
        Some([re, _]) => format!("{re:.3}"),
        None => "—".into(),
    };
    writeln!(out)?;
    writeln!(out, "Design model beside the implemented loop")?;
    writeln!(
        out,
        "{:<12} {:>18} {:>18}",
        "compensator", "design max K_BF", "implemented max K_BF"
    )?;
    let kbf = |k: Option<f64>| k.map_or_else(|| format!("> {MAX_KBF}"), |k| format!("{k:.4}"));
    for c in &r.comparison {
        writeln!(
            out,
            "{:<12} {:>18} {:>18}   {}",
            c.name,
            kbf(c.design.max_stable_kbf),
            kbf(c.implemented.max_stable_kbf),
            c.note
        )?;
        // A conjugate pair moves together: list its upper member only.
        for d in c
            .differences
            .iter()
            .filter(|d| d.design.or(d.implemented).is_some_and(|p| p[1] >= 0.0))
        {
            writeln!(
                out,
                "    {:>22} → {:<22} {}",
                pole(d.design),
                pole(d.implemented),
                d.cause
            )?;
        }
    }
    Ok(())
}
