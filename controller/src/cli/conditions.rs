//! `conditions`: the machine-conditions table (`docs/machine-conditions.md`) — each design,
//! made for the parameter file's rig, on that rig under each condition: its swept-sine bench
//! cab-acceleration reduction against its twin and its largest stable K_BF with the body.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use bdft_controller::compensator::CompensatorKind;
use bdft_controller::conditions::condition_table;
use bdft_controller::params::{MachineCondition, Seat};

use super::params::{design, load_params};
use super::values::parse_kbf;
use super::write_result;

#[derive(Debug, clap::Args)]
pub(super) struct ConditionsArgs {
    /// Designs, as `robustness` takes them [default: the notch, the shaper and the
    /// cab-velocity LQR, each fixed and adaptive, and the LQR's Kalman-observer variant; each
    /// twin is run too].
    designs: Vec<String>,
    /// Conditions, comma-separated (stilts, tires, outriggers, loaded[:FILL], stick, modes:R
    /// joined by '+') [default: every ground × empty or rated bucket × boom or stick, and
    /// the modes moved ±30 % (modes:0.7, modes:1.3)].
    #[arg(long, value_delimiter = ',')]
    conditions: Vec<MachineCondition>,
    /// JSON file of parameters (as printed by `defaults`): its plant is the rig the designs
    /// are made for, its body the one the margin closes the loop through.
    #[arg(long)]
    params: Option<PathBuf>,
    /// The study's K_BF: the verdict of each row.
    #[arg(long, default_value_t = 0.78, value_parser = parse_kbf)]
    kbf: f64,
    /// Seed of the accelerometer noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

const DEFAULT_DESIGNS: [&str; 7] = [
    "pid-notch",
    "pid-notch-adaptive",
    "pid-shaper",
    "pid-shaper-adaptive",
    "lqr-cabvel",
    "lqr-cabvel-scheduled",
    "lqr-cabvel:kalman",
];

pub(super) fn run(args: ConditionsArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let params = load_params(args.params.as_ref())?;
    let names: Vec<String> = if args.designs.is_empty() {
        DEFAULT_DESIGNS.map(String::from).to_vec()
    } else {
        args.designs
    };
    let designs = names
        .iter()
        .map(|n| Ok((n.clone(), design(&params, n)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let conditions = if args.conditions.is_empty() {
        let mut all = MachineCondition::named();
        all.extend(
            ["modes:0.7", "modes:1.3"].map(|m| m.parse::<MachineCondition>().expect("valid")),
        );
        all
    } else {
        args.conditions
    };
    let base = params.setup(CompensatorKind::Pid, Seat::On, args.kbf);
    let table =
        condition_table(&designs, &conditions, &base, args.seed).context("the conditions table")?;
    write_result(out, args.json, &table, |out, t| {
        writeln!(
            out,
            "{} bench, {} s, seed {}; margin with the body, verdict at K_BF {}",
            t.signal, t.duration_s, t.seed, t.k_bf
        )?;
        writeln!(
            out,
            "{:<20} {:<24} {:>7} {:>10} {:>9} {:>7}",
            "design", "condition", "f1 Hz", "reduction", "max K_BF", "stable"
        )?;
        for r in &t.rows {
            let reduction = r
                .cab_accel_reduction_pct
                .map_or_else(|| "—".into(), |p| format!("{p:.1} %"));
            let margin = r
                .max_stable_kbf
                .map_or_else(|| "≥ max".into(), |m| format!("{m:.3}"));
            writeln!(
                out,
                "{:<20} {:<24} {:>7.2} {reduction:>10} {margin:>9} {:>7}",
                r.design,
                r.condition,
                r.f1_hz,
                if r.stable { "yes" } else { "NO" }
            )?;
        }
        Ok(())
    })
}
