//! The real controller on a rig over UDP (`serve --rig udp`): a trial runs on `rig-sim`, one
//! rig trial at a time, and a silent or lying rig faults the trial with the reason.

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::rig::{RigCommand, RigState};
use bdft_protocol::server_to_controller::{ServerToController, StartTrial};
use bdft_protocol::trial::{FaultKind, InputSource, Outcome, TargetSpec};
use bdft_tests::controller_link::{Link, Proc, TrialLog};

use super::controller_starts::synthetic_trial;

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
