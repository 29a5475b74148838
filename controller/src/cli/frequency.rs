//! `frequency`: the sampled loop's frequency domain (Bode data, the Nyquist view, the pole
//! table in both views); the summary printed is each design's Nyquist verdict.

use std::io::Write;
use std::path::PathBuf;

use bdft_controller::analysis::frequency;
use bdft_controller::compensator::CompensatorKind;
use bdft_controller::params::{MAX_KBF, MachineCondition, NOMINAL_KBF, Seat};

use super::params::{design, load_params};
use super::values::parse_kbf;
use super::write_result;

#[derive(Debug, clap::Args)]
pub(super) struct FrequencyArgs {
    /// JSON file of parameters (as printed by `defaults`).
    #[arg(long)]
    params: Option<PathBuf>,
    /// A design to report (repeatable; names as for `robustness`) [default: every
    /// compensator; an adaptive one as its design frozen at r = 1].
    #[arg(long = "compensator")]
    compensators: Vec<String>,
    /// K_BF at which the loops are closed and the Nyquist curve is drawn.
    #[arg(long, default_value_t = NOMINAL_KBF, value_parser = parse_kbf)]
    kbf: f64,
    /// The machine's condition the designs, made for the thesis's rig, run on (as for
    /// `simulate`): the parts, closed loops and Nyquist view are of the machine under it.
    #[arg(long, default_value = "stilts")]
    condition: MachineCondition,
    /// Print JSON instead of a summary.
    #[arg(long)]
    json: bool,
}

pub(super) fn run(args: FrequencyArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let FrequencyArgs {
        params,
        compensators,
        kbf,
        condition,
        json,
    } = args;
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
    let rig = condition.apply(&base.plant)?;
    let r = frequency::FrequencyReport {
        condition: (!condition.is_default()).then(|| condition.to_string()),
        ..frequency::report(&base, &designs, rig)?
    };
    write_result(out, json, &r, |out, r| {
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
        Ok(())
    })
}
