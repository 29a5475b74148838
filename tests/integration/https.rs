//! HTTPS: a self-signed certificate made at the first start and kept, its fingerprint
//! printed for the stations to check (checked against `openssl x509`, an independent
//! reading of the certificate file, as is its subject naming the lab's server), `Secure`
//! session cookies and HSTS, and plain HTTP on the TLS port redirected to HTTPS within the
//! connection limits. The end-to-end browser test runs over HTTPS too (`browser.rs`).

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::Command;
use std::time::Duration;

use bdft_tests::server::{ADMIN_PASSWORD, Server, agent, eventually};
use serde_json::json;

/// The fingerprint line the server printed before its address.
fn printed_fingerprint(server: &Server) -> String {
    server
        .proc
        .banner
        .iter()
        .find_map(|l| l.strip_prefix("TLS certificate SHA-256 fingerprint: "))
        .expect("the fingerprint is printed at start")
        .to_string()
}

#[test]
fn the_server_speaks_https_with_a_kept_certificate_and_secure_cookies() {
    let mut server = Server::start_https("https");
    let cert = server.cert.clone().unwrap();

    // The printed fingerprint is the certificate's, as openssl reads the file.
    let out = Command::new("openssl")
        .args(["x509", "-noout", "-fingerprint", "-sha256", "-in"])
        .arg(&cert)
        .output()
        .expect("openssl runs");
    assert!(out.status.success(), "{out:?}");
    let openssl = String::from_utf8(out.stdout).unwrap();
    let openssl = openssl.trim().rsplit('=').next().unwrap().to_string();
    let fingerprint = printed_fingerprint(&server);
    assert_eq!(fingerprint, openssl);

    // A log-in over HTTPS sets a Secure cookie, and every answer carries HSTS.
    let http = agent(Some(&cert));
    let r = http
        .post(&format!("{}/api/login", server.base))
        .send_json(json!({ "username": "admin", "password": ADMIN_PASSWORD }))
        .expect("log-in over HTTPS");
    let cookie = r.header("set-cookie").unwrap().to_string();
    assert!(cookie.contains("; Secure"), "{cookie}");
    assert!(cookie.contains("HttpOnly"), "{cookie}");
    assert_eq!(
        r.header("strict-transport-security"),
        Some("max-age=31536000")
    );
    let page = http
        .get(&format!("{}/station", server.base))
        .call()
        .unwrap();
    assert!(page.header("strict-transport-security").is_some());
    assert!(page.into_string().unwrap().contains("<html"));

    // The API works through the trusting client (cookies, CSRF).
    let api = server.experimenter();
    let (code, _) = api.get("/api/studies");
    assert_eq!(code, 200);

    // The certificate names the lab's server, as openssl reads it.
    let out = Command::new("openssl")
        .args(["x509", "-noout", "-subject", "-nameopt", "RFC2253", "-in"])
        .arg(&cert)
        .output()
        .expect("openssl runs");
    assert!(out.status.success(), "{out:?}");
    let subject = String::from_utf8(out.stdout).unwrap();
    assert!(subject.contains("CN=bdft-lab server "), "{subject}");
    assert!(subject.contains("O=bdft-lab"), "{subject}");

    // A client that does not trust the certificate is refused by its own TLS check.
    assert!(
        agent(None)
            .get(&format!("{}/api/setup", server.base))
            .call()
            .is_err()
    );

    // The certificate is kept: a restart serves the same one.
    server.crash_and_restart();
    assert_eq!(printed_fingerprint(&server), fingerprint);
    let (code, _) = server.anonymous().get("/api/setup");
    assert_eq!(code, 200);
}

/// What the server answers on a new connection to `addr` that sends `request`, until it
/// closes the connection (a read error after an answer counts as the close).
fn exchange(addr: std::net::SocketAddr, request: &[u8]) -> String {
    let mut socket = TcpStream::connect(addr).unwrap();
    // A bound for a broken server, not a wait: the answer comes, or the connection closes.
    socket
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    if socket.write_all(request).is_err() {
        // Closed before the whole request was taken (a head over the size cap).
        return String::new();
    }
    let mut answer = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        match socket.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => answer.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                panic!("no answer and no close within a minute: {answer:?}")
            }
            Err(_) => break,
        }
    }
    String::from_utf8_lossy(&answer).into_owned()
}

/// Whether the server closes `socket` (no answer but its end, or a reset).
fn closed_by_server(socket: &mut TcpStream) -> bool {
    socket
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let mut rest = Vec::new();
    match socket.read_to_end(&mut rest) {
        Ok(_) => true,
        Err(e) => !matches!(e.kind(), std::io::ErrorKind::WouldBlock),
    }
}

#[test]
fn plain_http_on_the_https_port_is_redirected_within_the_connection_limits() {
    let server = Server::start_with(
        "https-redirect",
        &[
            "--tls-self-signed",
            "--header-timeout-ms",
            "10000",
            "--max-connections-per-address",
            "2",
        ],
    );
    let addr = server.proc.addr;
    let port = addr.port();

    // Plain-HTTP clients that never finish a head hold no more connections than their
    // address may (first, before any other connection of this test is open), and those only
    // until the header timeout.
    let slow = || {
        let mut s = TcpStream::connect(addr).unwrap();
        s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").unwrap();
        s
    };
    let (mut first, mut second, mut third) = (slow(), slow(), slow());
    assert!(closed_by_server(&mut third), "the third from one address");
    first.set_nonblocking(true).unwrap();
    let still_open = first.read(&mut [0u8; 1]);
    assert!(
        matches!(&still_open, Err(e) if e.kind() == std::io::ErrorKind::WouldBlock),
        "the first is held, not closed, when the third is refused: {still_open:?}"
    );
    first.set_nonblocking(false).unwrap();
    assert!(closed_by_server(&mut first), "closed at the header timeout");
    assert!(
        closed_by_server(&mut second),
        "closed at the header timeout"
    );

    // A browser given http://: the same path over https, at the host it asked for (once the
    // slow ones' places are free again).
    let get = format!("GET /dashboard HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n");
    let answer = eventually(Duration::from_secs(30), || {
        Some(exchange(addr, get.as_bytes())).filter(|a| !a.is_empty())
    });
    let head = answer
        .split("\r\n\r\n")
        .next()
        .unwrap()
        .to_ascii_lowercase();
    assert!(head.starts_with("http/1.1 308"), "{answer}");
    assert!(
        head.contains(&format!(
            "\r\nlocation: https://127.0.0.1:{port}/dashboard\r\n"
        )),
        "{answer}"
    );

    // No usable Host: a page that says where to go, and no redirect anywhere.
    for request in [
        "GET /x HTTP/1.0\r\n\r\n".to_string(),
        "GET /x HTTP/1.1\r\nHost: evil.example@127.0.0.1\r\n\r\n".into(),
    ] {
        let answer = exchange(addr, request.as_bytes());
        let status = answer.split("\r\n").next().unwrap();
        assert!(status.ends_with(" 400 Bad Request"), "{request}: {answer}");
        assert!(
            !answer.to_ascii_lowercase().contains("location:"),
            "{answer}"
        );
        assert!(
            answer.contains(&format!(
                "This port speaks HTTPS: open <a href=\"https://127.0.0.1:{port}/\">"
            )),
            "{answer}"
        );
    }

    // A head larger than the redirect needs is not read whole, nor followed.
    let huge = format!(
        "GET /{} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n",
        "a".repeat(64 * 1024)
    );
    let answer = exchange(addr, huge.as_bytes());
    assert!(!answer.contains(" 308 "), "{answer}");
}

#[test]
fn tls_settings_that_cannot_work_are_refused_at_start() {
    let dir = bdft_tests::TempDir::new("https-bad");
    let junk = dir.path().join("junk.pem");
    std::fs::write(&junk, "not a certificate").unwrap();
    let db = dir.path().join("x.db");
    let run = |args: &[&str]| {
        let out = bdft_tests::server_cmd([
            "serve",
            "--db",
            db.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
        ])
        .args(args)
        .output()
        .unwrap();
        assert!(!out.status.success(), "{args:?} started");
        String::from_utf8(out.stderr).unwrap()
    };
    let j = junk.to_str().unwrap();
    assert!(run(&["--tls-cert", j, "--tls-key", j]).contains("--tls-cert"));
    // A certificate without its key, and both kinds at once, are usage errors.
    assert!(run(&["--tls-cert", j]).contains("--tls-key"));
    assert!(
        run(&["--tls-cert", j, "--tls-key", j, "--tls-self-signed"])
            .contains("cannot be used with")
    );
}
