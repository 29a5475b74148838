//! Who may talk to the controller, and the E-stop's own connection: real controller and
//! server processes, real sockets.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::link_auth::{Bytes32, LinkKey, LinkRole};
use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::{FaultKind, Outcome};
use bdft_tests::controller_link::{Link, PATIENCE, Proc, TrialLog, input_flood_batch};
use bdft_tests::server::{ADMIN_PASSWORD, Server, eventually};

use super::controller_starts::{server_input_trial, synthetic_trial};

fn refusal(msg: ControllerToServer) -> String {
    match msg {
        ControllerToServer::Rejected { reason, .. } => reason,
        other => panic!("expected a refusal, got {other:?}"),
    }
}

#[test]
fn a_client_without_the_key_runs_nothing() {
    let ctl = Proc::controller(&["--lockstep"]);
    // The wrong key: refused and closed.
    let stranger = LinkKey::generate().unwrap();
    let (mut wrong, answer) = Link::hello_as(ctl.addr, &stranger, LinkRole::Control);
    assert!(
        refusal(answer).contains("authentication failed"),
        "a wrong key is refused"
    );
    assert!(wrong.try_recv().is_none(), "closed after the refusal");

    // No hello at all: any other first message is refused, the connection closed.
    let mut rude = Link::raw(ctl.addr);
    rude.challenge();
    rude.send(&ServerToController::Heartbeat { seq: 1 });
    let why = refusal(rude.recv());
    assert!(why.contains("first message"), "{why}");
    assert!(rude.try_recv().is_none());
    // A start_trial first, which would drive the machine, is larger than anything an
    // unauthenticated peer may send (a whole study's rig and design): refused by its size
    // before it is read, the connection closed.
    let mut rude = Link::raw(ctl.addr);
    rude.challenge();
    rude.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        1,
        CompensatorKind::Pid,
        Seat::On,
        0.6,
        1.0,
        1,
    ))));
    let why = refusal(rude.recv());
    assert!(why.contains("before authentication"), "{why}");
    assert!(rude.try_recv().is_none());

    // A proof made for one connection's challenge does not open another (a recorded
    // handshake is worthless).
    let mut first = Link::raw(ctl.addr);
    let seen = first.challenge();
    let nonce = Bytes32([9; 32]);
    let replayed = ServerToController::Hello {
        protocol_version: bdft_protocol::PROTOCOL_VERSION,
        client: "replay".into(),
        role: LinkRole::Control,
        nonce,
        proof: ctl.key.server_proof(LinkRole::Control, &seen, &nonce),
    };
    let mut second = Link::raw(ctl.addr);
    second.challenge();
    second.send(&replayed);
    assert!(refusal(second.recv()).contains("authentication failed"));
    drop(first);

    // Before authentication a peer cannot make the controller buffer a big frame: the
    // announced length alone ends it.
    let mut greedy = Link::raw(ctl.addr);
    greedy.challenge();
    greedy.send_bytes(&(8u32 << 20).to_be_bytes());
    let reason = refusal(greedy.recv());
    assert!(reason.contains("1024-byte limit"), "{reason}");
    assert!(greedy.try_recv().is_none());

    // None of it started anything: the key holder finds the controller idle and runs.
    let (mut link, _) = Link::connect(&ctl);
    link.send(&ServerToController::Status {});
    match link.recv() {
        ControllerToServer::Status(s) => assert!(s.running_trials.is_empty(), "{s:?}"),
        other => panic!("{other:?}"),
    }
    let mut log = TrialLog::default();
    link.start_and_wait(synthetic_trial(
        2,
        CompensatorKind::Pid,
        Seat::Off,
        0.6,
        0.2,
        2,
    ));
    link.step(300, &mut log);
    assert_eq!(log.results[0].outcome, Outcome::Complete);
}

/// Reads until the peer closes; how many bytes it said before (panics if it stays open
/// for `PATIENCE`).
fn closes(stream: &mut TcpStream) -> usize {
    stream.set_read_timeout(Some(PATIENCE)).unwrap();
    let mut got = Vec::new();
    match stream.read_to_end(&mut got) {
        Ok(_) => got.len(),
        Err(e) => panic!("the controller kept the connection open: {e}"),
    }
}

#[test]
fn unauthenticated_connections_are_capped_and_time_out() {
    let ctl = Proc::controller(&["--lockstep"]);
    // Four silent sockets fill this address's share of the handshake places; each has
    // its challenge.
    let mut silent: Vec<TcpStream> = (0..4)
        .map(|_| {
            let mut s = TcpStream::connect(ctl.addr).unwrap();
            let mut len = [0u8; 4];
            s.set_read_timeout(Some(PATIENCE)).unwrap();
            s.read_exact(&mut len).expect("a challenge");
            let mut body = vec![0u8; u32::from_be_bytes(len) as usize];
            s.read_exact(&mut body).unwrap();
            s
        })
        .collect();
    // The fifth is closed unread and unanswered.
    let mut fifth = TcpStream::connect(ctl.addr).unwrap();
    assert_eq!(closes(&mut fifth), 0, "no challenge beyond the cap");
    // A silent socket loses its place after the handshake timeout (2 s), told why.
    let waited = Instant::now();
    let said = closes(&mut silent[0]);
    assert!(said > 0, "the refusal names the timeout");
    assert!(
        waited.elapsed() < PATIENCE,
        "closed by the controller, not by our read timeout"
    );
    // Places come back: with the silent ones gone, the key holder gets in.
    silent.clear();
    let (_link, ack) = eventually(Duration::from_secs(30), || {
        let (l, ack) = Link::hello(&ctl);
        matches!(ack, ControllerToServer::HelloAck { .. }).then_some((l, ack))
    });
    assert!(matches!(ack, ControllerToServer::HelloAck { .. }));
}

#[test]
fn the_estop_path_stops_every_trial_at_the_next_tick_and_can_do_nothing_else() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::connect(&ctl);
    let mut log = TrialLog::default();
    for (id, kind) in [(1, CompensatorKind::Lqr), (2, CompensatorKind::PidNotch)] {
        link.start_and_wait(synthetic_trial(id, kind, Seat::On, 0.6, 10.0, id));
    }
    link.step(100, &mut log);
    let (mut path, ack) = Link::hello_as(ctl.addr, &ctl.key, LinkRole::EStop);
    assert!(
        matches!(ack, ControllerToServer::HelloAck { .. }),
        "{ack:?}"
    );
    path.send(&ServerToController::EStop {});
    assert!(matches!(
        path.recv(),
        ControllerToServer::Fault {
            trial_id: None,
            kind: FaultKind::EStop,
            ..
        }
    ));
    // Confirmed before the next tick has run: that tick ends every trial.
    link.step(1, &mut log);
    for id in [1, 2] {
        let r = log.assert_faulted(id, FaultKind::EStop);
        assert!(r.metrics.ticks <= 101, "stopped at the next tick");
    }
    // The path can stop the machine, never move it or clear the latch.
    path.send(&ServerToController::ResetEStop {});
    assert!(refusal(path.recv()).contains("only e_stop"));
    path.send(&ServerToController::StartTrial(Box::new(synthetic_trial(
        3,
        CompensatorKind::Pid,
        Seat::On,
        0.6,
        1.0,
        3,
    ))));
    assert!(refusal(path.recv()).contains("only e_stop"));
    path.send(&ServerToController::Status {});
    match path.recv() {
        ControllerToServer::Status(s) => {
            assert!(s.estop_latched, "still latched");
            assert!(s.running_trials.is_empty(), "nothing started: {s:?}");
        }
        other => panic!("{other:?}"),
    }
}

/// The control connection is flooded with operator input as fast as a socket takes it,
/// so an E-stop written there would queue behind megabytes; on its own connection each
/// press is confirmed at once.
#[test]
fn an_estop_overtakes_a_flood_on_the_control_connection() {
    let ctl = Proc::controller(&[]);
    let (mut link, _) = Link::connect(&ctl);
    let mut trial = server_input_trial(1, 120.0);
    trial.stale_input_ms = 10_000.0;
    link.start_and_wait(trial);
    let mut flood_to = link.stream_clone();
    let stop = Arc::new(AtomicBool::new(false));
    let sent = Arc::new(AtomicU64::new(0));
    let flood = {
        let (stop, sent) = (Arc::clone(&stop), Arc::clone(&sent));
        std::thread::spawn(move || {
            let batch = input_flood_batch(1, 1000);
            while !stop.load(Ordering::Relaxed) {
                if flood_to.write_all(&batch).is_err() {
                    break;
                }
                sent.fetch_add(1000, Ordering::Relaxed);
            }
        })
    };
    // The control connection's messages are drained meanwhile, as a server would.
    let draining = std::thread::spawn(move || {
        let mut log = TrialLog::default();
        while let Some(msg) = link.try_recv() {
            log.add(msg);
            if !log.results.is_empty() {
                break;
            }
        }
        log
    });
    eventually(Duration::from_secs(30), || {
        (sent.load(Ordering::Relaxed) >= 200_000).then_some(())
    });
    let (mut path, _) = Link::hello_as(ctl.addr, &ctl.key, LinkRole::EStop);
    let mut took: Vec<Duration> = (0..20)
        .map(|_| {
            let pressed = Instant::now();
            path.send(&ServerToController::EStop {});
            loop {
                if let ControllerToServer::Fault {
                    kind: FaultKind::EStop,
                    ..
                } = path.recv()
                {
                    return pressed.elapsed();
                }
            }
        })
        .collect();
    let during = sent.load(Ordering::Relaxed);
    took.sort();
    let log = draining.join().unwrap();
    stop.store(true, Ordering::Relaxed);
    drop(ctl);
    flood.join().unwrap();
    assert!(
        during >= 200_000,
        "the flood ran throughout ({during} inputs)"
    );
    assert!(
        matches!(
            log.results[0].outcome,
            Outcome::Faulted {
                fault: FaultKind::EStop,
                ..
            }
        ),
        "the running trial was stopped: {:?}",
        log.results[0].outcome
    );
    let median = took[took.len() / 2];
    assert!(
        median <= Duration::from_millis(10),
        "E-stop confirmation median {median:?} (all: {took:?})"
    );
}

/// A remote controller (a real-time PC) runs with a key file; the server needs the same
/// file, and a server with another key is never connected.
#[test]
fn a_remote_controller_serves_only_the_server_with_its_key_file() {
    let dir = bdft_tests::TempDir::new("remote-key");
    let key_file = dir.path().join("link.key");
    let made = bdft_tests::controller(&["keygen", key_file.to_str().unwrap()]);
    assert!(made.status.success(), "{made:?}");
    let other_file = dir.path().join("other.key");
    LinkKey::create_file(&other_file).unwrap();
    let ctl = Proc::spawn(
        "bdft-controller",
        &[
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--key-file",
            key_file.to_str().unwrap(),
        ],
        "listening on ",
    );
    let addr = ctl.addr.to_string();

    let impostor = Server::start_with(
        "remote-impostor",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--controller",
            &addr,
            "--controller-key-file",
            other_file.to_str().unwrap(),
        ],
    );
    let api = impostor.experimenter();
    // Its link attempts fail authentication, and it says so.
    let refused = eventually(Duration::from_secs(30), || {
        let (_, s) = api.get("/api/controller");
        s["down_because"]
            .as_str()
            .is_some_and(|why| why.contains("authentication failed"))
            .then_some(s)
    });
    assert_eq!(refused["connected"], false, "{refused}");
    drop(impostor);

    let server = Server::start_with(
        "remote-key",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--controller",
            &addr,
            "--controller-key-file",
            key_file.to_str().unwrap(),
        ],
    );
    let api = server.experimenter();
    let status = eventually(Duration::from_secs(30), || {
        let (_, s) = api.get("/api/controller");
        (s["connected"] == true && s["estop_path"] == true).then_some(s)
    });
    assert_eq!(status["rig"], "sim");
    // Without --controller-key-file the server refuses to start against a remote one.
    let out = bdft_tests::server_cmd(["serve", "--db", dir.path().join("x.db").to_str().unwrap()])
        .args(["--listen", "127.0.0.1:0", "--controller", &addr])
        .env_remove("BDFT_CONTROLLER_KEY_FILE")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--controller-key-file"), "{err}");
}
