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
            station: seat,
        },
        signal: SignalKind::Steps,
        duration_s,
        seed,
        operator: OperatorParams::default(),
        steps: StepParams::default(),
        max_cab_rms_mm_s2: None,
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
