//! The real controller's one server at a time, and a lost link — closed, or silent past the
//! link timeout — stopping every running trial, after which a new server finds it free.

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::Outcome;
use bdft_tests::controller_link::{Link, Proc, TrialLog};

use super::controller_starts::synthetic_trial;

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
