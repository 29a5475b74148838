//! Operator input from a haptic-device host over UDP (`serve --input-udp`): it drives the
//! trial, and spoofed or replayed datagrams never keep a trial alive.

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::server_to_controller::{ServerToController, StartTrial};
use bdft_protocol::trial::{FaultKind, InputSource, Outcome};
use bdft_tests::controller_link::{Link, Proc, TrialLog};

use super::controller_starts::server_input_trial;

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
    log.assert_faulted(1, FaultKind::StaleInput);
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
