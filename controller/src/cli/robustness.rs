//! `robustness`: each design fixed on the nominal plant and run on perturbed rigs — the
//! K_H × structure-frequency map of the largest stable K_BF and the Monte-Carlo pass rate —
//! printed as one summary line a design.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use bdft_controller::analysis::robustness::{Range, RobustnessSpec, robustness};
use bdft_controller::compensator::CompensatorKind;
use bdft_controller::params::{MAX_KBF, Seat};

use super::params::{design, load_params};
use super::values::{parse_kbf, parse_range};
use super::write_result;

#[derive(Debug, clap::Args)]
pub(super) struct RobustnessArgs {
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
}

pub(super) fn run(args: RobustnessArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let RobustnessArgs {
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
    } = args;
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
    write_result(out, json, &reports, |out, reports| {
        writeln!(
            out,
            "{:<26} {:>14} {:>14} {:>10}",
            "design", "min max K_BF", "max max K_BF", "pass rate"
        )?;
        for r in reports {
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
        Ok(())
    })
}
