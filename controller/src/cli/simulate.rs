//! `simulate`: one compensator on the rig model, faster than real time; its summary as a
//! table or JSON, and with `--out` the full record as CSV in the samples export's columns.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use bdft_controller::compensator::CompensatorKind;
use bdft_controller::interlock::DEFAULT_LIMIT_MM_S2;
use bdft_controller::params::{MachineCondition, NOMINAL_KBF, Seat};
use bdft_controller::simulate::{SignalKind, SimConfig, SimSummary, simulate};
use bdft_protocol::numbers::format_number;
use bdft_protocol::trial::{RECORD_CHANNELS, RECORD_TIME};

use super::params::load_params;
use super::values::{parse_duration, parse_kbf_positive};
use super::write_result;

#[derive(Debug, clap::Args)]
pub(super) struct SimulateArgs {
    /// JSON file of parameters (as printed by `defaults`; keys left out keep their default).
    #[arg(long)]
    params: Option<PathBuf>,
    /// pid, pid-notch, pid-shaper, lqr, lqr-cabvel, lqr-cabacc, pid-notch-adaptive,
    /// pid-shaper-adaptive or lqr-cabvel-scheduled.
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
    /// The operator's seat: on (feedthrough loop closed) or off [default: on for steps,
    /// off for bench signals, which have no operator].
    #[arg(long = "station", visible_alias = "seat", value_name = "STATION")]
    seat: Option<Seat>,
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
    /// The machine's condition (stilts, tires, outriggers, loaded[:FILL], stick, joined by
    /// '+'): the design stays made for the parameters' rig, the run is on that rig under it.
    #[arg(long, default_value = "stilts")]
    condition: MachineCondition,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Write the full 1 kHz record as CSV to this file.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub(super) fn run(args: SimulateArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let SimulateArgs {
        params,
        compensator,
        signal,
        duration,
        seat,
        kbf,
        seed,
        max_cab_rms,
        condition,
        json,
        out: record,
    } = args;
    let seat = seat.unwrap_or(if signal == SignalKind::Steps {
        Seat::On
    } else {
        Seat::Off
    });
    let params = load_params(params.as_ref())?;
    let cfg = SimConfig {
        setup: params.setup(compensator, seat, kbf),
        signal,
        duration_s: duration.unwrap_or(signal.default_duration_s()),
        seed,
        operator: params.operator,
        steps: params.steps,
        max_cab_rms_mm_s2: (signal == SignalKind::Steps).then_some(max_cab_rms),
        condition,
    };
    let summary = match record {
        Some(path) => write_record(&cfg, &path)?,
        None => simulate(&cfg, |_| {})?,
    };
    write_result(out, json, &summary, |out, summary| {
        writeln!(out, "compensator       {}", summary.compensator)?;
        writeln!(
            out,
            "signal            {} ({} s, seed {})",
            summary.signal, summary.duration_s, summary.seed
        )?;
        writeln!(
            out,
            "station           {} (K_BF {})",
            summary.seat, summary.kbf
        )?;
        writeln!(out, "tracking MSE      {:.3} mm²", summary.mse_tracking_mm2)?;
        writeln!(
            out,
            "cab accel MS      {:.1} (mm/s²)²",
            summary.ms_cab_accel
        )?;
        writeln!(
            out,
            "cab a_w, VDV      {:.4} m/s², {:.4} m/s^1.75 (ISO 2631-1 W_d)",
            summary.cab_aw_m_s2, summary.cab_vdv_m_s175
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
        Ok(())
    })
}

/// Simulates while streaming the record to a CSV file; the file only appears complete
/// (written to a temporary name, renamed at the end) so a failed run leaves no half file.
fn write_record(cfg: &SimConfig, path: &PathBuf) -> anyhow::Result<SimSummary> {
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
