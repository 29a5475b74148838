//! Speed of the control core, run with `cargo bench -p bdft-controller --bench tick`.
//!
//! - cost of one closed-loop tick (plant + accelerometer + body + compensator) per compensator;
//! - one 140 s protocol trial (140,000 ticks with the synthetic operator) end to end;
//! - the same discrete PID-notch loop as `tools/bench/forced_response.py`, timed here and
//!   there (python-control's `forced_response`) in the same run, with the ratio.
//!
//! Medians over repeated runs: the machines are shared and noisy.

use std::hint::black_box;
use std::process::Command;
use std::time::Instant;

use bdft_controller::closed_loop::{ClosedLoop, Drive, LoopSetup};
use bdft_controller::compensator::{CompensatorKind, default_spec};
use bdft_controller::operator::OperatorParams;
use bdft_controller::params::{BodyModel, LoopParams, PlantParams, Seat};
use bdft_controller::signals::StepParams;
use bdft_controller::simulate::{SignalKind, SimConfig, simulate};

const RUNS: usize = 9;

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

fn setup(kind: CompensatorKind, noise: bool) -> LoopSetup {
    let plant = PlantParams {
        accel_noise_std: if noise { 150.0 } else { 0.0 },
        ..PlantParams::default()
    };
    LoopSetup {
        compensator: default_spec(kind, &plant),
        plant,
        body: BodyModel::default(),
        loop_params: LoopParams::default(),
        station: Seat::On,
    }
}

/// Median nanoseconds per tick over `RUNS` runs of `ticks` ticks.
fn time_ticks(lp: &mut ClosedLoop, ticks: usize) -> f64 {
    let runs = (0..RUNS)
        .map(|_| {
            lp.reset();
            let start = Instant::now();
            for k in 0..ticks {
                // A 0.5 Hz, 20 mm hand motion keeps every branch live and nothing saturated.
                let p_h = 20.0 * (k as f64 * 1e-3 * std::f64::consts::PI).sin();
                black_box(lp.tick(Drive::Hand(black_box(p_h))));
            }
            start.elapsed().as_nanos() as f64 / ticks as f64
        })
        .collect();
    median(runs)
}

fn main() {
    let mut report = serde_json::Map::new();
    println!(
        "tick cost (plant + accelerometer noise + body + compensator), median of {RUNS} × 200,000 ticks"
    );
    let mut ticks = serde_json::Map::new();
    for kind in CompensatorKind::ALL {
        let mut lp = ClosedLoop::new(&setup(kind, true), 1).expect("design");
        let ns = time_ticks(&mut lp, 200_000);
        println!("  {:<12} {ns:7.1} ns", kind.name());
        ticks.insert(kind.name().into(), ns.into());
    }
    report.insert("tick_ns".into(), ticks.into());

    let mut trial = serde_json::Map::new();
    println!("140 s trial (steps, synthetic operator, station on), median of {RUNS}");
    for kind in CompensatorKind::ALL {
        let cfg = SimConfig {
            setup: setup(kind, true),
            signal: SignalKind::Steps,
            duration_s: 140.0,
            seed: 1,
            operator: OperatorParams::default(),
            steps: StepParams::default(),
            max_cab_rms_mm_s2: None,
        };
        let ms = median(
            (0..RUNS)
                .map(|_| {
                    let start = Instant::now();
                    black_box(simulate(&cfg, |s| {
                        black_box(s);
                    }))
                    .expect("simulate");
                    start.elapsed().as_secs_f64() * 1e3
                })
                .collect(),
        );
        println!("  {:<12} {ms:7.2} ms", kind.name());
        trial.insert(kind.name().into(), ms.into());
    }
    report.insert("trial_140s_ms".into(), trial.into());

    // The loop of tools/bench/forced_response.py: PID-notch, station on, K_BF 0.6, no noise.
    let mut lp = ClosedLoop::new(&setup(CompensatorKind::PidNotch, false), 1).expect("design");
    let ours_s = time_ticks(&mut lp, 140_000) * 140_000.0 * 1e-9;
    println!(
        "PID-notch loop, 140,000 ticks: bdft-lab {:.3} ms",
        ours_s * 1e3
    );
    report.insert("pid_notch_140k_s".into(), ours_s.into());
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../tools/bench/forced_response.py"
    );
    match Command::new("python3")
        .arg(script)
        .args(["--runs", "7"])
        .output()
    {
        Ok(out) if out.status.success() => {
            let line = String::from_utf8_lossy(&out.stdout);
            let theirs: serde_json::Value =
                serde_json::from_str(line.trim()).expect("script prints JSON");
            let theirs_s = theirs["median_s"].as_f64().expect("median_s");
            println!(
                "  python-control {} forced_response: {:.1} ms → bdft-lab is {:.0}× faster",
                theirs["version"],
                theirs_s * 1e3,
                theirs_s / ours_s
            );
            report.insert("python_control".into(), theirs);
            report.insert(
                "speedup_vs_python_control".into(),
                (theirs_s / ours_s).into(),
            );
        }
        Ok(out) => println!(
            "  python-control comparison skipped: {}",
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        ),
        Err(e) => println!("  python-control comparison skipped: {e}"),
    }
    println!("{}", serde_json::Value::Object(report));
}
