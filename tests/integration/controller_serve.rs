//! `bdft-controller serve` as the server uses it: real process, real socket, real protocol.

use bdft_controller::closed_loop::LoopSetup;
use bdft_controller::compensator::default_spec;
use bdft_controller::rng::Rng;
use bdft_controller::simulate::{SignalKind, SimConfig, simulate};
use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::link_auth::{Bytes32, LinkRole};
use bdft_protocol::params::{
    BodyModel, CompensatorKind, LoopParams, OperatorParams, PlantParams, Seat, StepParams,
};
use bdft_protocol::rig::{RigCommand, RigState};
use bdft_protocol::server_to_controller::{ServerToController, StartTrial};
use bdft_protocol::trial::{FaultKind, InputSource, Outcome, RECORD_CHANNELS, TargetSpec};
use bdft_tests::controller_link::{Link, Proc, TrialLog};

/// The StartTrial that reproduces `simulate` with these settings (same target, same noise,
/// same synthetic operator seeds).
pub(crate) fn synthetic_trial(
    trial_id: u64,
    kind: CompensatorKind,
    seat: Seat,
    k_bf: f64,
    duration_s: f64,
    seed: u64,
) -> StartTrial {
    let plant = PlantParams::default();
    let target = bdft_controller::signals::StepTarget::generate(
        &StepParams::default(),
        duration_s.max(4.0),
        seed,
    )
    .unwrap();
    StartTrial {
        trial_id,
        compensator: default_spec(kind, &plant),
        station: seat,
        k_bf,
        target: TargetSpec::Steps {
            interval_s: target.interval_s,
            levels_mm: target.levels_mm,
        },
        duration_s,
        input: InputSource::Synthetic {
            operator: OperatorParams::default(),
            seed,
        },
        plant,
        body: BodyModel::default(),
        noise_seed: Rng::derive(seed, Rng::ACCEL_NOISE).next_u64(),
        live_rate_hz: 100.0,
        stale_input_ms: 100.0,
        max_cab_rms_mm_s2: bdft_protocol::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2,
    }
}

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

pub(crate) fn server_input_trial(trial_id: u64, duration_s: f64) -> StartTrial {
    StartTrial {
        input: InputSource::Server,
        ..synthetic_trial(
            trial_id,
            CompensatorKind::Lqr,
            Seat::Off,
            0.6,
            duration_s,
            1,
        )
    }
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
    let r = log
        .results
        .iter()
        .find(|r| r.trial_id == 5)
        .expect("faulted");
    assert!(
        matches!(
            r.outcome,
            Outcome::Faulted {
                fault: FaultKind::StaleInput,
                ..
            }
        ),
        "{:?}",
        r.outcome
    );
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
    let r = log
        .results
        .iter()
        .find(|r| r.trial_id == 6)
        .expect("faulted");
    assert!(matches!(
        r.outcome,
        Outcome::Faulted {
            fault: FaultKind::StaleInput,
            ..
        }
    ));
}

#[test]
fn estop_stops_everything_and_latches_until_reset() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::connect(&ctl);
    let mut log = TrialLog::default();
    link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        1,
        CompensatorKind::Lqr,
        Seat::On,
        0.6,
        10.0,
        1,
    ))));
    link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        2,
        CompensatorKind::PidNotch,
        Seat::On,
        0.6,
        10.0,
        2,
    ))));
    link.step(100, &mut log);
    link.send(&ServerToController::EStop {});
    link.step(1, &mut log);
    for id in [1, 2] {
        let r = log
            .results
            .iter()
            .find(|r| r.trial_id == id)
            .expect("stopped");
        assert!(matches!(
            r.outcome,
            Outcome::Faulted {
                fault: FaultKind::EStop,
                ..
            }
        ));
        assert!(r.metrics.ticks <= 101);
    }
    assert!(log.faults.iter().any(|f| matches!(
        f,
        ControllerToServer::Fault {
            kind: FaultKind::EStop,
            trial_id: None,
            ..
        }
    )));
    // Latched: a new trial is refused until the reset.
    link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        3,
        CompensatorKind::Lqr,
        Seat::On,
        0.6,
        1.0,
        3,
    ))));
    link.step(1, &mut log);
    assert!(
        log.rejected.iter().any(|r| r.contains("e-stop")),
        "{:?}",
        log.rejected
    );
    link.send(&ServerToController::ResetEStop {});
    match link.recv() {
        ControllerToServer::Status(s) => assert!(!s.estop_latched),
        other => panic!("{other:?}"),
    }
    link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        3,
        CompensatorKind::Lqr,
        Seat::On,
        0.6,
        0.5,
        3,
    ))));
    link.step(600, &mut log);
    let r = log
        .results
        .iter()
        .find(|r| r.trial_id == 3)
        .expect("ran after reset");
    assert_eq!(r.outcome, Outcome::Complete);
}

#[test]
fn bad_messages_are_rejected_counted_and_never_reach_the_valve() {
    let ctl = Proc::controller(&["--lockstep"]);
    // A client that does not say hello first is turned away.
    let mut rude = Link::raw(ctl.addr);
    rude.challenge();
    rude.send(&ServerToController::Status {});
    assert!(matches!(
        rude.try_recv(),
        Some(ControllerToServer::Rejected { .. })
    ));
    assert!(rude.try_recv().is_none(), "closed after the refusal");
    // So is a client of another protocol version.
    let mut old = Link::raw(ctl.addr);
    let challenge = old.challenge();
    let nonce = Bytes32([5; 32]);
    old.send(&ServerToController::Hello {
        protocol_version: 999,
        client: "old".into(),
        role: LinkRole::Control,
        nonce,
        proof: ctl.key.server_proof(LinkRole::Control, &challenge, &nonce),
    });
    match old.try_recv() {
        Some(ControllerToServer::Rejected { reason, .. }) => {
            assert!(reason.contains("999"), "{reason}")
        }
        other => panic!("{other:?}"),
    }

    let (mut link, _) = Link::connect(&ctl);
    let mut log = TrialLog::default();
    // Malformed JSON in a valid frame: rejected, the link stays usable.
    link.send_json(r#"{"type":"launch_missiles"}"#);
    assert!(matches!(link.recv(), ControllerToServer::Rejected { .. }));
    // Out-of-range parameters: the reason names the field.
    let mut bad = server_input_trial(9, 1.0);
    bad.k_bf = 50.0;
    link.send(&ServerToController::StartTrial(Box::new(bad.clone())));
    match link.recv() {
        ControllerToServer::Rejected { reason, .. } => assert!(
            reason.contains("k_bf") && reason.contains("[0, 20]"),
            "{reason}"
        ),
        other => panic!("{other:?}"),
    }
    // Infinity is not JSON either (it goes out as null) and is refused.
    bad.k_bf = f64::INFINITY;
    link.send(&ServerToController::StartTrial(Box::new(bad)));
    assert!(matches!(link.recv(), ControllerToServer::Rejected { .. }));
    let mut bad = server_input_trial(9, 1.0);
    bad.target = TargetSpec::Steps {
        interval_s: 2.0,
        levels_mm: vec![5.0, f64::NAN],
    };
    // NaN is not JSON: serde_json writes null, which must not deserialize into a level.
    link.send(&ServerToController::StartTrial(Box::new(bad)));
    assert!(matches!(link.recv(), ControllerToServer::Rejected { .. }));

    // A running trial fed wild input: non-finite and huge positions are dropped and counted;
    // the last good position keeps driving, and every valve command stays saturated.
    link.send(&ServerToController::StartTrial(Box::new(
        server_input_trial(10, 0.2),
    )));
    for (seq, p) in [(1, 5.0), (2, f64::NAN), (3, 1e9), (4, -1e300)] {
        link.send(&ServerToController::OperatorInput {
            trial_id: 10,
            seq,
            position_mm: p,
        });
    }
    link.send(&ServerToController::OperatorInput {
        trial_id: 999,
        seq: 1,
        position_mm: 1.0,
    });
    link.step(50, &mut log);
    for seq in 5..20 {
        link.send(&ServerToController::OperatorInput {
            trial_id: 10,
            seq,
            position_mm: 5.0,
        });
        link.step(10, &mut log);
    }
    let r = log
        .results
        .iter()
        .find(|r| r.trial_id == 10)
        .expect("result");
    assert_eq!(r.outcome, Outcome::Complete);
    let rec = log.record(10);
    assert!(
        rec[1].iter().all(|h| *h == 0.0 || *h == 5.0),
        "only the good position was used"
    );
    assert!(rec[4].iter().all(|v| v.is_finite() && v.abs() <= 10.0));
    // Step is refused outside lockstep? Here we are in lockstep, so check the status counts.
    link.send(&ServerToController::Status {});
    let status = loop {
        match link.recv() {
            ControllerToServer::Status(s) => break s,
            other => log.add(other),
        }
    };
    assert!(status.rejected_messages >= 6, "{status:?}");
    assert!(status.running_trials.is_empty());
}

#[test]
fn a_message_without_fields_refuses_unknown_fields() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::connect(&ctl);
    // docs/protocol.md: unknown fields are refused, also beside a message that has none.
    for text in [
        r#"{"type":"status","x":1}"#,
        r#"{"type":"e_stop","now":true}"#,
        r#"{"type":"reset_e_stop","x":null}"#,
    ] {
        link.send_json(text);
        match link.recv() {
            ControllerToServer::Rejected { trial_id, reason } => {
                assert_eq!(trial_id, None);
                assert!(reason.contains("unknown field"), "{text}: {reason}");
            }
            other => panic!("{text} was answered with {other:?}"),
        }
    }
    // None of them acted (no e-stop latched), and the link is still up: the same message
    // without the stray field is answered.
    link.send_json(r#"{"type":"status"}"#);
    match link.recv() {
        ControllerToServer::Status(s) => {
            assert!(!s.estop_latched, "the refused e_stop did nothing");
            assert_eq!(s.rejected_messages, 3);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_lost_server_link_stops_trials_and_the_controller_accepts_a_new_one() {
    let ctl = Proc::controller(&["--link-timeout-ms", "300"]);
    let (mut link, _) = Link::connect(&ctl);
    let mut log = TrialLog::default();
    link.start_and_wait(synthetic_trial(
        1,
        CompensatorKind::Lqr,
        Seat::On,
        0.6,
        60.0,
        1,
    ));
    // While one server is connected, another is turned away.
    match Link::hello(&ctl).1 {
        ControllerToServer::Rejected { reason, .. } => {
            assert!(reason.contains("another server"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
    drop(link);
    // A new connection after the loss finds no trial running and can run a new one.
    let (mut link, _) = loop {
        // Hello only: the latch stays as the first server left it (cleared).
        let (mut l, ack) = Link::hello(&ctl);
        if matches!(ack, ControllerToServer::HelloAck { .. }) {
            break (l, ack);
        }
        // The controller may not have noticed the close yet; it refused us as "another".
        assert!(l.try_recv().is_none());
    };
    let status = loop {
        link.send(&ServerToController::Status {});
        match link.recv() {
            ControllerToServer::Status(s) if s.running_trials.is_empty() => break s,
            ControllerToServer::Status(_) => continue,
            other => log.add(other),
        }
    };
    assert!(!status.estop_latched);
    link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        2,
        CompensatorKind::PidNotch,
        Seat::On,
        0.6,
        0.3,
        2,
    ))));
    let r = link.until_result(2, &mut log);
    assert_eq!(r.outcome, Outcome::Complete);
    assert!(
        r.timing.wake_latency_us.max > 0.0,
        "real-time mode measures wake latency"
    );
    // Silence longer than the link timeout also counts as a lost link.
    link.start_and_wait(synthetic_trial(
        3,
        CompensatorKind::Lqr,
        Seat::On,
        0.6,
        60.0,
        3,
    ));
    // Keep reading without sending: the controller must drop us within the timeout.
    let closed = loop {
        match link.try_recv() {
            None => break true,
            Some(_) => continue,
        }
    };
    assert!(closed);
    let (mut link, _) = Link::connect(&ctl);
    link.send(&ServerToController::Status {});
    let running = loop {
        match link.recv() {
            ControllerToServer::Status(s) => break s.running_trials,
            _ => continue,
        }
    };
    assert!(running.is_empty(), "{running:?}");
}

#[test]
fn a_trial_runs_on_a_rig_over_udp_and_a_silent_rig_is_a_fault() {
    let mut rig = Proc::rig_sim();
    let rig_addr = rig.addr.to_string();
    let ctl = Proc::controller(&["--rig", "udp", "--rig-addr", &rig_addr]);
    let (mut link, ack) = Link::connect(&ctl);
    assert!(
        matches!(&ack, ControllerToServer::HelloAck { rig, .. } if rig == "udp"),
        "{ack:?}"
    );
    let mut log = TrialLog::default();
    // A 3 s bench trapezoid straight into the cylinder reference.
    let bench = StartTrial {
        target: TargetSpec::Trapezoid {
            amplitude_mm: 25.0,
            period_s: 6.0,
        },
        input: InputSource::Reference,
        ..synthetic_trial(1, CompensatorKind::PidNotch, Seat::Off, 0.6, 3.0, 1)
    };
    link.send(&ServerToController::StartTrial(Box::new(bench.clone())));
    let r = link.until_result(1, &mut log);
    assert_eq!(r.outcome, Outcome::Complete, "{:?}", log.faults);
    // The rig's model tracked the trapezoid: an error of a few mm, as offline.
    assert!(
        r.metrics.mse_tracking_mm2 < 20.0,
        "{}",
        r.metrics.mse_tracking_mm2
    );
    let rec = log.record(1);
    let y_max = rec[5].iter().fold(0f32, |m, v| m.max(v.abs()));
    assert!(y_max > 15.0, "the rig's cylinder moved ({y_max} mm)");
    // A second rig trial while one runs is refused (one machine).
    link.send(&ServerToController::StartTrial(Box::new(StartTrial {
        trial_id: 2,
        duration_s: 30.0,
        ..bench.clone()
    })));
    link.send(&ServerToController::StartTrial(Box::new(StartTrial {
        trial_id: 3,
        duration_s: 30.0,
        ..bench
    })));
    loop {
        match link.recv() {
            ControllerToServer::Rejected { reason, .. } => {
                assert!(reason.contains("rig is in use"), "{reason}");
                break;
            }
            other => log.add(other),
        }
    }
    // The rig dies mid-trial: the trial faults instead of hanging.
    rig.kill();
    let r = link.until_result(2, &mut log);
    assert!(
        matches!(
            r.outcome,
            Outcome::Faulted {
                fault: FaultKind::RigTimeout,
                ..
            }
        ),
        "{:?}",
        r.outcome
    );
}

#[test]
fn operator_input_arrives_over_udp_from_a_haptic_host() {
    let ctl = Proc::controller(&["--input-udp", "127.0.0.1:0"]);
    let input = ctl.input_udp.expect("input port announced");
    let (mut link, _) = Link::connect(&ctl);
    let mut log = TrialLog::default();
    let st = StartTrial {
        input: InputSource::Udp { channel: 4 },
        ..server_input_trial(1, 1.0)
    };
    link.start_and_wait(st);
    let host = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    // A haptic host streams at 1 kHz; a malformed datagram and a wrong channel in between.
    host.send_to(b"garbage", input).unwrap();
    let writer = std::thread::spawn(move || {
        for seq in 1..=1500u32 {
            let d = bdft_protocol::rig::InputDatagram {
                channel: 4,
                seq,
                position_mm: 8.0,
            };
            let _ = host.send_to(&d.encode(), input);
            let other = bdft_protocol::rig::InputDatagram {
                channel: 5,
                seq,
                position_mm: 99.0,
            };
            if seq % 100 == 0 {
                let _ = host.send_to(&other.encode(), input);
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    });
    let r = link.until_result(1, &mut log);
    writer.join().unwrap();
    assert_eq!(r.outcome, Outcome::Complete, "{:?}", log.faults);
    let rec = log.record(1);
    assert!(
        rec[1].iter().skip(100).all(|h| *h == 8.0),
        "the host's position drove the trial"
    );
    assert!(log.live.iter().any(|s| s.input_seq > 100));
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

#[test]
fn a_controller_starts_with_the_estop_latched_until_a_server_clears_it() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::hello(&ctl);
    link.send(&ServerToController::Status {});
    let ControllerToServer::Status(status) = link.recv() else {
        panic!("status expected")
    };
    assert!(status.estop_latched, "a fresh controller is latched");
    link.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        1,
        CompensatorKind::Lqr,
        Seat::On,
        0.6,
        1.0,
        1,
    ))));
    match link.recv() {
        ControllerToServer::Rejected {
            trial_id: Some(1),
            reason,
        } => {
            assert!(reason.contains("e-stop is latched"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
    link.send(&ServerToController::ResetEStop {});
    let ControllerToServer::Status(status) = link.recv() else {
        panic!("status expected")
    };
    assert!(!status.estop_latched);
    link.start_and_wait(synthetic_trial(
        2,
        CompensatorKind::Lqr,
        Seat::On,
        0.6,
        1.0,
        1,
    ));
}

#[test]
fn spoofed_and_replayed_input_datagrams_never_keep_a_trial_alive() {
    let ctl = Proc::controller(&["--lockstep", "--input-udp", "127.0.0.1:0"]);
    let input = ctl.input_udp.expect("input port announced");
    let (mut link, _) = Link::connect(&ctl);
    let mut log = TrialLog::default();
    link.start_and_wait(StartTrial {
        input: InputSource::Udp { channel: 4 },
        ..server_input_trial(1, 10.0)
    });
    let datagram = |seq| {
        bdft_protocol::rig::InputDatagram {
            channel: 4,
            seq,
            position_mm: 8.0,
        }
        .encode()
    };
    let host = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let intruder = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    // The host's first datagram pins it as the trial's source; wait until the loop uses it.
    host.send_to(&datagram(1), input).unwrap();
    for _ in 0..200 {
        if log.live.iter().any(|s| s.trial_id == 1 && s.input_seq == 1) {
            break;
        }
        // Re-sending the same datagram is a replay: it is refused but harmless here.
        host.send_to(&datagram(1), input).unwrap();
        link.step(10, &mut log);
    }
    assert!(
        log.live.iter().any(|s| s.input_seq == 1),
        "the host's input reached the loop"
    );
    // The host goes silent; a replay of its last datagram and an intruder with a newer
    // sequence arrive before every 10 ticks. Neither counts: the input goes stale.
    for seq in 2..60u32 {
        host.send_to(&datagram(1), input).unwrap();
        intruder.send_to(&datagram(seq), input).unwrap();
        link.step(10, &mut log);
        if log.results.iter().any(|r| r.trial_id == 1) {
            break;
        }
    }
    let r = log
        .results
        .iter()
        .find(|r| r.trial_id == 1)
        .expect("the trial ended");
    assert!(
        matches!(
            r.outcome,
            Outcome::Faulted {
                fault: FaultKind::StaleInput,
                ..
            }
        ),
        "{:?}",
        r.outcome
    );
    assert!(
        log.live.iter().all(|s| s.input_seq <= 1),
        "no foreign sequence was used"
    );
    link.send(&ServerToController::Status {});
    let status = loop {
        if let ControllerToServer::Status(s) = link.recv() {
            break s;
        }
    };
    assert!(status.rejected_datagrams >= 10, "{status:?}");
}

/// What a lying rig makes of an honest reply.
type Lie = fn(RigState) -> RigState;

/// A rig that answers every command like `rig-sim` at rest, except that after `good`
/// commands it sends what `lie` makes of the reply.
fn lying_rig(good: u32, lie: Lie) -> std::net::SocketAddr {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = socket.local_addr().unwrap();
    std::thread::spawn(move || {
        let mut buf = [0u8; 64];
        let mut n = 0u32;
        while let Ok((len, from)) = socket.recv_from(&mut buf) {
            let Ok(cmd) = RigCommand::decode(&buf[..len]) else {
                continue;
            };
            n += 1;
            let honest = RigState {
                seq: cmd.seq,
                cylinder_mm: 0.5,
                cab_accel_mm_s2: 10.0,
            };
            let reply = if n > good { lie(honest) } else { honest };
            let _ = socket.send_to(&reply.encode(), from);
        }
    });
    addr
}

#[test]
fn implausible_rig_readings_fault_the_trial_with_the_reason() {
    let lies: [(Lie, &str); 4] = [
        (
            |s| RigState {
                cylinder_mm: 1e300,
                ..s
            },
            "beyond the stroke",
        ),
        (
            |s| RigState {
                cab_accel_mm_s2: -2e5,
                ..s
            },
            "beyond the plausible",
        ),
        (
            |s| RigState {
                cylinder_mm: f64::NAN,
                ..s
            },
            "not a finite number",
        ),
        (
            |s| RigState {
                seq: s.seq + 5000,
                ..s
            },
            "never sent",
        ),
    ];
    for (lie, words) in lies {
        let rig = lying_rig(300, lie);
        let ctl = Proc::controller(&["--rig", "udp", "--rig-addr", &rig.to_string()]);
        let (mut link, _) = Link::connect(&ctl);
        let mut log = TrialLog::default();
        link.start_and_wait(StartTrial {
            target: TargetSpec::Trapezoid {
                amplitude_mm: 5.0,
                period_s: 6.0,
            },
            input: InputSource::Reference,
            ..synthetic_trial(1, CompensatorKind::PidNotch, Seat::Off, 0.6, 10.0, 1)
        });
        let r = link.until_result(1, &mut log);
        let Outcome::Faulted {
            fault: FaultKind::RigImplausible,
            message,
        } = &r.outcome
        else {
            panic!("{words}: {:?}", r.outcome)
        };
        assert!(message.contains(words), "{message}");
        // Stopped at the first lie, long before the 10 s trial would end.
        assert!(r.metrics.ticks < 2000, "{words}: {} ticks", r.metrics.ticks);
    }
}
