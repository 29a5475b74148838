//! The E-stop under contention (issue 37): `POST /api/estop` answered at the client, on the
//! real server and controller over loopback, while the server is idle, while another client
//! holds the store's write lock for 12 s, while a 50-subject pilot runs, while a samples
//! export streams, and while a calibration runs. In each: PRESSES presses (the latch stays
//! set between them; each is a whole press: sent to the controller, confirmed, its audit row
//! queued), then the controller is killed and its successor must come up latched, then the
//! latch is reset.
//!
//! Prints one JSON object. Run: `cargo build --workspace --bins && cargo bench --profile dev
//! -p bdft-tests --bench estop_contention` (env PRESSES=50, SCENARIOS=idle,held,pilot,export,
//! calibration).

use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use bdft_tests::server::{
    Api, HeldWrite, Server, pilot_copy, replace_controller, short_study, wait_latched,
};
use bdft_tests::{server_cmd, setting, setting_list};
use serde_json::{Value, json};

fn main() {
    let presses: usize = setting("PRESSES", 50);
    let scenarios: Vec<String> = setting_list("SCENARIOS", "idle,held,pilot,export,calibration");
    let server = Server::start("bench-estop-contention");
    let api = server.experimenter();
    let study = short_study(&api, 20.0, 5.0);
    // A pilot's data (in its dry-run copy) for the export and the calibration to work on.
    let copy = pilot_copy(&api, study, 8);
    let mut report = Vec::new();
    for name in &scenarios {
        let load = Load::start(name, &server, &api, (study, copy));
        let times = press(&api, presses);
        let kept = latch_kept_across_a_controller_kill(&api);
        let load_finished = load.stop();
        api.ok("/api/estop/reset", json!({}));
        wait_latched(&api, false);
        report.push(json!({
            "scenario": name,
            "answered_ms": summary(times),
            "latch_kept_across_controller_kill": kept,
            "load_ran_throughout": !load_finished,
        }));
    }
    let loadavg = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "{}",
        json!({ "presses": presses, "loadavg": loadavg.trim(), "scenarios": report })
    );
}

/// `n` presses, each timed at the client from writing the request to reading the answer.
fn press(api: &Api, n: usize) -> Vec<f64> {
    (0..n)
        .map(|_| {
            let t = Instant::now();
            let (code, body) = api.post("/api/estop", json!({}));
            let ms = t.elapsed().as_secs_f64() * 1e3;
            assert_eq!(code, 200, "{body}");
            ms
        })
        .collect()
}

fn latch_kept_across_a_controller_kill(api: &Api) -> bool {
    let pid = api.get("/api/controller").1["pid"].as_u64().unwrap();
    replace_controller(api, pid)["estop_latched"] == true
}

fn summary(mut v: Vec<f64>) -> Value {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    json!({ "n": v.len(), "p50": at(0.5), "p99": at(0.99), "max": at(1.0) })
}

/// What runs beside the presses.
enum Load {
    None,
    Held(HeldWrite),
    Process(Child),
}

impl Load {
    /// `studies`: the study and its pilot's dry-run copy.
    fn start(name: &str, server: &Server, api: &Api, studies: (i64, i64)) -> Self {
        let (study, copy) = studies;
        let load = match name {
            "idle" => Self::None,
            "held" => Self::Held(HeldWrite::take(server)),
            // As the dashboard runs them: in the server's process.
            "pilot" => {
                api.ok(
                    &format!("/api/studies/{study}/pilot"),
                    json!({ "subjects": 50 }),
                );
                Self::None
            }
            "export" => Self::Process(tool(
                server,
                &["export", "--kind", "samples", "--out", "/dev/null"],
            )),
            "calibration" => {
                api.ok(
                    &format!("/api/studies/{copy}/calibrate"),
                    json!({ "simulated_subjects": 48 }),
                );
                Self::None
            }
            other => {
                panic!("SCENARIOS: no scenario {other:?} (idle, held, pilot, export, calibration)")
            }
        };
        // Under way before the first press.
        std::thread::sleep(Duration::from_millis(500));
        load
    }

    /// Ends the load; whether it had finished by itself before the presses ended.
    fn stop(self) -> bool {
        match self {
            Self::None => false,
            Self::Held(lock) => {
                drop(lock);
                false
            }
            Self::Process(mut child) => {
                let finished = matches!(child.try_wait(), Ok(Some(_)));
                let _ = child.kill();
                let _ = child.wait();
                finished
            }
        }
    }
}

/// `bdft-server ARGS --db` on the server's store, as a user runs it beside the server.
fn tool(server: &Server, args: &[&str]) -> Child {
    let store = server.store();
    server_cmd(args)
        .args(["--db", &store])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting bdft-server")
}
