//! One anonymous client cannot lock everyone out (issue 37): a request body trickling in is
//! cut off at its deadline, one address holding every connection it can open does not keep
//! another address from logging in, one address cannot take every pairing code, and a refused
//! login says when to try again. The attacker is 127.0.0.2 (`raw::connect_from`), everyone
//! else the tests' usual 127.0.0.1: two clients as the server's per-address limits see them.

use std::io::Write;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use bdft_tests::raw::{self, Answer, connect_from, loopback};
use bdft_tests::server::{ADMIN_PASSWORD, Api, Server, eventually, short_study};
use serde_json::json;

/// A login whose body is announced at 100,000 bytes and sent a byte at a time: its head
/// and the first byte.
fn slow_login(from: std::net::IpAddr, server: &Server) -> TcpStream {
    let mut sock = connect_from(from, server.proc.addr).unwrap();
    let head = raw::head(
        "POST",
        "/api/login",
        &[("content-type", "application/json")],
        Some(100_000),
    );
    sock.write_all(head.as_bytes()).unwrap();
    sock.write_all(b"{").unwrap();
    sock
}

#[test]
fn a_request_body_trickling_in_is_cut_off_at_its_deadline() {
    // The defaults: a body has 10 s after its head (then at least 16 KiB/s).
    let server = Server::start("bounded-slow-body");
    let opened = Instant::now();
    let sock = slow_login(loopback(2), &server);
    // A byte every 200 ms until the server answers or closes (then a write fails).
    let mut writer = sock.try_clone().unwrap();
    let trickle = std::thread::spawn(move || {
        for _ in 0..500 {
            std::thread::sleep(Duration::from_millis(200));
            if writer.write_all(b" ").is_err() {
                return;
            }
        }
    });
    // Served meanwhile.
    let (code, _) = Api::anonymous(&server.base).get("/api/health");
    assert_eq!(code, 200);
    let mut sock = sock;
    // Generous for a loaded machine: the deadline is 10 s.
    let answer = raw::read_answer(&mut sock, Duration::from_secs(40))
        .expect("the trickling request was not answered and closed within 40 s");
    let took = opened.elapsed();
    assert_eq!(answer.status, 408, "{answer:?}");
    assert_eq!(answer.header("connection"), Some("close"), "{answer:?}");
    let error = answer.json()["error"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(error.contains("--body-timeout-ms"), "{answer:?}");
    assert!(took >= Duration::from_secs(10), "answered after {took:?}");
    drop(sock);
    trickle.join().unwrap();
}

#[test]
fn an_idle_keep_alive_connection_is_closed_at_the_header_timeout() {
    let server = Server::start_with(
        "bounded-keep-alive",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--header-timeout-ms",
            "1000",
        ],
    );
    let mut sock = connect_from(loopback(2), server.proc.addr).unwrap();
    // One request on a kept-alive connection, answered, then silence.
    sock.write_all(raw::head("GET", "/api/health", &[], None).as_bytes())
        .unwrap();
    let answered = Instant::now();
    // The answer, then the close: read until EOF.
    let answer = raw::read_answer(&mut sock, Duration::from_secs(30))
        .expect("answered, then closed within 30 s");
    assert_eq!(answer.status, 200, "{answer:?}");
    assert!(
        answered.elapsed() >= Duration::from_secs(1),
        "closed before the header timeout"
    );
}

/// An answer given before its request's body was read says `connection: close`: the server
/// closes the connection rather than read the rest, and a client that kept it would send its
/// next request into a closed socket (a POST is not retried: the E-stop's reset once failed
/// so). An answer whose body was read keeps the connection.
#[test]
fn an_answer_given_before_its_body_was_read_closes_the_connection_and_says_so() {
    let server = Server::start_with(
        "bounded-unread-body",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--header-timeout-ms",
            "1000",
        ],
    );
    // Refused from its head alone (no session): answered before the announced body comes.
    let mut sock = connect_from(loopback(1), server.proc.addr).unwrap();
    let head = raw::head(
        "POST",
        "/api/estop/reset",
        &[("content-type", "application/json")],
        Some(2),
    );
    sock.write_all(head.as_bytes()).unwrap();
    let answer = raw::read_answer(&mut sock, Duration::from_secs(30)).expect("answered");
    assert_eq!(answer.status, 401, "{answer:?}");
    assert_eq!(answer.header("connection"), Some("close"), "{answer:?}");
    // A login whose body the server read: kept alive (closed later, at the header timeout).
    let mut sock = connect_from(loopback(1), server.proc.addr).unwrap();
    let body = r#"{"username":"admin","password":"not it"}"#;
    let mut bytes = raw::head(
        "POST",
        "/api/login",
        &[("content-type", "application/json")],
        Some(body.len()),
    )
    .into_bytes();
    bytes.extend_from_slice(body.as_bytes());
    sock.write_all(&bytes).unwrap();
    let answer = raw::read_answer(&mut sock, Duration::from_secs(30)).expect("answered");
    assert_eq!(answer.status, 403, "{answer:?}");
    assert_eq!(answer.header("connection"), None, "{answer:?}");
}

/// `slow` connections from `from` sending a login body a byte at a time, then `idle` more
/// that say nothing (opened at once: the server accepts them as fast as it can).
fn occupy(from: std::net::IpAddr, server: &Server, slow: usize, idle: usize) -> Vec<TcpStream> {
    let mut held: Vec<TcpStream> = (0..slow).map(|_| slow_login(from, server)).collect();
    held.extend((0..idle).map(|_| connect_from(from, server.proc.addr).unwrap()));
    held
}

#[test]
fn one_address_holding_many_connections_cannot_keep_another_from_logging_in() {
    // Room for 256 connections and a long header timeout: before the per-address limit
    // (128 by default), 300 connections from one address held every slot for 30 s and a new
    // client waited that long.
    let server = Server::start_with(
        "bounded-per-address",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--max-connections",
            "256",
            "--header-timeout-ms",
            "30000",
        ],
    );
    // A session open before the flood.
    let open = server.experimenter();
    let attacker = loopback(2);
    let held = occupy(attacker, &server, 50, 250);
    // Another address logs in, reads its session, and the open session is served, at once
    // (generous for a loaded machine: the flood's connections are held 30 s).
    let began = Instant::now();
    let newcomer = server.experimenter();
    let (code, me) = newcomer.get("/api/me");
    assert_eq!(code, 200, "{me}");
    let (code, _) = open.get("/api/me");
    assert_eq!(code, 200);
    let (code, _) = Api::anonymous(&server.base).get("/api/health");
    assert_eq!(code, 200);
    let took = began.elapsed();
    assert!(
        took < Duration::from_secs(10),
        "a login and two reads from another address took {took:?} while one address held its connections"
    );
    // One more connection from the attacker is answered 429, with when to try again, and
    // closed (those refused in the flood's first second may only have been closed).
    let refused = eventually(Duration::from_secs(20), || {
        let a = raw::request(attacker, server.proc.addr, "GET", "/api/health", &[], None).ok()?;
        (a.status == 429).then_some(a)
    });
    assert_eq!(refused.retry_after(), Some(1), "{refused:?}");
    let error = refused.json()["error"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(
        error.contains("--max-connections-per-address"),
        "{refused:?}"
    );
    // Once the attacker lets go, its address is served again.
    drop(held);
    eventually(Duration::from_secs(30), || {
        let a = raw::request(attacker, server.proc.addr, "GET", "/api/health", &[], None).ok()?;
        (a.status == 200).then_some(())
    });
}

#[test]
fn one_address_cannot_take_every_pairing_code() {
    let server = Server::start("bounded-register");
    // 256 registrations from one address as fast as it can: before the per-address limit
    // every code was taken, and every other station got 503 for an hour.
    let answers: Vec<Answer> = (0..256)
        .map(|_| raw::register(loopback(2), server.proc.addr))
        .collect();
    let given = answers.iter().filter(|a| a.status == 200).count();
    assert_eq!(given, 20, "the default is 20 a minute");
    for a in answers.iter().filter(|a| a.status != 200) {
        assert_eq!(a.status, 429, "{a:?}");
        let retry = a.retry_after().expect("Retry-After");
        assert!((1..=60).contains(&retry), "{a:?}");
        let error = a.json()["error"].as_str().unwrap_or_default().to_string();
        assert!(
            error.contains("--station-registrations-per-minute"),
            "{a:?}"
        );
    }
    // Another address gets a code, and it pairs.
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let reg = Api::anonymous(&server.base).ok("/api/station/register", json!({}));
    api.ok(
        &format!("/api/studies/{study}/stations"),
        json!({ "pairing_code": reg["pairing_code"], "name": "Desk", "role": "off" }),
    );
}

#[test]
fn an_address_shows_at_most_its_pairing_codes_its_oldest_withdrawn() {
    let server = Server::start_with(
        "bounded-codes",
        &[
            "--admin-password",
            ADMIN_PASSWORD,
            "--station-registrations-per-minute",
            "1000",
            "--pairing-codes-per-address",
            "4",
        ],
    );
    let api = server.experimenter();
    let study = short_study(&api, 60.0, 60.0);
    let codes: Vec<(String, String)> = (0..6)
        .map(|_| {
            let a = raw::register(loopback(2), server.proc.addr);
            assert_eq!(a.status, 200, "{a:?}");
            let b = a.json();
            (
                b["token"].as_str().unwrap().to_string(),
                b["pairing_code"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    let pair = |code: &str, name: &str| {
        api.post(
            &format!("/api/studies/{study}/stations"),
            json!({ "pairing_code": code, "name": name, "role": "off" }),
        )
    };
    // The two oldest were withdrawn: they pair no station, and their page is told to
    // register again.
    for (i, (token, code)) in codes[..2].iter().enumerate() {
        let (status, body) = pair(code, &format!("old-{i}"));
        assert_eq!(status, 422, "{body}");
        assert!(
            body["error"].as_str().unwrap().contains("not shown"),
            "{body}"
        );
        let (status, body) =
            Api::anonymous(&server.base).post("/api/station/pairing", json!({ "token": token }));
        assert_eq!(status, 404, "{body}");
    }
    // The four newest are shown and pair.
    for (i, (_, code)) in codes[2..].iter().enumerate() {
        let (status, body) = pair(code, &format!("new-{i}"));
        assert_eq!(status, 200, "{body}");
    }
}

#[test]
fn a_login_refused_for_too_many_attempts_says_when_to_try_again() {
    let server = Server::start("bounded-login-429");
    let attempt = || {
        raw::request(
            loopback(2),
            server.proc.addr,
            "POST",
            "/api/login",
            &[],
            Some(r#"{"username": "admin", "password": "wrong"}"#),
        )
        .unwrap()
    };
    // Five wrong passwords a minute for one name from one address.
    for _ in 0..5 {
        assert_eq!(attempt().status, 403);
    }
    let refused = attempt();
    assert_eq!(refused.status, 429, "{refused:?}");
    let retry = refused.retry_after().expect("Retry-After");
    assert!((1..=60).contains(&retry), "{refused:?}");
    // Another address logs in.
    server.experimenter();
}
