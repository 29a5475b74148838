//! Speed of the control core, run with `cargo bench -p bdft-controller --bench tick`.
//!
//! - cost of one closed-loop tick (plant + accelerometer + body + compensator) per compensator,
//!   and what model-based cancellation adds to it;
//! - one 140 s protocol trial (140,000 ticks with the synthetic operator) end to end;
//! - the same discrete PID-notch loop as `tools/bench/forced_response.py`, timed here and
//!   there (python-control's `forced_response`) in the same run, with the ratio;
//! - the real-time loop's work for the 8 trials of `bench-rt` in one tick, with warm caches
//!   and with caches evicted between ticks as the other processes of a busy machine do
//!   (`cargo bench -p bdft-controller --bench tick -- loop` runs only this part);
//! - the power planner's batched trials (`batch::metrics`, `LANES` subjects per batch)
//!   against the same trials one at a time (`runtime::local::metrics`), per compensator
//!   (`-- batch` runs only this part); `-- cancellation` runs only the cancellation's cost;
//! - what the adaptive designs' estimator, schedule and crossfade add to a tick: each adaptive
//!   design's tick against its fixed counterpart's in the same run (`-- adaptive` runs only
//!   this part; issue 41's budget: 200 ns).
//!
//! Medians over repeated runs: the machines are shared and noisy.

use std::hint::black_box;
use std::process::Command;
use std::time::Instant;

use bdft_controller::batch::{self, LANES};
use bdft_controller::cancellation::{CancellationModel, Canceller};
use bdft_controller::closed_loop::{ClosedLoop, Drive, LoopSetup};
use bdft_controller::compensator::{CompensatorKind, default_spec};
use bdft_controller::operator::OperatorParams;
use bdft_controller::params::{BodyModel, LoopParams, PlantParams, Seat};
use bdft_controller::runtime::histogram::Histogram;
use bdft_controller::runtime::local;
use bdft_controller::runtime::rt_loop::Event;
use bdft_controller::runtime::slot::SlotTick;
use bdft_controller::signals::StepParams;
use bdft_controller::simulate::{SignalKind, SimConfig, simulate};
use bdft_protocol::params::PopulationParams;
use bdft_protocol::trial::InputSource;

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
        seat: Seat::On,
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

/// Bytes written between cold ticks: more than the L2 cache and the TLBs' reach.
const EVICT_BYTES: usize = 8 << 20;

/// One loop tick's work for the 8 trials of `bench-rt` (slot ticks and live samples into an
/// event queue), p50 and p99 in µs over 4,000 ticks, with or without evicting the caches
/// between ticks.
fn loop_tick_us(cold: bool) -> (f64, f64) {
    let dt = 1e-3;
    let mut slots: Vec<_> = (0..8)
        .map(|i| {
            let st = bdft_controller::runtime::bench_trial(i, 140.0).expect("trial");
            let mut slot = bdft_controller::runtime::setup::build_slot(&st, dt, false)
                .expect("build")
                .slot;
            // As the loop installs trials.
            slot.live_phase = i as u64 % slot.live_every;
            slot
        })
        .collect();
    let (mut tx, mut rx) = rtrb::RingBuffer::new(1 << 16);
    // Pages touched once, as the loop does, so that page faults are not counted.
    while tx.push(Event::Stepped { tick: 0 }).is_ok() {}
    while rx.pop().is_ok() {}
    let mut evict = vec![0u8; EVICT_BYTES];
    let mut h = Histogram::default();
    for now in 0..4000u64 {
        if cold {
            // What the other processes on this CPU do while the loop sleeps.
            for b in evict.iter_mut().step_by(64) {
                *b = b.wrapping_add(1);
            }
            black_box(&evict);
        }
        while rx.pop().is_ok() {}
        let start = Instant::now();
        for slot in slots.iter_mut() {
            if let SlotTick::Live(s) = slot.tick(now, now * 1_000_000, 10.0) {
                let _ = tx.push(Event::Live(s));
            }
        }
        h.record(start.elapsed().as_nanos() as u64);
    }
    let p = h.percentiles_us();
    (p.p50, p.p99)
}

fn loop_cost(report: &mut serde_json::Map<String, serde_json::Value>) {
    println!("one loop tick of bench-rt's 8 trials, 4,000 ticks, median of {RUNS} runs");
    for cold in [false, true] {
        let runs: Vec<_> = (0..RUNS).map(|_| loop_tick_us(cold)).collect();
        let p50 = median(runs.iter().map(|r| r.0).collect());
        let p99 = median(runs.iter().map(|r| r.1).collect());
        let name = if cold { "cold" } else { "warm" };
        println!("  {name}: p50 {p50:6.2} µs, p99 {p99:6.2} µs");
        report.insert(
            format!("loop_tick_8_trials_{name}_us"),
            serde_json::json!({ "p50": p50, "p99": p99 }),
        );
    }
}

/// `LANES` planner trials of `kind`: 140 s, station on, each with its own subject drawn
/// from the default population (seated body, learning and fatigue as at test 3 after half
/// an hour), target and seeds.
fn planner_trials(kind: CompensatorKind) -> Vec<bdft_protocol::server_to_controller::StartTrial> {
    use bdft_controller::population;
    use bdft_protocol::params::PopulationParams;
    (0..LANES)
        .map(|i| {
            let mut st = bdft_controller::runtime::bench_trial(i, 140.0).expect("trial");
            let d = population::draw(&PopulationParams::default(), i as u64);
            st.compensator = bdft_controller::compensator::study_spec(kind, &st.plant);
            st.body = population::body(&d, st.body);
            st.input = InputSource::Synthetic {
                operator: population::operator(&d, 3, 0.5),
                seed: i as u64,
            };
            st
        })
        .collect()
}

/// Nanoseconds per trial tick (one core) of the batched planner trials, in every build this
/// CPU runs, and of the same trials one at a time, medians of `RUNS`, per study compensator.
fn batch_cost(report: &mut serde_json::Map<String, serde_json::Value>) {
    println!(
        "planner trials: {LANES} subjects × 140 s per compensator, ns per trial tick (one core), median of {RUNS}"
    );
    let dt = 1e-3;
    let mut rows = serde_json::Map::new();
    for kind in CompensatorKind::STUDY {
        let starts = planner_trials(kind);
        let ticks = (starts.len() * 140_000) as f64;
        let time = |f: &dyn Fn()| {
            median(
                (0..RUNS)
                    .map(|_| {
                        let start = Instant::now();
                        f();
                        start.elapsed().as_nanos() as f64 / ticks
                    })
                    .collect(),
            )
        };
        let mut row = serde_json::Map::new();
        let mut line = format!("  {:<12}", kind.name());
        for build in batch::Build::ALL.into_iter().filter(|b| b.available()) {
            let ns = time(&|| {
                black_box(batch::metrics_with(build, black_box(&starts), dt).expect("batch"));
            });
            line += &format!(" {build:?} {ns:5.2} ns,");
            row.insert(format!("{build:?}_ns"), ns.into());
        }
        let scalar = time(&|| {
            for st in &starts {
                black_box(local::metrics(black_box(st), dt).expect("trial"));
            }
        });
        println!("{line} one at a time {scalar:5.2} ns");
        row.insert("scalar_ns".into(), scalar.into());
        rows.insert(kind.name().into(), row.into());
    }
    report.insert("planner_trial_tick_ns".into(), rows.into());
}

/// Model-based cancellation (issue 38's budget: 50 ns a trial a tick): the PID tick with and
/// without a canceller, in the same run.
fn cancellation_cost(report: &mut serde_json::Map<String, serde_json::Value>) {
    let mut plain = ClosedLoop::new(&setup(CompensatorKind::Pid, true), 1).expect("design");
    let mut cancelling = plain.clone();
    cancelling.set_canceller(Some(
        Canceller::new(
            &CancellationModel {
                // The all-pass runs too.
                phase_lag_deg: 30.0,
                ..CancellationModel::of_seated(&PopulationParams::default().median_body())
                    .expect("seated")
            },
            1e-3,
        )
        .expect("model"),
    ));
    let (without, with) = (
        time_ticks(&mut plain, 200_000),
        time_ticks(&mut cancelling, 200_000),
    );
    println!(
        "cancellation: PID tick {without:.1} ns without, {with:.1} ns with (+{:.1} ns)",
        with - without
    );
    report.insert(
        "cancellation_ns".into(),
        serde_json::json!({ "without": without, "with": with, "added": with - without }),
    );
}

/// Each adaptive design's tick against its fixed counterpart's, in the same run: the
/// estimator, the schedule and (while blending) the second design.
fn adaptive_cost(report: &mut serde_json::Map<String, serde_json::Value>) {
    println!("adaptive designs: tick (station on, noise on), median of {RUNS} × 200,000 ticks");
    let mut rows = serde_json::Map::new();
    for kind in CompensatorKind::ALL.into_iter().filter(|k| k.is_adaptive()) {
        let fixed = kind
            .fixed_counterpart()
            .expect("an adaptive design has one");
        let mut with = ClosedLoop::new(&setup(kind, true), 1).expect("design");
        let mut without = ClosedLoop::new(&setup(fixed, true), 1).expect("design");
        let (a, f) = (
            time_ticks(&mut with, 200_000),
            time_ticks(&mut without, 200_000),
        );
        println!(
            "  {:<21} {a:6.1} ns, {:<11} {f:6.1} ns: +{:.1} ns",
            kind.name(),
            fixed.name(),
            a - f
        );
        rows.insert(
            kind.name().into(),
            serde_json::json!({ "adaptive": a, "fixed": f, "added": a - f }),
        );
    }
    report.insert("adaptive_tick_ns".into(), rows.into());
}

fn main() {
    let mut report = serde_json::Map::new();
    let only = std::env::args()
        .skip(1)
        .find(|a| a == "loop" || a == "batch" || a == "cancellation" || a == "adaptive");
    match only.as_deref() {
        Some("loop") => loop_cost(&mut report),
        Some("batch") => batch_cost(&mut report),
        Some("adaptive") => adaptive_cost(&mut report),
        Some(_) => cancellation_cost(&mut report),
        None => {}
    }
    if only.is_some() {
        println!("{}", serde_json::Value::Object(report));
        return;
    }
    loop_cost(&mut report);
    batch_cost(&mut report);
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

    cancellation_cost(&mut report);
    adaptive_cost(&mut report);

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
            condition: Default::default(),
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
