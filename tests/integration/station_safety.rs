//! The stations' live sockets under abuse, through the real server and controller: a
//! flooding station is throttled and then cut off while another station's test runs
//! normally; a station has one socket (the newest); closed sockets give back their file
//! descriptors; the pairing codes are bounded; and, in Chromium, the E-stop shows "Stopped"
//! on the station at once and keeps the experimenter's Start disabled until Reset.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bdft_tests::TempDir;
use bdft_tests::raw;
use bdft_tests::server::{
    self, ADMIN_PASSWORD, Api, Server, eventually, pair_station, short_study,
};
use bdft_tests::station::{self, Socket, read_timeout};
use bdft_tests::webdriver::Driver;
use serde_json::{Value, json};
use tungstenite::Message;
use tungstenite::client::IntoClientRequest;

/// The limits the server documents (engine::station_sockets): input at 500 a second, 100
/// at once; a station read at 2,000 a second, 200 at once; 4 sockets opened at once.
const INPUT_RATE: f64 = 500.0;
const INPUT_BURST: f64 = 100.0;
const READ_RATE: f64 = 2000.0;
const READ_BURST: f64 = 200.0;
const OPENING_BURST: u32 = 4;

/// A person enrolled, consented and assigned to a new station serving both seats, with the
/// controller connected: (subject id, station id, station token, the practice trial's id).
pub fn person_and_practice(server: &Server, api: &Api, study: i64) -> (i64, i64, String, i64) {
    let (subject, station, token) = server::person_at_a_station(server, api, study);
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    let practice = detail["trials"][0]["trial"]["id"].as_i64().unwrap();
    (subject, station, token, practice)
}

fn station_socket(server: &Server, token: &str) -> Socket {
    station::connect(&server.base, token)
}

/// Reads until a text message of `kind` (or a close) arrives; `None` on a close.
pub fn next_of(ws: &mut Socket, kind: &str) -> Option<Value> {
    read_timeout(ws, Duration::from_secs(30));
    loop {
        match ws.read().expect("a message within 30 s") {
            Message::Text(t) => {
                let v: Value = serde_json::from_str(&t).unwrap();
                if v["type"] == kind {
                    return Some(v);
                }
            }
            Message::Close(_) => return None,
            _ => {}
        }
    }
}

/// Reads until the server's close frame: (code, reason).
fn close_frame(ws: &mut Socket) -> (u16, String) {
    read_timeout(ws, Duration::from_secs(30));
    loop {
        match ws.read() {
            Ok(Message::Close(Some(f))) => return (f.code.into(), f.reason.to_string()),
            Ok(Message::Close(None)) => panic!("closed without a code"),
            Ok(_) => {}
            Err(e) => panic!("the socket failed before its close frame: {e}"),
        }
    }
}

/// The station's socket as the experimenter's monitor shows it.
pub fn socket_view(api: &Api, station: i64) -> Value {
    api.get(&format!("/api/stations/{station}/state")).1["station"]["socket"].clone()
}

pub fn trial_row(api: &Api, subject: i64) -> Value {
    api.get(&format!("/api/subjects/{subject}")).1["trials"][0]["trial"].clone()
}

#[test]
fn a_flooding_station_is_throttled_then_cut_off_while_another_runs_normally() {
    let _turn = bdft_tests::machine_load_turn();
    let server = Server::start("station-flood");
    let api = server.experimenter();
    // Practice runs of 8 s: long enough to outlast the flood's three seconds.
    let study = short_study(&api, 60.0, 8.0);
    let (flood_subject, flooder, flood_token, flood_trial) =
        person_and_practice(&server, &api, study);
    let (calm_subject, calm, calm_token, calm_trial) = person_and_practice(&server, &api, study);
    let mut calm_ws = station_socket(&server, &calm_token);
    let flood_ws = station_socket(&server, &flood_token);
    for trial in [calm_trial, flood_trial] {
        let (code, body) = api.post(&format!("/api/trials/{trial}/start"), json!({}));
        assert_eq!(code, 200, "{body}");
    }

    // The calm station feeds its test at 100 Hz, as a page does, until it has ended, however
    // long a loaded machine makes it take. (The socket stays open until the thread is joined.)
    let stop = Arc::new(AtomicBool::new(false));
    let calm_thread = std::thread::spawn({
        let stop = Arc::clone(&stop);
        move || {
            let fed = station::feed_until(
                &mut calm_ws,
                calm_trial,
                100.0,
                &stop,
                Duration::from_secs(60),
            );
            (fed, calm_ws)
        }
    });

    // The other floods as fast as the server takes it.
    let began = Instant::now();
    let (sent, closed) =
        station::flood_until_closed(flood_ws, flood_trial, Duration::from_secs(60));
    let flooded_for = began.elapsed();
    let closed = closed.expect("the server's close frame");
    assert_eq!(closed.0, 1008, "policy violation: {closed:?}");
    assert!(closed.1.contains("flood"), "{closed:?}");

    // Of everything it sent, the server read at most its read budget (the rest waited in
    // the network) and used at most the input budget of that.
    let view = eventually(Duration::from_secs(10), || {
        let v = socket_view(&api, flooder);
        (v["connected"] == false).then_some(v)
    });
    let accepted = view["accepted"].as_u64().unwrap();
    let dropped = view["dropped"].as_u64().unwrap();
    let secs = flooded_for.as_secs_f64();
    assert!(
        (accepted as f64) <= INPUT_BURST + INPUT_RATE * secs,
        "{accepted} accepted in {flooded_for:?}"
    );
    assert!(
        (accepted + dropped) as f64 <= READ_BURST + READ_RATE * secs + 1.0,
        "{} read in {flooded_for:?}",
        accepted + dropped
    );
    assert!(dropped > accepted, "{dropped} dropped, {accepted} accepted");
    assert!(accepted + dropped <= sent, "{view}");
    assert!(
        view["closed_by_server"].as_str().unwrap().contains("flood"),
        "{view}"
    );

    // The calm station's test ran to its end, fed and echoed all along, nothing dropped.
    let calm_row = eventually(Duration::from_secs(60), || {
        let t = trial_row(&api, calm_subject);
        (t["status"] != "running").then_some(t)
    });
    let calm_view = socket_view(&api, calm);
    assert_eq!(calm_view["dropped"], 0, "{calm_view}");
    assert_eq!(calm_view["connected"], true, "{calm_view}");
    stop.store(true, Ordering::Relaxed);
    let (fed, _calm_ws) = calm_thread.join().unwrap();
    assert_eq!(calm_row["status"], "complete", "{calm_row}");
    assert!(fed.ended.is_none(), "{:?}", fed.ended);
    assert!(!fed.echo_ms.is_empty(), "echoed");
    // The flooder's own test lost its input when it was cut off.
    let flood_row = eventually(Duration::from_secs(30), || {
        let t = trial_row(&api, flood_subject);
        (t["status"] != "running").then_some(t)
    });
    assert_ne!(flood_row["status"], "complete", "{flood_row}");
}

#[test]
fn a_second_socket_of_a_station_replaces_the_first() {
    let server = Server::start("station-replace");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let (_, station, token, _) = person_and_practice(&server, &api, study);
    let began = Instant::now();
    let mut first = station_socket(&server, &token);
    // The latch comes first on every new socket: the page knows at once.
    assert_eq!(
        next_of(&mut first, "estop").expect("the latch")["latched"],
        false
    );
    let mut second = station_socket(&server, &token);
    let (code, reason) = close_frame(&mut first);
    assert_eq!(code, 4001, "{reason}");
    assert!(reason.contains("opened again"), "{reason}");
    assert!(
        next_of(&mut second, "estop").is_some(),
        "the newest is live"
    );
    let view = eventually(Duration::from_secs(10), || {
        let v = socket_view(&api, station);
        (v["connected"] == true).then_some(v)
    });
    assert!(view["closed_by_server"].is_null(), "{view}");
    // The E-stop reaches the live socket at once.
    api.ok("/api/estop", json!({}));
    assert_eq!(
        next_of(&mut second, "estop").expect("pushed")["latched"],
        true
    );
    api.ok("/api/estop/reset", json!({}));
    assert_eq!(
        next_of(&mut second, "estop").expect("pushed")["latched"],
        false
    );
    // A station opens a few sockets at once and then one a second; more are refused before
    // the upgrade, with the limit named (and however slow this was, no more got through).
    let mut opened = 2u32;
    let refused = loop {
        match tungstenite::connect(station::socket_url(&server.base, &token)) {
            Ok(_) => opened += 1,
            Err(tungstenite::Error::Http(refused)) => break refused,
            Err(e) => panic!("opening a socket: {e}"),
        }
        assert!(opened < 1000, "never refused");
    };
    assert_eq!(refused.status(), 429);
    let body: Value = serde_json::from_slice(refused.body().as_deref().unwrap()).unwrap();
    assert!(
        body["error"].as_str().unwrap().contains("too many sockets"),
        "{body}"
    );
    let most = OPENING_BURST as f64 + began.elapsed().as_secs_f64();
    assert!(opened as f64 <= most, "{opened} opened");
}

fn open_fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .count()
}

/// The dashboard's live socket, as a logged-in experimenter's page opens it.
fn dashboard_socket(server: &Server, api: &Api) -> Socket {
    let mut req = format!("{}/api/live", server.base.replace("http://", "ws://"))
        .into_client_request()
        .unwrap();
    let h = req.headers_mut();
    h.insert("cookie", api.cookie_header().parse().unwrap());
    h.insert("origin", server.base.parse().unwrap());
    let (ws, _) = tungstenite::connect(req).expect("dashboard socket");
    ws
}

#[test]
fn closed_sockets_give_back_their_file_descriptors() {
    // 40 stations registered within seconds from this one address.
    let server = Server::start_with(
        "station-fds",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--station-registrations-per-minute",
            "100",
        ],
    );
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    const N: usize = 40;
    let tokens: Vec<(i64, String)> = (0..N).map(|_| pair_station(&api, study, "off")).collect();
    let pid = server.proc.child.id();
    let all_closed = || {
        tokens
            .iter()
            .all(|(station, _)| socket_view(&api, *station)["connected"] == false)
    };
    let mut before = 0;
    // The first round warms up what the server opens lazily and keeps (the database
    // pool's connections); the next two must give back every descriptor they took.
    for round in 0..3 {
        let mut open: Vec<Socket> = tokens
            .iter()
            .flat_map(|(_, token)| {
                [
                    station_socket(&server, token),
                    dashboard_socket(&server, &api),
                ]
            })
            .collect();
        // Each socket holds one descriptor while open.
        let during = open_fds(pid);
        if round > 0 {
            assert!(during >= before + 2 * N, "{during} open, {before} before");
        }
        // Half close as a browser closing a tab does, half vanish (the TCP connection
        // closes without a close frame), in a quiet moment: no event to send would
        // reveal a dead socket.
        for (i, ws) in open.iter_mut().enumerate() {
            if i % 2 == 0 {
                ws.close(None).unwrap();
                let _ = ws.flush();
            }
        }
        drop(open);
        // Every station socket's task has ended (it marks its socket closed last)...
        eventually(Duration::from_secs(20), || all_closed().then_some(()));
        if round == 0 {
            before = open_fds(pid);
            continue;
        }
        // ... and the descriptors of all of them, dashboards too, are back.
        let deadline = Instant::now() + Duration::from_secs(20);
        let after = loop {
            let n = open_fds(pid);
            if n <= before + 4 || Instant::now() > deadline {
                break n;
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        assert!(
            after <= before + 4,
            "round {round}: {after} open, {before} before"
        );
    }
}

#[test]
fn pairing_codes_are_bounded_and_a_waiting_station_learns_of_its_pairing_at_once() {
    let server = Server::start("station-pairing");
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let anyone = Api::anonymous(&server.base);
    let reg = anyone.ok("/api/station/register", json!({}));
    let token = reg["token"].as_str().unwrap().to_string();
    let code = reg["pairing_code"].as_str().unwrap().to_string();
    // The page waits for its pairing instead of polling its state; the pairing answers it.
    let waiting = {
        let (base, token) = (server.base.clone(), token.clone());
        std::thread::spawn(move || {
            let asked = Instant::now();
            let answer =
                Api::anonymous(&base).post("/api/station/pairing", json!({ "token": token }));
            (answer, asked.elapsed())
        })
    };
    api.ok(
        &format!("/api/studies/{study}/stations"),
        json!({ "pairing_code": code, "name": "Desk", "role": "off" }),
    );
    let ((status, body), took) = waiting.join().unwrap();
    assert_eq!((status, &body), (200, &json!({ "paired": true })));
    assert!(
        took < Duration::from_secs(20),
        "answered at the pairing, not at the timeout"
    );
    // A token that is neither shown nor paired is told to register again.
    let (status, body) = anyone.post("/api/station/pairing", json!({ "token": "nope" }));
    assert_eq!(status, 404, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("register again"),
        "{body}"
    );
    // The codes shown at once are bounded; the refusal says why and what to do. One address
    // shows at most 16 (`bounded_clients`), so sixteen stations' addresses (127.0.0.10 to
    // .25) register 16 each (the code above was paired: it is no longer shown).
    let register = |n: u8| raw::register(raw::loopback(n), server.proc.addr);
    let shown = (10..26)
        .flat_map(|n| (0..16).map(move |_| n))
        .map(register)
        .take_while(|a| a.status == 200)
        .count();
    assert_eq!(shown, 256);
    let refused = register(26);
    assert_eq!(refused.status, 503, "{refused:?}");
    assert!(
        refused.json()["error"].as_str().unwrap().contains("expire"),
        "{refused:?}"
    );
}

#[test]
fn the_estop_shows_stopped_on_the_station_and_holds_start_until_reset() {
    let server = Server::start("station-estop-browser");
    let api = server.experimenter();
    let base = server.base.clone();
    let study = short_study(&api, 60.0, 60.0);
    let downloads = TempDir::new("station-estop-downloads");
    let driver = Driver::start();

    // A station page, paired and assigned to a consenting subject.
    let station = driver.session(downloads.path());
    station.goto(&format!("{base}/station"));
    let code = station.text("#pairing-code");
    let paired = api.ok(
        &format!("/api/studies/{study}/stations"),
        json!({ "pairing_code": code.trim(), "name": "Desk", "role": "both" }),
    );
    let station_id = paired["id"].as_i64().unwrap();
    let enrolled = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    api.ok(
        &format!("/api/stations/{station_id}/assign"),
        json!({ "subject_id": subject }),
    );
    station.wait_phase("consent");
    station.click("#consent-agree");
    station.wait_phase("ready");

    // The experimenter's dashboard with the station's Start enabled.
    let dash = driver.session(downloads.path());
    dash.log_in_to_dashboard(&base);
    let start = format!("button[data-action='start'][data-station-id='{station_id}']");
    let start_state = format!(
        "const b = document.querySelector(\"{start}\"); \
         const l = b && b.closest('section').querySelector('.mon-latch'); \
         return b ? [b.disabled, l && !l.hidden ? l.textContent : ''] : null;"
    );
    let enabled = |want: bool| {
        dash.wait_until(
            &format!(
                "const s = (() => {{ {start_state} }})(); return s && s[0] === {} ? s : null;",
                !want
            ),
            json!([]),
        )
    };
    enabled(true);
    // A running test on the station page.
    dash.click(&start);
    station.wait_phase("running");

    // E-stop: the station says "Stopped" (pushed, not polled) and its display stops.
    let pressed = Instant::now();
    api.ok("/api/estop", json!({}));
    station.wait_phase("stopped");
    let shown_after = pressed.elapsed();
    assert!(station.text("#phase-stopped h1").contains("Stopped"));
    assert!(
        shown_after < Duration::from_secs(5),
        "shown {shown_after:?} after the press"
    );
    let row = eventually(Duration::from_secs(10), || {
        let t = trial_row(&api, subject);
        (t["status"] != "running").then_some(t)
    });
    assert_eq!(row["status"], "aborted", "{row}");
    // The monitor keeps Start disabled and says to reset, though the station is ready again.
    let state = enabled(false);
    assert!(
        state[1].as_str().unwrap().contains("Reset e-stop"),
        "{state}"
    );
    let (_, view) = api.get(&format!("/api/stations/{station_id}/state"));
    assert_eq!(
        view["phase"], "ready",
        "the redo or next test waits: {view}"
    );
    assert_eq!(
        station.exec("return document.body.dataset.phase", json!([])),
        "stopped",
        "still stopped while latched"
    );

    // Reset: the station shows its test again, and Start is enabled.
    api.ok("/api/estop/reset", json!({}));
    station.wait_phase("ready");
    let state = enabled(true);
    assert_eq!(state[1], "", "{state}");
}
