//! One station cannot hurt another (issue 20), through the real server and controller: a
//! station flooding input on four sockets at once does not stop another station's test,
//! and of the flooder's sockets only the newest is live — each newer one replaces the older,
//! which are told so — while all of them together are read no more than one station's
//! budget. (The figures under load are `tests/benches/isolation.rs`'s.)

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bdft_tests::server::{Server, eventually, short_study};
use bdft_tests::station;
use serde_json::json;

use crate::station_safety::{next_of, person_and_practice, socket_view, trial_row};

/// What the server documents (engine::station_sockets): a station's sockets are read at
/// most 2,000 messages a second together, 200 at once.
const READ_RATE: f64 = 2000.0;
const READ_BURST: f64 = 200.0;
const REPLACED: u16 = 4001;
const FLOOD: u16 = 1008;

#[test]
fn a_station_flooding_on_four_sockets_does_not_stop_another_stations_test() {
    let _turn = bdft_tests::machine_load_turn();
    let server = Server::start("isolation");
    let api = server.experimenter();
    // Practice runs of 10 s: the flood (cut off after 3 s of it) runs inside the other test.
    let study = short_study(&api, 60.0, 10.0);
    let (flood_subject, flooder, flood_token, flood_trial) =
        person_and_practice(&server, &api, study);
    let (subject, station, token, trial) = person_and_practice(&server, &api, study);
    let mut ws = station::connect(&server.base, &token);
    for t in [trial, flood_trial] {
        let (code, body) = api.post(&format!("/api/trials/{t}/start"), json!({}));
        assert_eq!(code, 200, "{body}");
    }
    // The other station's page feeds its test at 60 Hz until it has ended, however long a
    // loaded machine makes it take (its socket stays open until the thread is joined).
    let stop = Arc::new(AtomicBool::new(false));
    let feeding = std::thread::spawn({
        let stop = Arc::clone(&stop);
        move || {
            let fed = station::feed_until(&mut ws, trial, 60.0, &stop, Duration::from_secs(60));
            (fed, ws)
        }
    });

    // The flooding station opens four sockets one after the other (each is the station's
    // once the server has sent its first message, the latch) and floods on every one.
    let began = Instant::now();
    let floods: Vec<_> = (0..4)
        .map(|_| {
            let mut ws = station::connect(&server.base, &flood_token);
            assert!(next_of(&mut ws, "estop").is_some(), "the latch first");
            std::thread::spawn(move || {
                station::flood_until_closed(ws, flood_trial, Duration::from_secs(60))
            })
        })
        .collect();
    let closes: Vec<_> = floods
        .into_iter()
        .map(|f| {
            let (_, closed) = f.join().unwrap();
            closed.expect("the server's close frame")
        })
        .collect();
    let flooded_for = began.elapsed();
    // Each older socket was replaced by the next; the newest was cut off for its flood.
    for (i, (code, reason)) in closes.iter().enumerate() {
        if i < 3 {
            assert_eq!(*code, REPLACED, "socket {i}: {reason}");
        } else {
            assert_eq!(*code, FLOOD, "socket {i}: {reason}");
            assert!(reason.contains("flood"), "{reason}");
        }
    }
    // The newest read no more than the station's whole budget over the flood.
    let view = eventually(Duration::from_secs(10), || {
        let v = socket_view(&api, flooder);
        (v["connected"] == false).then_some(v)
    });
    let read = view["accepted"].as_u64().unwrap() + view["dropped"].as_u64().unwrap();
    let budget = READ_BURST + READ_RATE * flooded_for.as_secs_f64() + 1.0;
    assert!(
        read as f64 <= budget,
        "{read} read in {flooded_for:?}: {view}"
    );

    // The other station's test ran to its end, fed and echoed all along, nothing dropped.
    let row = eventually(Duration::from_secs(60), || {
        let t = trial_row(&api, subject);
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(row["status"], "complete", "{row}");
    stop.store(true, Ordering::Relaxed);
    let (fed, _ws) = feeding.join().unwrap();
    assert!(fed.ended.is_none(), "{:?}", fed.ended);
    assert!(!fed.echo_ms.is_empty(), "echoed");
    let its = socket_view(&api, station);
    assert_eq!(its["dropped"], 0, "{its}");
    assert_eq!(its["connected"], true, "{its}");
    // The flooder's own test lost its input when it was cut off.
    let flood_row = eventually(Duration::from_secs(30), || {
        let t = trial_row(&api, flood_subject);
        (t["status"] != "running").then_some(t)
    });
    assert_ne!(flood_row["status"], "complete", "{flood_row}");
}
