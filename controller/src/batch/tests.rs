//! The batch against the scalar trial it batches.

use bdft_protocol::params::{BodyModel, CompensatorKind, OperatorParams, PlantParams, Seat};
use bdft_protocol::server_to_controller::{DEFAULT_MAX_CAB_RMS_MM_S2, StartTrial};
use bdft_protocol::trial::{InputSource, Metrics, TargetSpec};

use super::trial::{BatchTrial, Build, run_with};
use super::{LANES, metrics};
use crate::compensator::{default_spec, study_spec};
use crate::runtime::local;

const DT: f64 = 1e-3;

/// Lane `l`'s subject: delays from 0.15 to 0.36 s (rings of different lengths), gains,
/// remnant (none in lane 2), motor noise (none in lane 3), delay added by felt vibration
/// (none in lane 4), shake aversion and grip all different.
fn operator(l: usize) -> OperatorParams {
    let x = l as f64 / (LANES - 1) as f64;
    OperatorParams {
        reaction_delay_s: 0.15 + 0.21 * x,
        neuromuscular_w: 9.0 + 6.0 * x,
        neuromuscular_zeta: 0.3 + 0.4 * x,
        error_gain: 0.1 + 0.5 * x,
        error_integral_gain: 0.2 + 0.6 * (1.0 - x),
        remnant_std_mm: if l == 2 { 0.0 } else { 0.2 + 1.5 * x },
        shake_aversion_per_mm: 0.8 * x,
        grip_stiffening_per_m_s2: 0.05 + 0.6 * x,
        vibration_remnant_per_m_s2: 1.0 - x,
        vibration_slowing_per_m_s2: 2.0 * x,
        vibration_regression_per_m_s2: 4.0 * (1.0 - x),
        // None in lane 4 (a ring without room for it); 0.3 s per m/s² reaches the cap.
        vibration_delay_s_per_m_s2: if l == 4 { 0.0 } else { 0.3 * x + 0.05 },
        motor_noise_mm: if l == 3 { 0.0 } else { 0.1 + 0.4 * x },
    }
}

/// Lane `l`'s body of `kind` (0 rigid, 1 one resonance, 2 seated), its feedthrough gain
/// scaled by `k_scale`.
fn body(kind: usize, l: usize, k_scale: f64) -> BodyModel {
    let x = l as f64 / (LANES - 1) as f64;
    let k_h = (0.3 + 0.5 * x) * k_scale;
    match kind {
        0 => BodyModel::RigidMass { k_h },
        1 => BodyModel::SingleResonance {
            k_h,
            f_hz: 3.0 + 3.0 * x,
            zeta: 0.3 + 0.2 * x,
        },
        _ => BodyModel::Seated {
            k_h,
            torso_f_hz: 0.9 + 0.8 * x,
            torso_zeta: 0.3 + 0.3 * x,
            arm_f_hz: 2.0 + 2.0 * (1.0 - x),
            arm_zeta: 0.25 + 0.2 * x,
        },
    }
}

fn start(l: usize, comp: CompensatorKind, seat: Seat, body: BodyModel, secs: f64) -> StartTrial {
    let plant = PlantParams::default();
    // Lanes 0–2 run out of levels before a 12 s trial ends (the last one holds).
    let levels_mm = (0..3 + l)
        .map(|i| (((i * 7 + l * 13) % 11) as f64 - 5.0) * 6.0)
        .collect();
    StartTrial {
        trial_id: l as u64,
        compensator: study_spec(comp, &plant),
        seat,
        k_bf: 0.78,
        target: TargetSpec::Steps {
            interval_s: 2.0,
            levels_mm,
        },
        duration_s: secs,
        input: InputSource::Synthetic {
            operator: operator(l),
            seed: 100 + l as u64,
        },
        plant,
        body,
        noise_seed: 200 + l as u64,
        live_rate_hz: 100.0,
        stale_input_ms: 100.0,
        max_cab_rms_mm_s2: DEFAULT_MAX_CAB_RMS_MM_S2,
        exposure_allowance: None,
        cancellation: None,
        condition: Default::default(),
    }
}

/// The batch run on the scalar trials' own deviates, and the scalar trials.
fn batch_and_scalar(starts: &[StartTrial]) -> (Vec<Option<Metrics>>, Vec<Option<Metrics>>) {
    let lanes = std::array::from_fn(|l| &starts[l]);
    let (mut batch, mut deviates, _) = BatchTrial::build_scalar(&lanes, DT).unwrap();
    assert!(run_with(Build::widest(), &mut batch, &mut deviates));
    let scalar = starts
        .iter()
        .map(|st| local::metrics(st, DT).unwrap())
        .collect();
    (batch.results().to_vec(), scalar)
}

#[test]
fn on_the_scalar_deviates_a_batch_reproduces_the_scalar_trials_bit_for_bit() {
    let kinds = [
        CompensatorKind::Pid,
        CompensatorKind::PidNotch,
        CompensatorKind::PidShaper,
        CompensatorKind::Lqr,
        CompensatorKind::LqrCabvel,
        CompensatorKind::LqrCabacc,
    ];
    for comp in kinds {
        for seat in [Seat::On, Seat::Off] {
            for body_kind in 0..3 {
                let starts: Vec<StartTrial> = (0..LANES)
                    .map(|l| start(l, comp, seat, body(body_kind, l, 1.0), 12.0))
                    .collect();
                let (batch, scalar) = batch_and_scalar(&starts);
                assert_eq!(
                    batch, scalar,
                    "{comp} at the {seat:?} seat, body {body_kind}"
                );
            }
        }
    }
}

#[test]
fn targets_other_than_steps_are_read_lane_by_lane_and_reproduced_too() {
    let starts: Vec<StartTrial> = (0..LANES)
        .map(|l| {
            let mut st = start(l, CompensatorKind::PidNotch, Seat::On, body(2, l, 1.0), 8.0);
            st.target = TargetSpec::SweptSine {
                amplitude_mm: 10.0 + l as f64,
                f0_hz: 0.1,
                f1_hz: 1.0 + 0.1 * l as f64,
            };
            st
        })
        .collect();
    let (batch, scalar) = batch_and_scalar(&starts);
    assert_eq!(batch, scalar);
}

#[test]
fn lanes_the_interlock_stops_are_reported_stopped_and_the_others_run_on() {
    // Plain LQR on the machine is pushed past its margin by a large feedthrough gain: the
    // lanes with the stiffest bodies trip, the others complete, as in the scalar trials.
    let starts: Vec<StartTrial> = (0..LANES)
        .map(|l| start(l, CompensatorKind::Lqr, Seat::On, body(0, l, 3.0), 20.0))
        .collect();
    let (batch, scalar) = batch_and_scalar(&starts);
    assert_eq!(batch, scalar);
    let stopped = batch.iter().filter(|m| m.is_none()).count();
    assert!(
        stopped > 0 && stopped < LANES,
        "want a mix of stopped and complete lanes: {batch:?}"
    );
    // The bench PID limit-cycles on the machine: every lane stops, and the batch with them.
    let mut starts = starts;
    for st in &mut starts {
        st.compensator = default_spec(CompensatorKind::Pid, &st.plant);
    }
    let (batch, scalar) = batch_and_scalar(&starts);
    assert_eq!(batch, scalar);
    assert!(batch.iter().all(Option::is_none), "{batch:?}");
}

#[test]
fn every_build_this_cpu_runs_gives_the_baseline_s_bits() {
    let starts: Vec<StartTrial> = (0..LANES)
        .map(|l| {
            start(
                l,
                CompensatorKind::LqrCabvel,
                Seat::On,
                body(2, l, 1.0),
                10.0,
            )
        })
        .collect();
    let lanes = std::array::from_fn(|l| &starts[l]);
    let (batch, deviates) = BatchTrial::build(&lanes, DT).unwrap();
    let run = |build: Build| {
        let (mut b, mut d) = (batch.clone(), deviates.clone());
        run_with(build, &mut b, &mut d).then(|| b.results())
    };
    let baseline = run(Build::Baseline).expect("every CPU runs the baseline");
    assert!(baseline.iter().all(Option::is_some));
    for build in Build::ALL {
        match run(build) {
            Some(results) => assert_eq!(results, baseline, "{build:?}"),
            None => assert!(!build.available(), "{build:?}"),
        }
    }
}

#[test]
fn a_trials_result_does_not_depend_on_its_batch_or_place_in_it() {
    let starts: Vec<StartTrial> = (0..LANES + 3)
        .map(|l| {
            start(
                l % LANES,
                CompensatorKind::PidNotch,
                Seat::On,
                body(2, l % LANES, 1.0),
                5.0,
            )
        })
        .enumerate()
        .map(|(i, mut st)| {
            st.noise_seed += 1000 * i as u64;
            st
        })
        .collect();
    let all = metrics(&starts, DT).unwrap();
    assert_eq!(all.len(), starts.len());
    let mut reversed = starts.clone();
    reversed.reverse();
    let mut back = metrics(&reversed, DT).unwrap();
    back.reverse();
    assert_eq!(all, back);
    assert_eq!(metrics(&starts[4..5], DT).unwrap(), vec![all[4]]);
}

#[test]
fn with_its_own_deviates_a_batch_has_the_scalar_trials_distribution() {
    // Same subject, target and design; 32 noise seeds. The batch's own streams are another
    // realization of the same noise, so per seed the metrics differ, but their means agree
    // within the paired differences' standard error.
    let n = 4 * LANES;
    let starts: Vec<StartTrial> = (0..n)
        .map(|i| {
            let mut st = start(
                5,
                CompensatorKind::LqrCabvel,
                Seat::On,
                body(2, 5, 1.0),
                10.0,
            );
            st.noise_seed = 1000 + i as u64;
            st.input = InputSource::Synthetic {
                operator: operator(5),
                seed: 5000 + i as u64,
            };
            st
        })
        .collect();
    let fast = metrics(&starts, DT).unwrap();
    let scalar: Vec<Metrics> = starts
        .iter()
        .map(|st| local::metrics(st, DT).unwrap().unwrap())
        .collect();
    for (name, pick) in [
        (
            "tracking error",
            (|m: &Metrics| m.mse_tracking_mm2) as fn(&Metrics) -> f64,
        ),
        ("cab acceleration", |m: &Metrics| m.ms_cab_accel),
    ] {
        let d: Vec<f64> = fast
            .iter()
            .zip(&scalar)
            .map(|(f, s)| pick(&f.unwrap()) - pick(s))
            .collect();
        let mean = d.iter().sum::<f64>() / n as f64;
        let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
        let level = scalar.iter().map(pick).sum::<f64>() / n as f64;
        assert!(sd > 0.0, "{name}: the batch's noise is not its own");
        assert!(
            mean.abs() < 4.0 * sd / (n as f64).sqrt(),
            "{name}: mean difference {mean} (level {level}, sd {sd})"
        );
    }
}

#[test]
fn a_batch_of_trials_that_differ_in_a_shared_setting_is_refused_by_name() {
    let mut starts: Vec<StartTrial> = (0..LANES)
        .map(|l| start(l, CompensatorKind::Pid, Seat::On, body(2, l, 1.0), 5.0))
        .collect();
    starts[3].seat = Seat::Off;
    let err = metrics(&starts, DT).unwrap_err();
    assert!(err.contains("station") && err.contains("trial 3"), "{err}");
    starts[3].seat = Seat::On;
    starts[5].body = body(0, 5, 1.0);
    let err = metrics(&starts, DT).unwrap_err();
    assert!(err.contains("body model kind"), "{err}");
}
