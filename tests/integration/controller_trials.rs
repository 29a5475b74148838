//! Trials in the real `bdft-controller serve` process: several at once reproduce the offline
//! simulation bit for bit, and the faults that end one early — stale operator input, the
//! cab-vibration interlock.

use bdft_controller::closed_loop::LoopSetup;
use bdft_controller::compensator::default_spec;
use bdft_controller::simulate::{SignalKind, SimConfig, simulate};
use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::params::{
    BodyModel, CompensatorKind, LoopParams, OperatorParams, PlantParams, Seat, StepParams,
};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::{FaultKind, Outcome, RECORD_CHANNELS};
use bdft_tests::controller_link::{Link, Proc, TrialLog};

use super::controller_starts::{server_input_trial, synthetic_trial};

fn offline(
    kind: CompensatorKind,
    seat: Seat,
    k_bf: f64,
    duration_s: f64,
    seed: u64,
) -> bdft_controller::simulate::SimSummary {
    let plant = PlantParams::default();
    let cfg = SimConfig {
        setup: LoopSetup {
            compensator: default_spec(kind, &plant),
            plant,
            body: BodyModel::default(),
            loop_params: LoopParams {
                k_bf,
                ..LoopParams::default()
            },
            seat,
        },
        signal: SignalKind::Steps,
        duration_s,
        seed,
        operator: OperatorParams::default(),
        steps: StepParams::default(),
        max_cab_rms_mm_s2: None,
        condition: Default::default(),
    };
    simulate(&cfg, |_| {}).unwrap()
}

#[test]
fn lockstep_trials_reproduce_the_offline_simulation_exactly() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, ack) = Link::connect(&ctl);
    assert!(
        matches!(ack, ControllerToServer::HelloAck { lockstep: true, .. }),
        "{ack:?}"
    );
    // Three stations at once, each with its own plant and compensator.
    let trials = [
        (1, CompensatorKind::LqrCabvel, Seat::On, 0.78, 11),
        (2, CompensatorKind::PidShaper, Seat::On, 0.6, 12),
        (3, CompensatorKind::Pid, Seat::Off, 0.6, 13),
    ];
    let duration = 6.0;
    for &(id, kind, station, k_bf, seed) in &trials {
        link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
            id, kind, station, k_bf, duration, seed,
        ))));
    }
    let mut log = TrialLog::default();
    for _ in 0..7 {
        link.step(1000, &mut log);
    }
    assert!(log.rejected.is_empty(), "{:?}", log.rejected);
    assert_eq!(log.started.len(), 3);
    for &(id, kind, station, k_bf, seed) in &trials {
        let r = log
            .results
            .iter()
            .find(|r| r.trial_id == id)
            .expect("result");
        assert_eq!(r.outcome, Outcome::Complete);
        let want = offline(kind, station, k_bf, duration, seed);
        assert_eq!(r.metrics.ticks, want.ticks);
        // Same code, same seeds: bit-identical metrics.
        assert_eq!(r.metrics.mse_tracking_mm2, want.mse_tracking_mm2, "{kind}");
        assert_eq!(r.metrics.ms_cab_accel, want.ms_cab_accel, "{kind}");
        // The full record arrived: every channel, every tick, and it reproduces the metric.
        let rec = log.record(id);
        assert_eq!(rec.len(), RECORD_CHANNELS.len());
        assert!(rec.iter().all(|c| c.len() as u64 == want.ticks));
        let (t, y) = (&rec[0], &rec[5]);
        let mse: f64 = t
            .iter()
            .zip(y)
            .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
            .sum::<f64>()
            / t.len() as f64;
        assert!(
            (mse / want.mse_tracking_mm2 - 1.0).abs() < 1e-4,
            "{mse} vs {}",
            want.mse_tracking_mm2
        );
        assert!(
            rec[4].iter().all(|v| v.abs() <= 10.0),
            "valve commands saturated"
        );
        // Live samples at ~100 Hz.
        let live = log.live.iter().filter(|s| s.trial_id == id).count();
        assert!((590..=600).contains(&live), "{live} live samples");
        assert_eq!(r.timing.ticks, want.ticks);
    }
}

#[test]
fn stale_operator_input_stops_the_trial_with_a_fault() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::connect(&ctl);
    link.send(&ServerToController::StartTrial(Box::new(
        server_input_trial(5, 10.0),
    )));
    let mut log = TrialLog::default();
    // 300 ticks with fresh input every 10 ticks: the trial runs and echoes our sequence.
    for seq in 1..=30u64 {
        link.send(&ServerToController::OperatorInput {
            trial_id: 5,
            seq,
            position_mm: 10.0,
        });
        link.step(10, &mut log);
    }
    assert!(log.results.is_empty(), "ended early: {:?}", log.results);
    assert!(log.live.iter().any(|s| s.input_seq == 30));
    // Then silence: the trial must fault once the last input is older than 100 ms.
    link.step(200, &mut log);
    let r = log.assert_faulted(5, FaultKind::StaleInput);
    // The last input arrived before tick 290; the trial ran until it was 100 ticks old.
    let ticks = r.metrics.ticks;
    assert!((385..=392).contains(&ticks), "stopped after {ticks} ticks");
    assert!(log.faults.iter().any(|f| matches!(
        f,
        ControllerToServer::Fault {
            kind: FaultKind::StaleInput,
            trial_id: Some(5),
            ..
        }
    )));
    // No input from the start at all also faults, after the same grace.
    link.send(&ServerToController::StartTrial(Box::new(
        server_input_trial(6, 10.0),
    )));
    link.step(150, &mut log);
    log.assert_faulted(6, FaultKind::StaleInput);
}

#[test]
fn the_vibration_interlock_stops_the_bench_pid_on_the_machine_in_the_real_process() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::connect(&ctl);
    // Ziegler–Nichols PID, on the machine at the study's K_BF: a limit cycle.
    link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        9,
        CompensatorKind::Pid,
        Seat::On,
        0.78,
        30.0,
        3,
    ))));
    let mut log = TrialLog::default();
    let r = run_to_result(&mut link, 9, &mut log);
    let Outcome::Faulted {
        fault: FaultKind::CabVibration,
        message,
    } = &r.outcome
    else {
        panic!("{:?}", r.outcome)
    };
    assert!(
        message.contains("mm/s² RMS") && message.contains("6000"),
        "{message}"
    );
    assert!(
        r.metrics.ticks < 20_000,
        "stopped after {} ticks",
        r.metrics.ticks
    );
    // The valve got no command after the trip: the record ends at the tick that tripped.
    let record = log.record(9);
    assert_eq!(record[0].len() as u64, r.metrics.ticks);
    // The study's slow PI on the machine runs to the end.
    let mut slow = synthetic_trial(10, CompensatorKind::Pid, Seat::On, 0.78, 10.0, 3);
    slow.compensator = bdft_controller::compensator::study_spec(CompensatorKind::Pid, &slow.plant);
    link.send(&ServerToController::StartTrial(Box::new(slow)));
    let r = run_to_result(&mut link, 10, &mut log);
    assert_eq!(r.outcome, Outcome::Complete);
}

/// Steps a lockstep controller until `trial_id` has its result.
fn run_to_result(
    link: &mut Link,
    trial_id: u64,
    log: &mut TrialLog,
) -> bdft_protocol::controller_to_server::TrialResult {
    for _ in 0..200 {
        if let Some(r) = log.results.iter().find(|r| r.trial_id == trial_id) {
            return r.clone();
        }
        link.step(500, log);
    }
    panic!("trial {trial_id} has no result after 100,000 ticks");
}

/// Power of `x` (sampled at 1 kHz) in [lo, hi] Hz: its DFT's squared magnitudes there.
fn band_power(x: &[f64], lo: f64, hi: f64) -> f64 {
    let n = x.len();
    let df = 1000.0 / n as f64;
    ((lo / df).ceil() as usize..=(hi / df).floor() as usize)
        .map(|k| {
            let w = std::f64::consts::TAU * k as f64 / n as f64;
            let (re, im) = x.iter().enumerate().fold((0.0, 0.0), |(re, im), (i, v)| {
                let a = w * i as f64;
                (re + v * a.cos(), im - v * a.sin())
            });
            re * re + im * im
        })
        .sum()
}

/// Model-based cancellation in the real process (issue 38): a rider on the machine under
/// the study's LQR, the test cancelling with the rider's own body — the feedthrough left in
/// the cylinder reference (r_c/K_BF less the intended hand, from the stored record's
/// channels) carries under a tenth of the feedthrough's power in 0.5–5 Hz (1.5 % when
/// written). The same test at the desk is refused naming it (the identification test's
/// refusal: the protocol's golden tests). One whose guard's bound is too tight completes,
/// uncancelled from the tick the guard tripped, and its result says when.
#[test]
fn a_cancelling_test_leaves_a_tenth_of_the_riders_feedthrough_in_the_reference() {
    use bdft_protocol::cancellation::CancellationModel;
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::connect(&ctl);
    // A rider a little more coupled than the population's median, cancelled with their own
    // body.
    let body = BodyModel::Seated {
        k_h: 0.6,
        torso_f_hz: 1.1,
        torso_zeta: 0.4,
        arm_f_hz: 2.0,
        arm_zeta: 0.35,
    };
    let model = CancellationModel::of_seated(&body).unwrap();
    let k_bf = 0.78;
    let mut trial = synthetic_trial(1, CompensatorKind::Lqr, Seat::On, k_bf, 20.0, 5);
    trial.body = body;
    trial.cancellation = Some(model);
    let mut desk = synthetic_trial(2, CompensatorKind::Lqr, Seat::Off, k_bf, 20.0, 5);
    desk.cancellation = Some(model);
    // The guard: a bound no prediction stays under turns cancellation off within the test,
    // which goes on uncancelled and reports when.
    let mut bounded = trial.clone();
    bounded.trial_id = 3;
    bounded.cancellation = Some(CancellationModel {
        limit_mm: 0.01,
        ..model
    });
    link.send(&ServerToController::StartTrial(Box::new(trial)));
    link.send(&ServerToController::StartTrial(Box::new(desk)));
    link.send(&ServerToController::StartTrial(Box::new(bounded)));
    let mut log = TrialLog::default();
    let r = run_to_result(&mut link, 1, &mut log);
    assert_eq!(r.outcome, Outcome::Complete);
    assert_eq!(r.cancellation_off_at_s, None);
    let off = run_to_result(&mut link, 3, &mut log);
    assert_eq!(off.outcome, Outcome::Complete);
    let at = off.cancellation_off_at_s.expect("the guard tripped");
    assert!(at > 0.0 && at < 20.0, "{at}");
    assert_eq!(log.rejected.len(), 1, "{:?}", log.rejected);
    assert!(
        log.rejected[0].contains("cancellation: at the desk no body rides"),
        "{:?}",
        log.rejected
    );
    let rec = log.record(1);
    let channel = |name: &str| -> Vec<f64> {
        let i = RECORD_CHANNELS.iter().position(|c| c.name == name).unwrap();
        rec[i].iter().map(|v| f64::from(*v)).collect()
    };
    let (hand, feedthrough, r_c) = (
        channel("hand_mm"),
        channel("feedthrough_mm"),
        channel("cyl_ref_mm"),
    );
    let left: Vec<f64> = r_c.iter().zip(&hand).map(|(r, p)| r / k_bf - p).collect();
    let shaken: Vec<f64> = feedthrough.iter().map(|h| -h).collect();
    let share = band_power(&left, 0.5, 5.0) / band_power(&shaken, 0.5, 5.0);
    assert!(share < 0.1, "{share} of the feedthrough's power left");
}
