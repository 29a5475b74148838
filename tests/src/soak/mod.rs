//! The lab-day soak: the real server (with its controller) on loopback, eight browser-like
//! stations running a whole study — consent, practice, tests, surveys, new subjects as
//! others finish — while faults are injected on a seeded schedule ([`plan`]): the server
//! restarted mid-test, the disk full, the controller killed and frozen, a station reloaded,
//! offline, hidden and flooding. The soak keeps its own journal of what it did
//! ([`journal`]); at the end ([`verify`]) it compares the journal with the exports and the
//! audit log, checks the database's integrity, and compares the server's memory and file
//! descriptors at the end with their baseline.
//!
//! Stations: four serve both seats, two pairs serve one seat each (the subject moves
//! between them); six subjects at a time.
//!
//! Everything waits on conditions (a station connected, the controller back with a new
//! process, no test running, no connection left); the only timed things are what the
//! simulated people do (think, reload, stay offline) and the schedule's gaps.
//!
//! Modules: [`plan`] (the seeded schedule: warm-up, the server restarts, the baseline quiet point,
//! then every other fault kind in a seeded order, repeated while the run lasts — the first round
//! always complete, so every kind is injected at least once), [`station`] (a browser-like station
//! as `web/station.js` behaves: a page thread for state, consent, surveys and timing figures, a
//! socket thread for 60–250 Hz input tracking the live target, 60 Hz "frames" and display reports;
//! faults arrive as commands: reload, offline, hidden, flood), [`experimenter`] (the dashboard:
//! enrols, assigns, starts each ready test, accepts a test failed three times as incomplete, holds
//! the live feed), [`faults`] (each fault injected, journaled with what it expects, and its
//! recovery awaited; the slow clients — slow request bodies and idle connections from another
//! address, 127.0.0.2 — with the API timed meanwhile), [`disk`] (the full disk: the server runs
//! with `--db-max-pages`, the soak keeps little room under that cap with ballast rows of its own
//! and fills it for a fault; the integrity check), [`host`] (the server's RSS, descriptors by kind
//! and client connections from /proc), [`journal`] (`soak.jsonl`: everything the soak did and was
//! answered), [`verify`] (the journal against the trials, subjects, samples and audit exports;
//! integrity; memory and descriptors at the end's quiet point against the baseline's; the server's
//! log free of panics).
//!
//! *Invariant:* a rule the product breaks is a violation in the verdict, never a panic of the soak.

mod disk;
mod experimenter;
mod faults;
mod host;
mod journal;
pub mod plan;
mod station;
mod verify;

use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use bdft_controller::rng::Rng;
use serde_json::{Value, json};

use crate::TempDir;
use crate::server::{Api, Server, Stop, pair_named};
use disk::Ballast;
use experimenter::Experimenter;
use journal::Journal;
use plan::Step;
use station::{Station, StationSpec};

pub use verify::Verdict;

/// A soak run's settings.
#[derive(Debug, Clone)]
pub struct Config {
    /// How long the stations run tests with faults (the first round of faults is always
    /// completed, and the tests left running finish after).
    pub length: Duration,
    pub seed: u64,
    /// Keep the run's directory (database, server log, journal, exports) even when the run
    /// passes (a failed run's is always kept).
    pub keep: bool,
}

/// A test's length and the practice's (s): short, so that a subject goes through the whole
/// schedule in about a minute.
pub const TRIAL_S: f64 = 3.0;
pub const PRACTICE_S: f64 = 2.0;
/// The stations: (role, group); a group holds one subject at a time.
const LAYOUT: [(&str, usize); 8] = [
    ("both", 0),
    ("both", 1),
    ("both", 2),
    ("both", 3),
    ("on", 4),
    ("off", 4),
    ("on", 5),
    ("off", 5),
];
const GROUPS: usize = 6;
/// Pages of room the soak keeps below the database's cap outside a disk-full fault (32 MiB:
/// minutes of the study's growth).
const RESERVE_PAGES: u32 = 8192;
/// How long past its length a run may take to finish its first round of faults, and to let
/// its last tests end: the cap on its wall time.
const OVERRUN: Duration = Duration::from_secs(180);
const DRAIN: Duration = Duration::from_secs(90);
/// How long a recovery may take before it counts as failed (debug builds on a loaded
/// 2-core machine: generous; a healthy recovery takes a second or two).
pub(crate) const RECOVERY: Duration = Duration::from_secs(60);

/// A test running now, as the dashboard shows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Running {
    pub station: usize,
    pub trial: i64,
    /// Wall-clock ms of its start and planned end.
    pub started_at: i64,
    pub ends_at: i64,
}

/// One soak run in progress.
#[derive(Debug)]
pub(crate) struct Soak {
    pub config: Config,
    pub journal: Arc<Journal>,
    pub server: Server,
    pub base: Arc<RwLock<String>>,
    /// The soak's own dashboard client (faults and checks).
    pub api: Api,
    pub study: i64,
    pub stations: Vec<Station>,
    pub experimenter: Option<Experimenter>,
    pub ballast: Option<Ballast>,
    /// While a disk-full fault holds the room full, the room is not kept.
    pub disk_full: bool,
    pub rng: Rng,
    /// Memory and descriptors at the quiet points: (label, server pid, RSS KiB, fds by kind).
    pub quiet: Vec<(String, u32, u64, std::collections::BTreeMap<String, usize>)>,
    /// The server's RSS (KiB) and descriptors sampled every few seconds: (t s, rss, fds).
    pub samples: Vec<(f64, u64, usize)>,
    last_sample: Instant,
    last_room: Instant,
    /// Whether the server process is expected to run (not while the soak restarts it).
    pub server_expected: bool,
    /// Messages the dashboard's live feed received (counted when it closes).
    live_messages: u64,
}

/// Runs a soak and checks it; the verdict lists every broken rule.
pub fn run(config: Config) -> Verdict {
    let dir = TempDir::new("soak");
    let journal =
        Arc::new(Journal::create(&dir.path().join("soak.jsonl")).expect("the soak's journal"));
    let plan = plan::plan(config.seed, config.length);
    journal.log(
        "phase",
        json!({ "phase": "start", "length_s": config.length.as_secs_f64(), "seed": config.seed,
            "dir": dir.path(), "warmup_s": plan.warmup.as_secs_f64(),
            "steps": plan.steps.iter().map(|s| match s.step {
                Step::Fault(f) => f.kind.name(),
                Step::Baseline => "baseline",
            }).collect::<Vec<_>>() }),
    );
    let cap = cap_pages(config.length);
    // The database may grow to its cap; the disk is shared, so leave 2 GiB beside it.
    let need_kib = u64::from(cap) * 4 + 2 * 1024 * 1024;
    if let Some(free) = host::free_kib(dir.path())
        && free < need_kib
    {
        return Verdict {
            violations: vec![format!(
                "the soak needs {} MiB free on {} ({} MiB for the database, 2 GiB to spare); {} MiB are",
                need_kib / 1024,
                dir.path().display(),
                cap / 256,
                free / 1024
            )],
            figures: json!({}),
            kept: None,
        };
    }
    let server = Server::start_logged(dir, &["--db-max-pages", &cap.to_string()]);
    journal.log(
        "server.start",
        json!({ "pid": server.proc.child.id(), "base": server.base, "cap_pages": cap }),
    );
    let api = server.experimenter();
    let study = create_study(&api);
    let base = Arc::new(RwLock::new(server.base.clone()));
    let mut soak = Soak {
        rng: Rng::derive(config.seed, 0x50a6),
        config,
        journal: Arc::clone(&journal),
        base,
        api,
        study,
        stations: Vec::new(),
        experimenter: None,
        ballast: None,
        disk_full: false,
        quiet: Vec::new(),
        samples: Vec::new(),
        last_sample: Instant::now(),
        last_room: Instant::now(),
        server_expected: true,
        live_messages: 0,
        server,
    };
    match Ballast::open(&soak.server.db, cap, RESERVE_PAGES) {
        Ok(b) => {
            if let Err(e) = b.keep_room() {
                soak.journal.violation(e);
            }
            soak.ballast = Some(b);
        }
        Err(e) => soak.journal.violation(e),
    }
    soak.open_stations();
    soak.run_plan(&plan);
    soak.finish();
    verify::verify(soak)
}

/// The database's cap (pages): room for the most the study can grow in the run's longest
/// wall time (every group recording its full-rate record all the time), plus the rows
/// around the records, plus the reserve.
fn cap_pages(length: Duration) -> u32 {
    let record_bytes_per_s = (bdft_protocol::trial::RECORD_CHANNELS.len() * 4 * 1000) as f64;
    let wall_s = (length + OVERRUN + DRAIN).as_secs_f64();
    let bytes = GROUPS as f64 * record_bytes_per_s * wall_s * 1.1 + 16.0 * 1024.0 * 1024.0;
    (bytes / 4096.0) as u32 + RESERVE_PAGES
}

/// The study the soak runs: the defaults (the published protocol), with short tests.
fn create_study(api: &Api) -> i64 {
    let (_, mut params) = api.get("/api/defaults");
    params["trial_s"] = json!(TRIAL_S);
    params["practice_s"] = json!(PRACTICE_S);
    params["step_interval_s"] = json!(0.5);
    api.ok(
        "/api/studies",
        json!({ "name": "lab-day soak", "params": params, "seed": 2026 }),
    )["id"]
        .as_i64()
        .expect("a study id")
}

impl Soak {
    fn open_stations(&mut self) {
        let mut groups: Vec<Vec<i64>> = vec![Vec::new(); GROUPS];
        for (index, (role, group)) in LAYOUT.iter().enumerate() {
            let name = format!("soak-{}", index + 1);
            let (id, token) = pair_named(&self.api, self.study, &name, role);
            groups[*group].push(id);
            let spec = StationSpec {
                index,
                id,
                token,
                rate_hz: self.rng.uniform(60.0, 250.0).round(),
                // In a pair, the subject reads the consent form at the machine's station.
                answers_consent: *role != "off",
            };
            self.journal.log(
                "station.pair",
                json!({ "station": index, "id": id, "name": name, "role": role, "group": group, "rate_hz": spec.rate_hz }),
            );
            self.stations.push(Station::open(
                spec,
                Arc::clone(&self.base),
                Arc::clone(&self.journal),
                self.config.seed,
            ));
        }
        let api = self.server.experimenter();
        self.experimenter = Some(Experimenter::start(
            api,
            Arc::clone(&self.base),
            Arc::clone(&self.journal),
            self.study,
            groups,
            self.config.seed,
        ));
    }

    fn run_plan(&mut self, plan: &plan::Plan) {
        let started = Instant::now();
        self.journal.log("phase", json!({ "phase": "warm-up" }));
        self.pause(plan.warmup);
        let hard_end = self.config.length + OVERRUN;
        for (n, planned) in plan.steps.iter().enumerate() {
            // Later rounds only while the run lasts; the first is always completed.
            if n >= plan.first_round && started.elapsed() + planned.gap >= self.config.length {
                break;
            }
            if started.elapsed() >= hard_end {
                self.journal.violation(format!(
                    "the run could not inject its first round of faults within {hard_end:?}; {} steps left",
                    plan.steps.len() - n
                ));
                break;
            }
            self.pause(planned.gap);
            match planned.step {
                Step::Baseline => self.quiet_point("baseline"),
                Step::Fault(f) => self.inject(f, n),
            }
        }
        let left = self.config.length.saturating_sub(started.elapsed());
        self.journal.log(
            "phase",
            json!({ "phase": "faults done", "running_on_s": left.as_secs_f64() }),
        );
        self.pause(left);
    }

    /// The end: no new tests, the running ones finish, the end's quiet point, everyone goes
    /// home and the server stops.
    fn finish(&mut self) {
        self.journal.log("phase", json!({ "phase": "drain" }));
        if let Some(e) = &self.experimenter {
            e.drain();
        }
        let limit = DRAIN + Duration::from_secs_f64(TRIAL_S);
        if !self.wait_until(limit, |s| s.running().is_some_and(|r| r.is_empty())) {
            let left: Vec<i64> = self
                .running()
                .unwrap_or_default()
                .iter()
                .map(|r| r.trial)
                .collect();
            self.journal.violation(format!(
                "tests still running {limit:?} after the last start: {left:?}"
            ));
        }
        self.quiet_point("end");
        self.journal.log("phase", json!({ "phase": "stop" }));
        for s in self.stations.drain(..) {
            s.close();
        }
        if let Some(e) = self.experimenter.take() {
            self.live_messages = e.live_messages();
            e.stop();
        }
        self.server_expected = false;
        if let Err(e) = self.server.stop(Stop::Term, RECOVERY) {
            self.journal.violation(e);
        }
        if let Some(b) = self.ballast.take()
            && let Err(e) = b.remove()
        {
            self.journal.violation(e);
        }
        self.journal.flush();
    }

    /// Lets the lab run for `d`, minding the server and the disk meanwhile.
    pub fn pause(&mut self, d: Duration) {
        let until = Instant::now() + d;
        self.wait_until(d + Duration::from_secs(1), |_| Instant::now() >= until);
    }

    /// Waits until `done` holds (checked every 50 ms), at most `limit`; whether it did.
    /// Minds the server and the disk meanwhile.
    pub fn wait_until(&mut self, limit: Duration, mut done: impl FnMut(&mut Self) -> bool) -> bool {
        let start = Instant::now();
        loop {
            self.tick();
            if done(self) {
                return true;
            }
            if start.elapsed() >= limit {
                return false;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// What runs beside every wait: the server must be alive (restarted if it died by
    /// itself), the disk keeps its room, the server's memory and descriptors are sampled.
    fn tick(&mut self) {
        if self.server_expected
            && let Ok(Some(status)) = self.server.proc.child.try_wait()
        {
            self.journal
                .violation(format!("the server exited by itself ({status}); restarted"));
            match self.server.restart(Stop::Kill, RECOVERY) {
                Ok(()) => self.server_started(),
                Err(e) => self
                    .journal
                    .violation(format!("restarting the server: {e}")),
            }
        }
        if !self.disk_full && self.last_room.elapsed() >= Duration::from_secs(1) {
            self.last_room = Instant::now();
            if let Some(b) = &self.ballast
                && let Err(e) = b.keep_room()
            {
                self.journal.violation(e);
                self.ballast = None;
            }
        }
        if self.last_sample.elapsed() >= Duration::from_secs(5) {
            self.last_sample = Instant::now();
            let pid = self.server.proc.child.id();
            if let (Some(rss), Ok(fds)) = (host::rss_kib(pid), host::fds(pid)) {
                let t = self.journal.elapsed().as_secs_f64();
                self.samples.push((t, rss, fds.values().sum()));
            }
        }
    }

    /// The server was (re)started: everyone follows its address.
    pub fn server_started(&mut self) {
        self.api.base = self.server.base.clone();
        *self.base.write().unwrap_or_else(|p| p.into_inner()) = self.server.base.clone();
        self.journal.log(
            "server.start",
            json!({ "pid": self.server.proc.child.id(), "base": self.server.base }),
        );
    }

    /// The tests running now (the dashboard's view of every station); `None` when the
    /// server cannot say.
    pub fn running(&self) -> Option<Vec<Running>> {
        let mut running: Vec<Running> = Vec::new();
        for (i, st) in self.stations.iter().enumerate() {
            let (code, view) = self
                .api
                .try_call(
                    "GET",
                    &format!("/api/stations/{}/state", st.spec().id),
                    None,
                )
                .ok()?;
            if code != 200 {
                return None;
            }
            if view["phase"] != "running" {
                continue;
            }
            let test = &view["test"];
            let trial = test["trial_id"].as_i64().unwrap_or_default();
            let started_at = test["started_at"].as_i64().unwrap_or_else(journal::wall_ms);
            let ends_at =
                started_at + (test["duration_s"].as_f64().unwrap_or(TRIAL_S) * 1000.0) as i64;
            if !running.iter().any(|r| r.trial == trial) {
                running.push(Running {
                    station: i,
                    trial,
                    started_at,
                    ends_at,
                });
            }
        }
        Some(running)
    }

    /// Waits (at most `limit`) for a running test with at least `left_s` to go; what runs
    /// then (possibly nothing).
    pub fn running_with(&mut self, limit: Duration, left_s: f64) -> Vec<Running> {
        let mut found = Vec::new();
        self.wait_until(limit, |s| {
            found = s.running().unwrap_or_default();
            let now = journal::wall_ms();
            found
                .iter()
                .any(|r| (r.ends_at - now) as f64 >= left_s * 1000.0)
        });
        found
    }

    /// A quiet point: no test running, every page and the dashboard closed, no client
    /// connection left on the server; its memory and descriptors are recorded, then the
    /// lab opens again.
    fn quiet_point(&mut self, label: &str) {
        let limit = RECOVERY + Duration::from_secs_f64(TRIAL_S);
        if let Some(e) = &self.experimenter {
            e.set_paused(true);
        }
        let settled = self.wait_until(limit, |s| {
            s.running().is_some_and(|r| r.is_empty())
                && s.api
                    .try_call("GET", "/api/controller", None)
                    .is_ok_and(|(_, c)| c["connected"] == true && c["estop_path"] == true)
        });
        for st in &self.stations {
            st.set_away(true);
        }
        let port = self.server.proc.addr.port();
        let closed = self.wait_until(limit, |s| {
            s.experimenter.as_ref().is_none_or(|e| e.idle()) && host::connections_to(port) == 0
        });
        let pid = self.server.proc.child.id();
        let rss = host::rss_kib(pid).unwrap_or(0);
        let fds = host::fds(pid).unwrap_or_default();
        self.journal.log(
            "quiet",
            json!({ "label": label, "settled": settled, "closed": closed, "pid": pid,
                "rss_kib": rss, "fds": fds }),
        );
        if !settled || !closed {
            self.journal.violation(format!(
                "quiet point {label}: {} within {limit:?}",
                if settled {
                    "client connections still open on the server"
                } else {
                    "tests still running or the controller not connected"
                }
            ));
        }
        self.quiet.push((label.to_string(), pid, rss, fds));
        for st in &self.stations {
            st.set_away(false);
        }
        if let Some(e) = &self.experimenter {
            e.set_paused(false);
        }
    }

    /// The figures of the run for the report.
    pub fn figures(&self) -> Value {
        let rss: Vec<u64> = self.samples.iter().map(|s| s.1).collect();
        json!({
            "length_s": self.config.length.as_secs_f64(),
            "wall_s": self.journal.elapsed().as_secs_f64(),
            "seed": self.config.seed,
            "rss_max_kib": rss.iter().max(),
            "samples": self.samples.len(),
            "dashboard_live_messages": self.live_messages,
        })
    }
}
