//! A test client for `bdft-server`: starts the real server (which starts the real
//! controller) on a fresh database and random port, and calls its API as a browser would.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

use crate::TempDir;
use crate::controller_link::Proc;
use crate::postgres::{PgDatabase, servers_on_postgres};

pub const ADMIN_PASSWORD: &str = "test-password-42";

/// A running server with its own database: a SQLite file in a temporary directory, or with
/// `BDFT_TEST_STORE=postgres` a PostgreSQL database of its own (its keys in the directory).
#[derive(Debug)]
pub struct Server {
    pub proc: Proc,
    /// Its PostgreSQL database, if it runs on one; dropped after the server stopped.
    pub postgres: Option<PgDatabase>,
    pub base: String,
    /// Its SQLite file (on PostgreSQL: where that file would be; nothing is there).
    pub db: PathBuf,
    pub dir: TempDir,
    /// Its arguments after `serve --db … --listen …`.
    args: Vec<String>,
    /// Its self-signed certificate (PEM) when it serves HTTPS: clients trust exactly it.
    pub cert: Option<PathBuf>,
    /// Where its standard error goes (appended at every start), if not to the test's.
    log: Option<PathBuf>,
}

/// How a server is stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// SIGKILL: a crash, nothing cleaned up.
    Kill,
    /// SIGTERM: the server's own shutdown.
    Term,
}

impl Server {
    /// A server with the account "admin" ([`ADMIN_PASSWORD`]).
    pub fn start(tag: &str) -> Self {
        Self::start_with(tag, &["--admin-password", ADMIN_PASSWORD])
    }

    /// A server started with `args` (no account unless they make one).
    pub fn start_with(tag: &str, args: &[&str]) -> Self {
        Self::start_in(TempDir::new(tag), args, None)
    }

    /// A server in `dir` with the account "admin" and `args`, its standard error appended
    /// to `server.log` there.
    pub fn start_logged(dir: TempDir, args: &[&str]) -> Self {
        let log = dir.path().join("server.log");
        let mut all = vec!["--admin-password", ADMIN_PASSWORD];
        all.extend_from_slice(args);
        Self::start_in(dir, &all, Some(log))
    }

    /// A server started with `args` on a copy of the database `source` (the copy is the
    /// server's `db`; `source` is never touched).
    pub fn start_on_copy(tag: &str, source: &Path, args: &[&str]) -> Self {
        let dir = TempDir::new(tag);
        std::fs::copy(source, dir.path().join("bdft-lab.db"))
            .unwrap_or_else(|e| panic!("copying {}: {e}", source.display()));
        Self::start_in(dir, args, None)
    }

    /// A server on `dir`'s `bdft-lab.db`, or on a PostgreSQL database of its own with its
    /// keys in `dir` when this run's servers use PostgreSQL.
    fn start_in(dir: TempDir, args: &[&str], log: Option<PathBuf>) -> Self {
        let postgres = (servers_on_postgres() && !dir.path().join("bdft-lab.db").exists())
            .then(|| PgDatabase::blocking_new("server"));
        Self::start_on(dir, postgres, args, log)
    }

    /// A server with the account "admin" and `args` on a PostgreSQL database of its own,
    /// whichever store this run's other servers use.
    pub fn start_on_postgres(tag: &str, args: &[&str]) -> Self {
        let mut all = vec!["--admin-password", ADMIN_PASSWORD];
        all.extend_from_slice(args);
        let postgres = Some(PgDatabase::blocking_new("server"));
        Self::start_on(TempDir::new(tag), postgres, &all, None)
    }

    /// A server on `postgres` if given, else on `dir`'s `bdft-lab.db`; its keys in `dir`.
    fn start_on(
        dir: TempDir,
        postgres: Option<PgDatabase>,
        args: &[&str],
        log: Option<PathBuf>,
    ) -> Self {
        let db = dir.path().join("bdft-lab.db");
        let mut args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        let store = match &postgres {
            Some(pg) => vec![
                "--db".to_string(),
                pg.url(),
                "--keys-dir".into(),
                dir.path().display().to_string(),
            ],
            None => vec!["--db".to_string(), db.display().to_string()],
        };
        args.splice(0..0, store);
        let proc =
            Self::spawn("127.0.0.1:0", &args, log.as_deref()).unwrap_or_else(|e| panic!("{e}"));
        let cert = args
            .iter()
            .any(|a| a == "--tls-self-signed")
            .then(|| db.with_extension("tls-cert.pem"));
        let mut server = Self {
            base: String::new(),
            proc,
            postgres,
            db,
            dir,
            args,
            cert,
            log,
        };
        server.base = server.base_url();
        server
    }

    /// A server over HTTPS with a self-signed certificate it makes at its first start, and
    /// the account "admin".
    pub fn start_https(tag: &str) -> Self {
        Self::start_with(
            tag,
            &["--admin-password", ADMIN_PASSWORD, "--tls-self-signed"],
        )
    }

    fn scheme(&self) -> &'static str {
        if self.cert.is_some() { "https" } else { "http" }
    }

    fn base_url(&self) -> String {
        format!("{}://{}", self.scheme(), self.proc.addr)
    }

    /// A client with no session that trusts this server's certificate, if it has one.
    pub fn anonymous(&self) -> Api {
        Api::with_agent(&self.base, agent(self.cert.as_deref()))
    }

    /// The value of `--db` for this server's database (a file's path or a URL), as the
    /// command-line tools take it.
    pub fn store(&self) -> String {
        match &self.postgres {
            Some(pg) => pg.url(),
            None => self.db.display().to_string(),
        }
    }

    /// `serve --listen listen` with `args` (its `--db` first).
    fn spawn(listen: &str, args: &[String], log: Option<&Path>) -> Result<Proc, String> {
        let extra = args;
        let mut args = vec!["serve", "--listen", listen];
        args.extend(extra.iter().map(String::as_str));
        let https = extra.iter().any(|a| a == "--tls-self-signed");
        let prefix = if https {
            "bdft-lab server on https://"
        } else {
            "bdft-lab server on http://"
        };
        let stderr = match log {
            Some(path) => std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .map_err(|e| format!("{}: {e}", path.display()))?
                .into(),
            None => std::process::Stdio::inherit(),
        };
        Proc::try_spawn("bdft-server", &args, prefix, stderr)
    }

    /// Kills the server (SIGKILL: no clean shutdown) and starts it again on the same
    /// database.
    pub fn crash_and_restart(&mut self) {
        self.proc.kill();
        self.proc = Self::spawn("127.0.0.1:0", &self.args, self.log.as_deref())
            .unwrap_or_else(|e| panic!("{e}"));
        self.base = self.base_url();
    }

    /// Stops the server `how` and starts it again on the same database and port, as an
    /// operator restarting it would (the stations' pages keep their address). If another
    /// process took the port meanwhile, on a new one (`base` changes). An error when it
    /// does not stop within `limit` after SIGTERM, or does not start.
    pub fn restart(&mut self, how: Stop, limit: Duration) -> Result<(), String> {
        self.stop(how, limit)?;
        let addr = self.proc.addr.to_string();
        self.proc = match Self::spawn(&addr, &self.args, self.log.as_deref()) {
            Ok(p) => p,
            Err(_) => Self::spawn("127.0.0.1:0", &self.args, self.log.as_deref())?,
        };
        self.base = self.base_url();
        Ok(())
    }

    /// Stops the server `how` and waits for it to exit; an error when SIGTERM did not stop
    /// it within `limit` (it is killed then) or stopped it without its own shutdown.
    pub fn stop(&mut self, how: Stop, limit: Duration) -> Result<(), String> {
        if how == Stop::Kill {
            self.proc.kill();
            return Ok(());
        }
        crate::send_signal(self.proc.child.id(), "TERM")?;
        let start = Instant::now();
        while start.elapsed() < limit {
            if let Ok(Some(status)) = self.proc.child.try_wait() {
                // Its own shutdown exits; the signal's default action (no handler yet)
                // would skip the clean-up a restore or a restart depends on.
                use std::os::unix::process::ExitStatusExt;
                return match status.signal() {
                    None => Ok(()),
                    Some(s) => Err(format!(
                        "the server was ended by signal {s}, not by its own shutdown"
                    )),
                };
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        self.proc.kill();
        Err(format!(
            "the server did not stop within {limit:?} of SIGTERM (killed)"
        ))
    }

    /// Where its standard error goes, when not to the test's.
    pub fn log(&self) -> Option<&Path> {
        self.log.as_deref()
    }

    /// A client logged in as the admin experimenter.
    pub fn experimenter(&self) -> Api {
        self.login("admin", ADMIN_PASSWORD)
    }

    /// A client logged in as `username`.
    pub fn login(&self, username: &str, password: &str) -> Api {
        let mut api = self.anonymous();
        let (code, body) = api.post(
            "/api/login",
            json!({ "username": username, "password": password }),
        );
        assert_eq!(code, 200, "log-in of {username}: {body}");
        api.csrf = body["csrf"].as_str().map(str::to_string);
        api
    }

    /// A new account `username` with `role` (password [`ADMIN_PASSWORD`]), made by the
    /// admin client `admin`: its id and a client logged in as it.
    pub fn account(&self, admin: &Api, username: &str, role: &str) -> (i64, Api) {
        let made = admin.ok(
            "/api/accounts",
            json!({ "username": username, "password": ADMIN_PASSWORD, "role": role }),
        );
        (
            made["id"].as_i64().unwrap(),
            self.login(username, ADMIN_PASSWORD),
        )
    }
}

/// An HTTP client with a cookie jar, optional CSRF token and optional bearer token.
#[derive(Debug)]
pub struct Api {
    agent: ureq::Agent,
    pub base: String,
    pub csrf: Option<String>,
    pub bearer: Option<String>,
}

/// An HTTP agent; over HTTPS it trusts only the certificate in `cert` (PEM).
pub fn agent(cert: Option<&Path>) -> ureq::Agent {
    let builder = ureq::AgentBuilder::new().timeout(Duration::from_secs(60));
    match cert {
        None => builder.build(),
        Some(cert) => {
            use rustls::pki_types::CertificateDer;
            use rustls::pki_types::pem::PemObject;
            let mut roots = rustls::RootCertStore::empty();
            for c in CertificateDer::pem_file_iter(cert).expect("the server's certificate") {
                roots
                    .add(c.expect("a PEM certificate"))
                    .expect("a usable certificate");
            }
            let config = rustls::ClientConfig::builder_with_provider(std::sync::Arc::new(
                rustls::crypto::ring::default_provider(),
            ))
            .with_safe_default_protocol_versions()
            .expect("TLS versions")
            .with_root_certificates(roots)
            .with_no_client_auth();
            builder.tls_config(std::sync::Arc::new(config)).build()
        }
    }
}

impl Api {
    pub fn anonymous(base: &str) -> Self {
        Self::with_agent(base, agent(None))
    }

    fn with_agent(base: &str, agent: ureq::Agent) -> Self {
        Self {
            agent,
            base: base.to_string(),
            csrf: None,
            bearer: None,
        }
    }

    pub fn with_bearer(base: &str, token: &str) -> Self {
        Self {
            bearer: Some(token.to_string()),
            ..Self::anonymous(base)
        }
    }

    pub fn call(&self, method: &str, path: &str, body: Option<Value>) -> (u16, Value) {
        self.try_call(method, path, body)
            .unwrap_or_else(|e| panic!("{method} {path}: {e}"))
    }

    /// The status and body, or the transport's error (refused, reset, timed out): whether
    /// the server acted on it is then unknown.
    pub fn try_call(
        &self,
        method: &str,
        path: &str,
        body: Option<Value>,
    ) -> Result<(u16, Value), String> {
        let mut req = self.agent.request(method, &format!("{}{path}", self.base));
        if let Some(c) = &self.csrf {
            req = req.set("x-csrf-token", c);
        }
        if let Some(b) = &self.bearer {
            req = req.set("authorization", &format!("Bearer {b}"));
        }
        let res = match body {
            Some(b) => req.send_json(b),
            None => req.call(),
        };
        let resp = match res {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => return Err(e.to_string()),
        };
        let code = resp.status();
        let text = resp.into_string().map_err(|e| e.to_string())?;
        Ok((
            code,
            serde_json::from_str(&text).unwrap_or(Value::String(text)),
        ))
    }

    /// The status a POST to `path` announcing a JSON body of `length` bytes gets before any
    /// of the body is sent: a limit refused from the header alone, answered without a race
    /// against a client still writing.
    pub fn status_of_announced_post(&self, path: &str, length: usize) -> u16 {
        use std::io::{Read, Write};
        let host = self.base.trim_start_matches("http://");
        let mut s = std::net::TcpStream::connect(host).unwrap();
        // A server that waited for the body instead would hang the test: fail it instead.
        s.set_read_timeout(Some(std::time::Duration::from_secs(60)))
            .unwrap();
        let csrf = self
            .csrf
            .as_deref()
            .map(|c| format!("x-csrf-token: {c}\r\n"))
            .unwrap_or_default();
        write!(
            s,
            "POST {path} HTTP/1.1\r\nhost: {host}\r\ncookie: {}\r\n{csrf}content-type: application/json\r\ncontent-length: {length}\r\n\r\n",
            self.cookie_header()
        )
        .unwrap();
        let mut head = [0u8; 12];
        s.read_exact(&mut head).unwrap();
        std::str::from_utf8(&head[9..12]).unwrap().parse().unwrap()
    }

    /// The session cookie as a `Cookie:` header value (for raw-socket requests).
    pub fn cookie_header(&self) -> String {
        self.agent
            .cookie_store()
            .iter_any()
            .map(|c| format!("{}={}", c.name(), c.value()))
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// Raw body of a GET (CSV downloads).
    pub fn get_text(&self, path: &str) -> (u16, String) {
        let req = self.agent.get(&format!("{}{path}", self.base));
        match req.call() {
            Ok(r) => (r.status(), r.into_string().unwrap()),
            Err(ureq::Error::Status(c, r)) => (c, r.into_string().unwrap_or_default()),
            Err(e) => panic!("GET {path}: {e}"),
        }
    }

    /// A CSV download (an export) as its header and rows; it must answer 200.
    pub fn get_csv(&self, path: &str) -> (Vec<String>, Vec<Vec<String>>) {
        let (code, text) = self.get_text(path);
        assert_eq!(code, 200, "{path}: {text}");
        let mut rows = crate::exports::parse_csv(&text);
        let header = rows.remove(0);
        (header, rows)
    }

    /// Creates a study named `name` with `params` and study seed 42: the status and body.
    pub fn create_study(&self, name: &str, params: &Value) -> (u16, Value) {
        self.post(
            "/api/studies",
            json!({ "name": name, "params": params, "seed": 42 }),
        )
    }

    /// Status, headers (lower-case names) and text of a GET (a page with its security
    /// headers).
    pub fn get_page(&self, path: &str) -> (u16, BTreeMap<String, String>, String) {
        let resp = match self.agent.get(&format!("{}{path}", self.base)).call() {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => panic!("GET {path}: {e}"),
        };
        let headers = resp
            .headers_names()
            .into_iter()
            .filter_map(|n| {
                let v = resp.header(&n)?.to_string();
                Some((n.to_ascii_lowercase(), v))
            })
            .collect();
        (
            resp.status(),
            headers,
            resp.into_string().unwrap_or_default(),
        )
    }

    /// Status and `Content-Type` of a GET (the body is read and dropped).
    pub fn content_type(&self, path: &str) -> (u16, String) {
        let (code, resp) = match self.agent.get(&format!("{}{path}", self.base)).call() {
            Ok(r) => (r.status(), r),
            Err(ureq::Error::Status(c, r)) => (c, r),
            Err(e) => panic!("GET {path}: {e}"),
        };
        let content_type = resp.header("content-type").unwrap_or_default().to_string();
        std::io::copy(&mut resp.into_reader(), &mut std::io::sink()).unwrap();
        (code, content_type)
    }

    /// Raw bytes of a GET (Parquet downloads).
    pub fn get_bytes(&self, path: &str) -> (u16, Vec<u8>) {
        use std::io::Read;
        let req = self.agent.get(&format!("{}{path}", self.base));
        let resp = match req.call() {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => panic!("GET {path}: {e}"),
        };
        let code = resp.status();
        let mut bytes = Vec::new();
        resp.into_reader().read_to_end(&mut bytes).unwrap();
        (code, bytes)
    }

    pub fn get(&self, path: &str) -> (u16, Value) {
        self.call("GET", path, None)
    }

    pub fn post(&self, path: &str, body: Value) -> (u16, Value) {
        self.call("POST", path, Some(body))
    }

    /// POST expecting 200; returns the body.
    pub fn ok(&self, path: &str, body: Value) -> Value {
        let (code, b) = self.post(path, body);
        assert_eq!(code, 200, "POST {path}: {b}");
        b
    }
}

/// Runs `f` on a pool of the SQLite file `db` — beside its running server, as WAL allows —
/// and closes the pool: for what no API does (write a value in, read every table back).
pub fn with_db<T>(db: &Path, f: impl AsyncFnOnce(&sqlx::AnyPool) -> T) -> T {
    with_url(&format!("sqlite://{}", db.display()), f)
}

/// [`with_db`] on `server`'s store, whichever it is.
pub fn with_store<T>(server: &Server, f: impl AsyncFnOnce(&sqlx::AnyPool) -> T) -> T {
    match &server.postgres {
        Some(pg) => with_url(&pg.url(), f),
        None => with_db(&server.db, f),
    }
}

/// Runs `f` on a pool of the database at `url` through sqlx's `Any` driver, as the server
/// reads its store (flags are integers there).
pub fn with_url<T>(url: &str, f: impl AsyncFnOnce(&sqlx::AnyPool) -> T) -> T {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        sqlx::any::install_default_drivers();
        let pool = sqlx::AnyPool::connect(url).await.unwrap();
        let out = f(&pool).await;
        pool.close().await;
        out
    })
}

/// Polls `f` until it returns `Some`, failing after `limit`.
pub fn eventually<T>(limit: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(
            start.elapsed() < limit,
            "condition not reached within {limit:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Study parameters with short tests, for end-to-end runs.
pub fn short_study(api: &Api, trial_s: f64, practice_s: f64) -> i64 {
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(trial_s);
    params["practice_s"] = json!(practice_s);
    params["step_interval_s"] = json!(0.5);
    let body = api.ok(
        "/api/studies",
        json!({ "name": "end-to-end", "params": params, "seed": 42 }),
    );
    body["id"].as_i64().unwrap()
}

/// The dry-run copy of `study`: where synthetic subjects go (a study holds people or
/// synthetic subjects, never both).
pub fn dry_run(api: &Api, study: i64) -> i64 {
    api.ok(&format!("/api/studies/{study}/dry-run"), json!({}))["study_id"]
        .as_i64()
        .unwrap()
}

/// Runs the dashboard's pilot of `study` with `subjects` synthetic subjects and waits for
/// it to end; returns the pilot's final status (its report names the dry-run copy it ran in).
pub fn run_pilot(api: &Api, study: i64, subjects: u32) -> Value {
    api.ok(
        &format!("/api/studies/{study}/pilot"),
        json!({ "subjects": subjects }),
    );
    eventually(Duration::from_secs(300), || {
        let (_, s) = api.get("/api/pilot");
        (s["running"] == false && (s["report"].is_object() || s["error"].is_string())).then_some(s)
    })
}

/// Runs the dashboard's pilot of `study` with `subjects` synthetic subjects; returns the
/// dry-run copy it ran in.
pub fn pilot_copy(api: &Api, study: i64, subjects: u32) -> i64 {
    let status = run_pilot(api, study, subjects);
    status["report"]["study_id"]
        .as_i64()
        .unwrap_or_else(|| panic!("the pilot did not run: {status}"))
}

/// A person enrolled, consented and assigned to a new station serving both seats, with the
/// controller connected and not latched: (subject id, station id, station token).
pub fn person_at_a_station(server: &Server, api: &Api, study: i64) -> (i64, i64, String) {
    let enrolled = api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let (station, token) = assigned_station(api, study, subject);
    Api::with_bearer(&server.base, &token)
        .ok("/api/station/consent", json!({ "decision": "agreed" }));
    controller_ready(api);
    (subject, station, token)
}

/// A synthetic subject enrolled in the dry-run copy `study`, assigned to a new station
/// serving both seats and consented there: its enrolment answer (`subject`: id, code, …),
/// the station's id and the station's client.
pub fn synthetic_at_a_station(api: &Api, study: i64) -> (Value, i64, Api) {
    let enrolled = api.ok(
        &format!("/api/studies/{study}/subjects"),
        json!({ "synthetic": true }),
    );
    let (station, token) =
        assigned_station(api, study, enrolled["subject"]["id"].as_i64().unwrap());
    let station_api = Api::with_bearer(&api.base, &token);
    station_api.ok("/api/station/consent", json!({ "decision": "agreed" }));
    (enrolled["subject"].clone(), station, station_api)
}

/// Pairs a new station with `role` to `study`; returns (station id, station token).
pub fn pair_station(api: &Api, study: i64, role: &str) -> (i64, String) {
    pair_named(api, study, &format!("station-{role}"), role)
}

/// Pairs a new station serving both seats to `study` and assigns `subject` to it; returns
/// (station id, station token).
pub fn assigned_station(api: &Api, study: i64, subject: i64) -> (i64, String) {
    let (station, token) = pair_station(api, study, "both");
    api.ok(
        &format!("/api/stations/{station}/assign"),
        json!({ "subject_id": subject }),
    );
    (station, token)
}

/// Pairs a new station called `name` with `role` to `study`: (station id, station token).
pub fn pair_named(api: &Api, study: i64, name: &str, role: &str) -> (i64, String) {
    let reg = Api::anonymous(&api.base).ok("/api/station/register", json!({}));
    let token = reg["token"].as_str().unwrap().to_string();
    let code = reg["pairing_code"].as_str().unwrap();
    let st = api.ok(
        &format!("/api/studies/{study}/stations"),
        json!({ "pairing_code": code, "name": name, "role": role }),
    );
    (st["id"].as_i64().unwrap(), token)
}

/// Waits until the server's controller is connected and not latched: a test can start.
pub fn controller_ready(api: &Api) {
    eventually(Duration::from_secs(30), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["estop_latched"] == false).then_some(())
    });
}

/// Waits until the server says the E-stop is latched (`true`) or released (`false`).
pub fn wait_latched(api: &Api, latched: bool) {
    eventually(Duration::from_secs(30), || {
        (api.get("/api/controller").1["estop_latched"] == latched).then_some(())
    });
}

/// Every attempt of the subject's tests, as the dashboard's subject view lists them.
pub fn trial_rows(api: &Api, subject: i64) -> Vec<Value> {
    let (_, d) = api.get(&format!("/api/subjects/{subject}"));
    d["trials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["trial"].clone())
        .collect()
}

/// The row of `trial` of `subject`.
pub fn trial_row(api: &Api, subject: i64, trial: i64) -> Value {
    trial_rows(api, subject)
        .into_iter()
        .find(|t| t["id"] == trial)
        .unwrap_or_else(|| panic!("subject {subject} has no trial {trial}"))
}

/// Waits (generously: a loaded machine) until `trial` of `subject` has ended, neither
/// scheduled nor running; its row.
pub fn trial_ended(api: &Api, subject: i64, trial: i64) -> Value {
    eventually(Duration::from_secs(60), || {
        let t = trial_row(api, subject, trial);
        (t["status"] != "running" && t["status"] != "scheduled").then_some(t)
    })
}

/// The subject's next test, as the server says (`next_trial_id`: first by block and queue
/// order, a failed test re-queued).
pub fn next_trial(api: &Api, subject: i64) -> i64 {
    let (_, s) = api.get(&format!("/api/subjects/{subject}"));
    s["next_trial_id"]
        .as_i64()
        .unwrap_or_else(|| panic!("no test of subject {subject} to start: {s}"))
}

/// Runs `trial` (started by the experimenter) to its end; returns its final row. A start
/// the server cannot serve now (503: the controller restarting after its link was lost on a
/// loaded machine) is tried again once the controller is back.
pub fn run_trial(api: &Api, subject: i64, trial: i64) -> Value {
    let (code, body) = eventually(Duration::from_secs(60), || {
        controller_ready(api);
        let (code, body) = api.post(&format!("/api/trials/{trial}/start"), json!({}));
        (code != 503).then_some((code, body))
    });
    assert_eq!(code, 200, "start {trial}: {body}");
    eventually(Duration::from_secs(60), || {
        let (_, s) = api.get(&format!("/api/subjects/{subject}"));
        let t = s["trials"]
            .as_array()?
            .iter()
            .map(|t| &t["trial"])
            .find(|t| t["id"] == trial)?
            .clone();
        (t["status"] != "running").then_some(t)
    })
}

/// The store's write lock held by another client, as a long change elsewhere holds it (an
/// erasure, a backup, a pilot filing), until dropped: the lock the server's own changes take
/// (`begin_write`), on a connection and thread of its own.
#[derive(Debug)]
pub struct HeldWrite {
    release: Option<std::sync::mpsc::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl HeldWrite {
    /// Takes `server`'s store's write lock; returns once it is held.
    pub fn take(server: &Server) -> Self {
        let url = match &server.postgres {
            Some(pg) => pg.url(),
            None => format!("sqlite://{}", server.db.display()),
        };
        let (held_tx, held) = std::sync::mpsc::channel();
        let (release, released) = std::sync::mpsc::channel::<()>();
        let thread = std::thread::spawn(move || {
            with_url(&url, async |pool| {
                let mut conn = pool.acquire().await.unwrap();
                bdft_server::store::db::begin_write(&mut conn)
                    .await
                    .expect("taking the store's write lock");
                held_tx.send(()).unwrap();
                // Held until the test drops its handle (or ends).
                let _ = tokio::task::spawn_blocking(move || released.recv())
                    .await
                    .unwrap();
                sqlx::Executor::execute(&mut *conn, "ROLLBACK")
                    .await
                    .unwrap();
            })
        });
        held.recv_timeout(Duration::from_secs(30))
            .expect("the store's write lock within 30 s");
        Self {
            release: Some(release),
            thread: Some(thread),
        }
    }
}

impl Drop for HeldWrite {
    fn drop(&mut self) {
        drop(self.release.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A consented synthetic subject at a station serving both seats, with the controller
/// connected and unlatched: (subject id, its practice trial's id, the controller's pid).
pub fn consented_synthetic_subject(server: &Server, api: &Api, study: i64) -> (i64, i64, u64) {
    let enrolled = api.ok(
        &format!("/api/studies/{study}/subjects"),
        json!({ "synthetic": true }),
    );
    let subject = enrolled["subject"]["id"].as_i64().unwrap();
    let (_, token) = assigned_station(api, study, subject);
    let (practice, pid) = consent_at(server, api, &token, subject);
    (subject, practice, pid)
}

/// The subject consents at the station of `token`; waits for the controller to be
/// connected and unlatched: (the subject's practice trial's id, the controller's pid).
pub fn consent_at(server: &Server, api: &Api, token: &str, subject: i64) -> (i64, u64) {
    Api::with_bearer(&server.base, token)
        .ok("/api/station/consent", json!({ "decision": "agreed" }));
    let pid = eventually(Duration::from_secs(20), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["estop_latched"] == false)
            .then(|| c["pid"].as_u64())
            .flatten()
    });
    let (_, detail) = api.get(&format!("/api/subjects/{subject}"));
    let practice = detail["trials"][0]["trial"]["id"].as_i64().unwrap();
    (practice, pid)
}

/// Kills the controller `pid` (SIGKILL) and waits for its successor to connect: its status
/// (`GET /api/controller`), whose `estop_latched` says whether it came up latched.
pub fn replace_controller(api: &Api, pid: u64) -> Value {
    crate::send_signal(pid as u32, "KILL").unwrap();
    eventually(Duration::from_secs(60), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["pid"].as_u64().is_some_and(|p| p != pid)).then_some(c)
    })
}

/// A dry-run study with `practice_s`-long practice tests whose first synthetic subject's
/// practice test has been started: (subject id, the practice trial's id, the controller's
/// pid).
pub fn running_practice(server: &Server, api: &Api, practice_s: f64) -> (i64, i64, u64) {
    let study = dry_run(api, short_study(api, 60.0, practice_s));
    let (subject, practice, pid) = consented_synthetic_subject(server, api, study);
    let (code, body) = api.post(&format!("/api/trials/{practice}/start"), json!({}));
    assert_eq!(code, 200, "start {practice}: {body}");
    (subject, practice, pid)
}
