//! The LSL streams (`serve --lsl`) read by an independent client: pylsl, which bundles the C
//! liblsl (installed by scripts/test.sh). In a network namespace of its own (loopback only:
//! LSL discovery multicasts and broadcasts), a server with its controller runs a synthetic
//! subject's practice and first test at a station; the client resolves the station's signal
//! and marker streams, and receives every tick of both tests (as many samples as the stored
//! records have rows, each value the record's within its export rounding), the channels'
//! labels and units, the study, station and subject, the markers of the tests, the survey,
//! the redo and the E-stop in order, and liblsl's clock offset to our outlets is under 1 ms.

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use bdft_controller::lsl::streams::SIGNAL_CHANNELS;
use bdft_protocol::trial::RECORD_CHANNELS;
use bdft_tests::exports::parse_csv;
use bdft_tests::server::{
    Server, dry_run, eventually, run_trial, short_study, synthetic_at_a_station, trial_rows,
};
use bdft_tests::{send_signal, unshare_network, venv_tool};
use serde_json::{Value, json};

/// Set in the copy of this test that runs inside the namespace.
const IN_NAMESPACE: &str = "BDFT_TEST_IN_NETNS";

fn python() -> PathBuf {
    venv_tool("pylsl", "python", "pylsl==1.18.6")
}

/// Whether this is the copy of test `name` inside its namespace (checked isolated); else
/// runs that copy, failing with its output when it fails.
fn isolated(name: &str) -> bool {
    if std::env::var_os(IN_NAMESPACE).is_none() {
        in_network_namespace(name);
        return false;
    }
    assert_isolated();
    true
}

/// A server with its controller publishing the stations' LSL streams.
fn lsl_server(name: &str) -> Server {
    Server::start_with(
        name,
        &[
            "--admin-password",
            bdft_tests::server::ADMIN_PASSWORD,
            "--lsl",
        ],
    )
}

/// The independent reader of station `station`'s streams (tests/scripts/lsl_client.py).
fn client(station: i64) -> Child {
    Command::new(python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/lsl_client.py"))
        .arg(station.to_string())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// What the client wrote to its standard error, up to its exit.
fn errors(client: &mut Child) -> String {
    let mut err = String::new();
    client
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    err
}

/// Runs the test named `name` of this binary again inside a new network namespace with only
/// loopback up, and fails with its output when it fails. The product's default scope keeps
/// its LSL traffic on this host; the namespace keeps every query of the client's liblsl
/// (which multicasts and broadcasts at site scope) off the machine's networks too.
fn in_network_namespace(name: &str) {
    let out = unshare_network()
        .args(["sh", "-c", "ip link set lo up && exec \"$@\"", "sh"])
        .arg(std::env::current_exe().unwrap())
        .args([name, "--exact", "--nocapture", "--test-threads=1"])
        .env(IN_NAMESPACE, "1")
        .output()
        .expect("unshare runs (util-linux) and ip (iproute2)");
    assert!(
        out.status.success() && String::from_utf8_lossy(&out.stdout).contains("1 passed"),
        "the test in its namespace failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    print!("{}", String::from_utf8_lossy(&out.stdout));
}

/// Refuses to go on outside a namespace whose only interface is loopback.
fn assert_isolated() {
    // /proc/net/dev lists the interfaces of this process's namespace (/sys is the host's
    // until remounted).
    let interfaces: Vec<String> = std::fs::read_to_string("/proc/net/dev")
        .unwrap()
        .lines()
        .filter_map(|l| l.split_once(':').map(|(name, _)| name.trim().to_string()))
        .collect();
    assert_eq!(
        interfaces,
        ["lo"],
        "LSL runs only in a loopback-only namespace"
    );
}

#[test]
fn pylsl_receives_every_sample_and_marker_of_a_test_with_its_labels_and_clock() {
    if !isolated("lsl::pylsl_receives_every_sample_and_marker_of_a_test_with_its_labels_and_clock")
    {
        return;
    }
    let server = lsl_server("lsl");
    let api = server.experimenter();
    // Synthetic subjects go into a study's dry-run copy.
    let study = dry_run(&api, short_study(&api, 3.0, 1.0));
    // The assignment publishes the station's streams: the client connects before any test.
    let (enrolled, station, station_api) = synthetic_at_a_station(&api, study);
    let subject = enrolled["id"].as_i64().unwrap();
    let code = enrolled["code"].as_str().unwrap().to_string();
    assert!(
        lsl_ports_bound().contains(&16571),
        "the streams answer discovery (and the probe of the other test sees them)"
    );

    let mut client = client(station);
    let mut lines = BufReader::new(client.stdout.take().unwrap()).lines();
    let ready = lines.next().and_then(Result::ok);
    if ready.as_deref() != Some("ready") {
        panic!(
            "the client did not open the streams ({ready:?}): {}",
            errors(&mut client)
        );
    }

    // The practice (1 s at the desk) and the first test (3 s on the machine), its survey, a
    // redo of it, and the E-stop, which ends the client's reading.
    let trials = trial_rows(&api, subject);
    let (practice, first) = (&trials[0], &trials[1]);
    let mut ran = Vec::new();
    for t in [practice, first] {
        let id = t["id"].as_i64().unwrap();
        let done = run_trial(&api, subject, id);
        assert_eq!(done["status"], "complete", "{done}");
        ran.push(done);
    }
    let first_id = first["id"].as_i64().unwrap();
    station_api.ok(
        "/api/station/survey",
        json!({ "trial_id": first_id, "accuracy": 5, "speed": 4, "smoothness": 3, "controllability": 6, "comment": "" }),
    );
    let redone = api.ok(
        &format!("/api/trials/{first_id}/redo"),
        json!({ "reason": "for the LSL test" }),
    );
    api.ok("/api/estop", json!({}));

    let report = lines
        .next()
        .and_then(Result::ok)
        .unwrap_or_else(|| panic!("the client printed no report"));
    assert!(client.wait().unwrap().success());
    let report: Value = serde_json::from_str(&report).unwrap();

    // The descriptions.
    let signal = &report["signal"];
    assert_eq!(signal["nominal_srate"], 1000.0);
    assert_eq!(signal["channel_format"], 1, "float32 (pylsl's cf_float32)");
    let units: Vec<&str> = SIGNAL_CHANNELS
        .iter()
        .map(|n| RECORD_CHANNELS.iter().find(|c| c.name == *n).unwrap().unit)
        .collect();
    let expected: Vec<Value> = SIGNAL_CHANNELS
        .iter()
        .zip(&units)
        .map(|(l, u)| json!([l, u]))
        .collect();
    assert_eq!(signal["channels"], json!(expected));
    assert_eq!(units, ["mm", "mm", "mm", "mm/s²", "1"]);
    for stream in [signal, &report["marker"]] {
        let meta = &stream["bdft"];
        let name = meta["study"].as_str().unwrap_or_default();
        assert!(name.starts_with("end-to-end"), "{stream}");
        assert_eq!(meta["study_id"], study.to_string());
        assert_eq!(meta["station"], "station-both");
        assert_eq!(meta["station_id"], station.to_string());
        assert_eq!(meta["subject"], code.as_str());
    }
    assert_eq!(report["marker"]["type"], "Markers");

    // Every tick of both tests, in order, equal to the stored records.
    let (status, csv) = api.get_text(&format!("/api/studies/{study}/export/samples"));
    assert_eq!(status, 200);
    let rows = parse_csv(&csv);
    let header = &rows[0];
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    let trial_col = col("trial_id");
    let mut stored: Vec<&Vec<String>> = Vec::new();
    for t in &ran {
        let id = t["id"].as_i64().unwrap().to_string();
        let of_trial: Vec<&Vec<String>> = rows[1..].iter().filter(|r| r[trial_col] == id).collect();
        let expected_ticks = (t["duration_s"].as_f64().unwrap() * 1000.0).round() as usize;
        assert_eq!(
            of_trial.len(),
            expected_ticks,
            "trial {id}: a record row per tick"
        );
        stored.extend(of_trial);
    }
    let samples = report["samples"].as_array().unwrap();
    assert_eq!(samples.len(), stored.len(), "every tick, none twice");
    for (k, (sample, row)) in samples.iter().zip(&stored).enumerate() {
        for (i, name) in SIGNAL_CHANNELS.iter().enumerate() {
            let got = sample[i + 1].as_f64().unwrap();
            let want: f64 = row[col(name)].parse().unwrap();
            let decimals = RECORD_CHANNELS
                .iter()
                .find(|c| c.name == *name)
                .unwrap()
                .decimals;
            // The export rounds to the channel's decimals; the stream is the stored f32.
            let tolerance = 0.5 * 10f64.powi(-i32::from(decimals)) + want.abs() * 1.2e-7;
            assert!(
                (got - want).abs() <= tolerance,
                "sample {k}, {name}: streamed {got}, stored {want}"
            );
        }
    }
    // Stamped with the loop's ticks: a millisecond apart within each test.
    let stamps: Vec<f64> = samples.iter().map(|s| s[0].as_f64().unwrap()).collect();
    let mut steps: Vec<f64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    steps.sort_by(f64::total_cmp);
    let median = steps[steps.len() / 2];
    assert!((median - 1e-3).abs() < 1e-4, "median step {median} s");

    // The markers, in order.
    let markers: Vec<Value> = report["markers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| serde_json::from_str(m[1].as_str().unwrap()).unwrap())
        .collect();
    let events: Vec<&str> = markers
        .iter()
        .map(|m| m["event"].as_str().unwrap())
        .collect();
    assert_eq!(
        events,
        [
            "test_start",
            "test_end",
            "test_start",
            "test_end",
            "survey",
            "redo",
            "e_stop"
        ],
        "{markers:?}"
    );
    for (m, t) in [(&markers[0], &ran[0]), (&markers[2], &ran[1])] {
        assert_eq!(m["trial_id"], t["id"]);
        assert_eq!(m["label"], t["blinded_label"]);
        assert_eq!(m["seat"], t["station"]);
    }
    assert_eq!(markers[0]["phase"], "practice");
    assert_eq!(markers[2]["phase"], "test");
    assert_eq!(markers[1]["status"], "complete");
    assert_eq!(markers[4]["trial_id"], first_id);
    assert_eq!(markers[5]["new_trial_id"], redone["id"]);
    // Each test's markers bracket its samples.
    let marker_stamps: Vec<f64> = report["markers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m[0].as_f64().unwrap())
        .collect();
    assert!(marker_stamps[1] > stamps[999] && marker_stamps[3] > stamps[stamps.len() - 1]);

    // liblsl's clock offset to our outlets.
    for offset in report["offsets_s"].as_array().unwrap() {
        let offset = offset.as_f64().unwrap();
        assert!(offset.abs() < 1e-3, "clock offset {offset} s");
    }
    println!(
        "LSL: {} samples, {} markers, median step {median} s, clock offsets {} s",
        samples.len(),
        markers.len(),
        report["offsets_s"]
    );
}

#[test]
fn a_controller_that_restarts_publishes_the_stations_signal_stream_again() {
    if !isolated("lsl::a_controller_that_restarts_publishes_the_stations_signal_stream_again") {
        return;
    }
    let server = lsl_server("lsl-restart");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 3.0, 1.0));
    // The assignment publishes the station's streams on this controller; it dies, and its
    // successor (started by the server's supervisor) knows nothing of them until told again.
    let (_, station, _) = synthetic_at_a_station(&api, study);
    let pid = api.get("/api/controller").1["pid"].as_u64().unwrap();
    send_signal(pid as u32, "KILL").unwrap();
    eventually(Duration::from_secs(20), || {
        let (_, c) = api.get("/api/controller");
        (c["connected"] == true && c["pid"].as_u64().is_some_and(|p| p != pid)).then_some(())
    });
    // A reader finds both of the station's streams, before any test.
    let mut client = client(station);
    let ready = BufReader::new(client.stdout.take().unwrap())
        .lines()
        .next()
        .and_then(Result::ok);
    // The E-stop's marker ends the client's reading either way.
    api.ok("/api/estop", json!({}));
    let err = errors(&mut client);
    let _ = client.wait();
    assert_eq!(ready.as_deref(), Some("ready"), "{err}");
}

/// The ports LSL uses (the discovery port 16571 and the range from 16572) that a socket of
/// this namespace has bound, from /proc/net/{udp,tcp}{,6}.
fn lsl_ports_bound() -> Vec<u16> {
    let mut ports = Vec::new();
    for table in ["udp", "udp6", "tcp", "tcp6"] {
        let text = std::fs::read_to_string(format!("/proc/net/{table}")).unwrap_or_default();
        for line in text.lines().skip(1) {
            let local = line.split_whitespace().nth(1).unwrap_or_default();
            let port = local
                .rsplit_once(':')
                .and_then(|(_, p)| u16::from_str_radix(p, 16).ok());
            ports.extend(port.filter(|p| (16571..16572 + 32).contains(p)));
        }
    }
    ports
}

#[test]
fn without_lsl_no_lsl_socket_is_opened() {
    if !isolated("lsl::without_lsl_no_lsl_socket_is_opened") {
        return;
    }
    let server = Server::start("no-lsl");
    let api = server.experimenter();
    let study = dry_run(&api, short_study(&api, 3.0, 1.0));
    let (enrolled, _, _) = synthetic_at_a_station(&api, study);
    let subject = enrolled["id"].as_i64().unwrap();
    let practice = trial_rows(&api, subject)[0]["id"].as_i64().unwrap();
    assert_eq!(run_trial(&api, subject, practice)["status"], "complete");
    assert_eq!(lsl_ports_bound(), Vec::<u16>::new());
}
