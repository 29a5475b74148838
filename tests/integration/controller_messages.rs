//! What the real controller does with messages it must not act on: a missing hello, another
//! protocol version, malformed JSON, out-of-range parameters, wild operator input, stray
//! fields — refused or dropped, counted, and never reaching the valve.

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::link_auth::{Bytes32, LinkRole};
use bdft_protocol::server_to_controller::{LslStation, ServerToController};
use bdft_protocol::trial::{Outcome, TargetSpec};
use bdft_tests::controller_link::{Link, Proc, TrialLog};

use super::controller_starts::server_input_trial;

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
    // LSL is off unless the controller was started with --lsl: its stream is refused (and
    // no LSL socket opened).
    link.send(&ServerToController::LslStation(Box::new(LslStation {
        station_id: 1,
        station: "cab".into(),
        study_id: 1,
        study: "pilot".into(),
        subject: "S001".into(),
        trial_id: Some(9),
    })));
    match link.recv() {
        ControllerToServer::Rejected { reason, .. } => {
            assert!(reason.contains("--lsl"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
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
