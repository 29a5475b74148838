//! The E-stop on the control link of the real controller: every trial stopped, the latch
//! held until a server resets it, and a controller that starts latched.

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::{FaultKind, Outcome};
use bdft_tests::controller_link::{Link, Proc, TrialLog};

use super::controller_starts::synthetic_trial;

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
        let r = log.assert_faulted(id, FaultKind::EStop);
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
