//! A small WebDriver client (W3C protocol over HTTP) driving Debian's headless Chromium
//! through chromedriver, for the browser tests. Synchronous, like the rest of the test
//! helpers; only the commands the tests need.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

/// A running chromedriver, killed when dropped.
#[derive(Debug)]
pub struct Driver {
    child: Child,
    base: String,
}

impl Driver {
    pub fn start() -> Self {
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("a free port");
        let child = Command::new("chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver (Debian package chromium-driver; scripts/test.sh installs it)");
        let base = format!("http://127.0.0.1:{port}");
        let agent = ureq::AgentBuilder::new()
            .timeout(Duration::from_secs(5))
            .build();
        let start = Instant::now();
        while agent.get(&format!("{base}/status")).call().is_err() {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "chromedriver did not start"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        Self { child, base }
    }

    /// A new browser logged in to the dashboard at `base`, with `study` selected.
    pub fn dashboard_on(&self, downloads: &Path, base: &str, study: i64) -> Session {
        let dash = self.session(downloads);
        dash.log_in_to_dashboard(base);
        dash.select_study(study);
        dash
    }

    /// A new browser (its own profile: cookies and storage are not shared between sessions).
    pub fn session(&self, downloads: &Path) -> Session {
        let agent = ureq::AgentBuilder::new()
            .timeout(Duration::from_secs(60))
            .build();
        let caps = json!({ "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            // The HTTPS run's server has a self-signed certificate made for it.
            "acceptInsecureCerts": true,
            "goog:chromeOptions": {
                "binary": "/usr/bin/chromium",
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-quic",
                         "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
                         "--window-size=1280,900"],
                "prefs": { "download.default_directory": downloads.to_str().unwrap(), "download.prompt_for_download": false }
            }
        }}});
        let resp: Value = agent
            .post(&format!("{}/session", self.base))
            .send_json(caps)
            .expect("new browser session")
            .into_json()
            .unwrap();
        let id = resp["value"]["sessionId"]
            .as_str()
            .expect("session id")
            .to_string();
        let s = Session {
            agent,
            url: format!("{}/session/{id}", self.base),
        };
        // Let downloads land in the directory without a prompt (headless Chromium).
        let _ = s.cmd("POST", "/chromium/send_command", json!({ "cmd": "Browser.setDownloadBehavior", "params": { "behavior": "allow", "downloadPath": downloads.to_str().unwrap() } }));
        s
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One browser.
#[derive(Debug)]
pub struct Session {
    agent: ureq::Agent,
    url: String,
}

impl Drop for Session {
    fn drop(&mut self) {
        let _ = self.agent.delete(&self.url).call();
    }
}

const PATIENCE: Duration = Duration::from_secs(30);

impl Session {
    /// Sends a command; Ok(value) or Err(WebDriver error message).
    pub fn cmd(&self, method: &str, path: &str, body: Value) -> Result<Value, String> {
        let req = self.agent.request(method, &format!("{}{path}", self.url));
        let res = if method == "GET" {
            req.call()
        } else {
            req.send_json(body)
        };
        let resp = match res {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => return Err(e.to_string()),
        };
        let v: Value = resp.into_json().map_err(|e| e.to_string())?;
        match v["value"].get("error") {
            Some(e) => Err(format!("{e}: {}", v["value"]["message"])),
            None => Ok(v["value"].clone()),
        }
    }

    pub fn goto(&self, url: &str) {
        self.cmd("POST", "/url", json!({ "url": url }))
            .expect("navigate");
    }

    /// Element id of the first match of `css`, waiting for it to exist and be displayed.
    pub fn find(&self, css: &str) -> String {
        let start = Instant::now();
        loop {
            if let Some(id) = self.visible(css) {
                return id;
            }
            assert!(
                start.elapsed() < PATIENCE,
                "no visible element {css}; page: {}",
                self.body_text()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Element id of the first match of `css` if it is displayed now.
    pub fn visible(&self, css: &str) -> Option<String> {
        let v = self
            .cmd(
                "POST",
                "/element",
                json!({ "using": "css selector", "value": css }),
            )
            .ok()?;
        let id = v
            .as_object()
            .and_then(|o| o.values().next())
            .and_then(Value::as_str)
            .filter(|id| !id.is_empty())?
            .to_string();
        let shown = self
            .cmd("GET", &format!("/element/{id}/displayed"), json!({}))
            .ok();
        (shown == Some(Value::Bool(true))).then_some(id)
    }

    pub fn exists(&self, css: &str) -> bool {
        self.exec(
            "return document.querySelector(arguments[0]) !== null",
            json!([css]),
        ) == Value::Bool(true)
    }

    pub fn click(&self, css: &str) {
        let id = self.find(css);
        self.cmd("POST", &format!("/element/{id}/click"), json!({}))
            .unwrap_or_else(|e| panic!("click {css}: {e}"));
    }

    pub fn type_into(&self, css: &str, text: &str) {
        let id = self.find(css);
        self.cmd("POST", &format!("/element/{id}/clear"), json!({}))
            .ok();
        self.cmd(
            "POST",
            &format!("/element/{id}/value"),
            json!({ "text": text }),
        )
        .unwrap_or_else(|e| panic!("type into {css}: {e}"));
    }

    /// Opens the dashboard at `base` and logs in as the first administrator; returns when
    /// the dashboard shows.
    pub fn log_in_to_dashboard(&self, base: &str) {
        self.goto(&format!("{base}/"));
        self.type_into("#login-username", "admin");
        self.type_into("#login-password", crate::server::ADMIN_PASSWORD);
        self.click("#login-submit");
        self.find("#estop");
    }

    /// Opens the station page at `base` as the paired station `token` (as if it had been
    /// paired in this browser). The token is set from a page of the same origin that runs no
    /// station code: the station page's own registration could otherwise overwrite it.
    pub fn open_paired_station(&self, base: &str, token: &str) {
        self.goto(&format!("{base}/api/health"));
        self.exec(
            "localStorage.setItem('bdft-station-token', arguments[0]); localStorage.setItem('bdft-station-code', 'PAIRED'); localStorage.setItem('bdft-station-code-at', String(Date.now())); localStorage.setItem('bdft-station-paired', '1');",
            json!([token]),
        );
        self.goto(&format!("{base}/station"));
    }

    /// Logs in to the dashboard at `base`, selects `study` once the list offers it and opens
    /// `subject`'s schedule.
    pub fn open_schedule(&self, base: &str, study: i64, subject: i64) {
        self.log_in_to_dashboard(base);
        self.wait_until(
            "return [...document.querySelectorAll('#study-select option')].some((o) => o.value === arguments[0]);",
            json!([study.to_string()]),
        );
        self.choose("#study-select", &study.to_string());
        let row = format!("#subjects tr[data-subject-id='{subject}']");
        self.find(&row);
        self.click(&row);
    }

    /// Selects `study` in the dashboard's study selector, once it is listed there.
    pub fn select_study(&self, study: i64) {
        self.wait_until(
            "return [...document.querySelectorAll('#study-select option')].some((o) => o.value === arguments[0]);",
            json!([study.to_string()]),
        );
        self.choose("#study-select", &study.to_string());
    }

    /// Sets a <select>'s value and fires `change`, as a person choosing an option does.
    pub fn choose(&self, css: &str, value: &str) {
        self.find(css);
        self.exec(
            "const e = document.querySelector(arguments[0]); e.value = arguments[1]; e.dispatchEvent(new Event('change', { bubbles: true }));",
            json!([css, value]),
        );
    }

    pub fn text(&self, css: &str) -> String {
        let id = self.find(css);
        self.cmd("GET", &format!("/element/{id}/text"), json!({}))
            .unwrap()
            .as_str()
            .unwrap_or_default()
            .to_string()
    }

    pub fn exec(&self, script: &str, args: Value) -> Value {
        self.cmd(
            "POST",
            "/execute/sync",
            json!({ "script": script, "args": args }),
        )
        .unwrap_or_else(|e| panic!("script failed: {e}"))
    }

    pub fn body_text(&self) -> String {
        self.cmd("POST", "/execute/sync", json!({ "script": "return document.body ? document.body.innerText.slice(0, 2000) : ''", "args": [] }))
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default()
    }

    /// Waits until `document.body.dataset.phase` is `phase` (the station page's state).
    pub fn wait_phase(&self, phase: &str) {
        let start = Instant::now();
        loop {
            let now = self.exec("return document.body.dataset.phase || ''", json!([]));
            if now == phase {
                return;
            }
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "phase {now} instead of {phase}; page: {}",
                self.body_text()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Waits until `script` returns something truthy; returns it.
    pub fn wait_until(&self, script: &str, args: Value) -> Value {
        let start = Instant::now();
        loop {
            let v = self.exec(script, args.clone());
            if !(v.is_null() || v == Value::Bool(false) || v == json!("") || v == json!(0)) {
                return v;
            }
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "condition never held: {script}; page: {}",
                self.body_text()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Moves a pointer (mouse) over the element through `points` (offsets from its centre,
    /// CSS pixels), pressing the button at the first point.
    /// The driver's refusal (e.g. the element was hidden meanwhile) is returned.
    pub fn pointer_path(
        &self,
        css: &str,
        points: &[(i64, i64)],
        step_ms: u64,
    ) -> Result<(), String> {
        let id = self
            .visible(css)
            .ok_or_else(|| format!("{css} is not displayed"))?;
        let origin = json!({ "element-6066-11e4-a52e-4f735466cecf": id });
        let mut actions = vec![];
        for (i, (x, y)) in points.iter().enumerate() {
            actions.push(json!({ "type": "pointerMove", "duration": step_ms, "origin": origin, "x": x, "y": y }));
            if i == 0 {
                actions.push(json!({ "type": "pointerDown", "button": 0 }));
            }
        }
        actions.push(json!({ "type": "pointerUp", "button": 0 }));
        self.cmd("POST", "/actions", json!({ "actions": [{ "type": "pointer", "id": "mouse", "parameters": { "pointerType": "mouse" }, "actions": actions }] }))
            .map(|_| ())
    }

    /// Saves a screenshot of the page as a PNG.
    pub fn screenshot(&self, path: &Path) {
        let b64 = self.cmd("GET", "/screenshot", json!({})).unwrap();
        let bytes = base64_decode(b64.as_str().unwrap());
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d).unwrap();
        }
        std::fs::write(path, bytes).unwrap();
    }
}

/// Where the browser tests save their screenshots (the artifacts of a CI run).
pub fn artifacts_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../artifacts/screenshots")
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => 0,
        }
    };
    let bytes: Vec<u8> = s.bytes().filter(|c| !c.is_ascii_whitespace()).collect();
    let mut out = Vec::with_capacity(bytes.len() * 3 / 4);
    for chunk in bytes.chunks(4) {
        let n = chunk.iter().enumerate().fold(0u32, |acc, (i, &c)| {
            acc | (if c == b'=' { 0 } else { val(c) } << (18 - 6 * i))
        });
        let pads = chunk.iter().filter(|&&c| c == b'=').count();
        out.push((n >> 16) as u8);
        if pads < 2 {
            out.push((n >> 8) as u8);
        }
        if pads < 1 {
            out.push(n as u8);
        }
    }
    out
}
