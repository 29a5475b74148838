//! Speed of the identification's analysis: estimation and fit (with the jackknife over the
//! record's periods, as the server's filing runs it) of one subject's default test (70 s at
//! 1 kHz), run with `cargo bench -p bdft-controller --bench identify`.
//!
//! The records are simulated first (not timed): subjects of the default population holding
//! still on the simulated rig. Medians over repeated runs: the machines are shared. Then each
//! subject's two LQR designs of the default study tuned to the fitted body
//! (`analysis::personal::personalize`), as a personalized study does when it files the test.

use std::hint::black_box;
use std::time::Instant;

use bdft_controller::analysis::personal::personalize;
use bdft_controller::closed_loop::LoopSetup;
use bdft_controller::compensator::{study_spec, variants};
use bdft_controller::identification::{BodyPrior, estimate, fit_record};
use bdft_controller::population;
use bdft_controller::runtime::setup::build_runner;
use bdft_protocol::identification::{IdentificationTask, MultisineSpec};
use bdft_protocol::params::{
    BodyModel, CompensatorKind, LoopParams, PlantParams, PopulationParams, Seat,
};
use bdft_protocol::server_to_controller::{DEFAULT_MAX_CAB_RMS_MM_S2, StartTrial};
use bdft_protocol::trial::{InputSource, TargetSpec};

const RUNS: usize = 9;
const SUBJECTS: u64 = 5;
/// The default study's K_BF and the stability gate's margin over it (the server's
/// `STUDY_KBF` and `stability::MARGIN`).
const STUDY_KBF: f64 = 0.78;
const MARGIN: f64 = 1.5;

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

/// Subject `i`'s record: (cab acceleration, device), as the controller stores them.
fn record(i: u64, spec: MultisineSpec) -> (Vec<f32>, Vec<f32>) {
    let dt = LoopParams::default().dt;
    let plant = PlantParams::default();
    let draw = population::draw(&PopulationParams::default(), 1000 + i);
    let st = StartTrial {
        trial_id: 1,
        compensator: variants::variant("pid", &plant, dt).unwrap(),
        seat: Seat::On,
        k_bf: 0.6,
        target: TargetSpec::Identification {
            excitation: spec,
            task: IdentificationTask::HoldStill,
        },
        duration_s: spec.duration_s(),
        input: InputSource::Synthetic {
            operator: population::operator(&draw, 0, 0.0),
            seed: i,
        },
        plant,
        body: population::body(&draw, BodyModel::default()),
        noise_seed: i,
        live_rate_hz: 100.0,
        stale_input_ms: 100.0,
        max_cab_rms_mm_s2: DEFAULT_MAX_CAB_RMS_MM_S2,
        exposure_allowance: None,
        cancellation: None,
        condition: Default::default(),
    };
    let (mut runner, _) = build_runner(&st, dt, false).unwrap();
    let (mut u, mut y) = (vec![], vec![]);
    while !runner.done() {
        let s = runner.tick(0.0);
        u.push(s.cab_accel as f32);
        y.push(s.device() as f32);
    }
    (u, y)
}

fn main() {
    let dt = LoopParams::default().dt;
    let spec = MultisineSpec::default();
    let records: Vec<_> = (0..SUBJECTS).map(|i| record(i, spec)).collect();
    let prior = BodyPrior::of(&PopulationParams::default());
    let (mut est_ms, mut fit_ms, mut total_ms) = (vec![], vec![], vec![]);
    for _ in 0..RUNS {
        for (u, y) in &records {
            let t0 = Instant::now();
            let points = estimate(&spec, dt, black_box(u), black_box(y)).unwrap();
            let t1 = Instant::now();
            // What the server's filing runs: the fit with the jackknife over the record and
            // the population's prior.
            black_box(fit_record(&points, &spec, dt, u, y, prior.as_ref()).unwrap());
            let t2 = Instant::now();
            est_ms.push((t1 - t0).as_secs_f64() * 1e3);
            fit_ms.push((t2 - t1).as_secs_f64() * 1e3);
            total_ms.push((t2 - t0).as_secs_f64() * 1e3);
        }
    }
    println!(
        "identification of one subject's default test ({} ticks, {} lines), median over {} runs:",
        records[0].0.len(),
        spec.lines,
        RUNS * SUBJECTS as usize
    );
    println!("  estimate  {:8.2} ms", median(est_ms));
    println!("  fit       {:8.2} ms", median(fit_ms));
    println!("  total     {:8.2} ms (goal ≤ 1000 ms)", median(total_ms));

    let plant = PlantParams::default();
    println!("a design tuned to each subject's fitted body, median over {SUBJECTS} subjects:");
    for kind in [CompensatorKind::Lqr, CompensatorKind::LqrCabvel] {
        let mut ms = vec![];
        for (u, y) in &records {
            let points = estimate(&spec, dt, u, y).unwrap();
            let fit = fit_record(&points, &spec, dt, u, y, prior.as_ref()).unwrap();
            let setup = LoopSetup {
                plant,
                body: fit.body(),
                loop_params: LoopParams {
                    k_bf: STUDY_KBF,
                    ..LoopParams::default()
                },
                seat: Seat::On,
                compensator: study_spec(kind, &plant),
            };
            let t0 = Instant::now();
            black_box(personalize(&setup, MARGIN * STUDY_KBF).unwrap());
            ms.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        println!("  {:<10} {:8.1} ms", kind.name(), median(ms));
    }
}
