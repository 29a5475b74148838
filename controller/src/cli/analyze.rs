//! `analyze`: every compensator's stability with the feedthrough loop closed — verdict,
//! largest stable K_BF, closed-loop poles — in the chosen view, then the design model beside
//! the implemented loop with the cause of each pole's difference.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use bdft_controller::analysis::AnalysisReport;
use bdft_controller::analysis::design_view::{Model, compare};
use bdft_controller::compensator::CompensatorKind;
use bdft_controller::params::{LoopParams, MAX_KBF, NOMINAL_KBF, Seat};

use super::params::load_params;
use super::values::parse_kbf;
use super::write_result;

#[derive(Debug, clap::Args)]
pub(super) struct AnalyzeArgs {
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
}

pub(super) fn run(args: AnalyzeArgs, out: &mut impl Write) -> anyhow::Result<()> {
    let AnalyzeArgs {
        params,
        kbf,
        model,
        json,
    } = args;
    let params = load_params(params.as_ref())?;
    let comparison = CompensatorKind::ALL
        .into_iter()
        .map(|k| compare(&params.setup(k, Seat::On, kbf)).with_context(|| format!("analysing {k}")))
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
    write_result(out, json, &report, print_analysis)
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
