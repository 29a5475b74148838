//! HTTPS: a self-signed certificate made at the first start and kept, its fingerprint
//! printed for the stations to check (checked against `openssl x509`, an independent
//! reading of the certificate file), `Secure` session cookies and HSTS, and no plain HTTP
//! on the TLS port. The end-to-end browser test runs over HTTPS too (`browser.rs`).

use std::process::Command;

use bdft_tests::server::{ADMIN_PASSWORD, Server, agent};
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

    // Plain HTTP on the TLS port gets no HTTP answer.
    let plain = format!("http://{}/api/setup", server.proc.addr);
    assert!(agent(None).get(&plain).call().is_err());
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

#[test]
fn tls_settings_that_cannot_work_are_refused_at_start() {
    let dir = bdft_tests::TempDir::new("https-bad");
    let junk = dir.path().join("junk.pem");
    std::fs::write(&junk, "not a certificate").unwrap();
    let db = dir.path().join("x.db");
    let run = |args: &[&str]| {
        let out = Command::new(bdft_tests::binary("bdft-server"))
            .args([
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
