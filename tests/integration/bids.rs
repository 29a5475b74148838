//! The BIDS export of a pilot, checked by the BIDS validator (PyPI's bids-validator-deno,
//! installed by scripts/test.sh, run offline in its own network namespace): 0 errors, and a
//! copy with a required sidecar key removed fails, proving the validator read our files.
//! Then what the validator does not check: each run's channels are its motion columns, its
//! rows are rate × duration (± 1) with the duration from the trials export, the scans list
//! exactly the motion files, participants are pseudonymous codes only, and the dashboard's
//! zip holds the same files as the command line's directory.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use bdft_tests::exports::parse_csv;

use crate::exports_audit::column;
use bdft_tests::server::{Server, pilot_copy, short_study};
use bdft_tests::{TempDir, server_command, server_output, unshare_network, venv_tool};
use serde_json::{Value, json};

fn validator() -> PathBuf {
    venv_tool(
        "bids-validator",
        "bids-validator-deno",
        "bids-validator-deno==3.0.2",
    )
}

/// The validator's issues of severity `error` as `CODE subCode location`, offline: in a
/// network namespace of its own with nothing but loopback.
fn validation_errors(dataset: &Path) -> Vec<String> {
    let out = unshare_network()
        .arg(validator())
        .args(["--format", "json", "--max-rows", "-1"])
        .arg(dataset)
        .output()
        .expect("unshare runs (util-linux)");
    let report: Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "the validator's report is no JSON ({e}); exit {:?}, stderr: {}",
            out.status.code(),
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let issues = report["issues"]["issues"]
        .as_array()
        .expect("the report lists issues");
    let errors: Vec<String> = issues
        .iter()
        .filter(|i| i["severity"] == "error")
        .map(|i| format!("{} {} {}", i["code"], i["subCode"], i["location"]))
        .collect();
    assert_eq!(
        out.status.success(),
        errors.is_empty(),
        "the validator's exit status agrees with its report: {errors:?}"
    );
    errors
}

fn tsv(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .map(|l| l.split('\t').map(str::to_string).collect())
        .collect()
}

fn files_under(root: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let path = e.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                let name = path
                    .strip_prefix(root)
                    .unwrap()
                    .to_string_lossy()
                    .into_owned();
                out.insert(name, std::fs::read(&path).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(root, root, &mut out);
    out
}

#[test]
fn a_pilots_bids_export_passes_the_validator_and_holds_every_run() {
    let server = Server::start("bids");
    let api = server.experimenter();
    let study = short_study(&api, 3.0, 1.0);
    let copy = pilot_copy(&api, study, 2);
    let dir = TempDir::new("bids-out");
    let dataset = dir.path().join("dataset");
    let db = server.store();
    let copy_arg = copy.to_string();
    let export_args = |out: &Path| {
        let args: [&str; 9] = [
            "export",
            "--db",
            &db,
            "--study",
            &copy_arg,
            "--kind",
            "bids",
            "--out",
            out.to_str().unwrap(),
        ];
        args.map(String::from)
    };
    let out = server_command(export_args(&dataset));
    let written: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(written["subjects"], 2, "{written}");
    assert!(!dir.path().join("dataset.partial").exists());

    // The validator: no error.
    assert_eq!(validation_errors(&dataset), Vec::<String>::new());

    // The trials export says which attempts were recorded and how long each test was.
    let (code, text) = api.get_text(&format!("/api/studies/{copy}/export/trials"));
    assert_eq!(code, 200);
    let trials = parse_csv(&text);
    let c = |name| column(&trials, name);
    let by_id: BTreeMap<&str, &Vec<String>> = trials[1..]
        .iter()
        .map(|r| (r[c("trial_id")].as_str(), r))
        .collect();

    // Every run: channels = motion columns, rows = rate × duration, events name its trial.
    let mut runs = 0;
    let mut recorded_ids = Vec::new();
    for (name, _) in files_under(&dataset) {
        let Some(stem) = name.strip_suffix("_motion.tsv") else {
            continue;
        };
        runs += 1;
        let motion = tsv(&dataset.join(&name));
        let channels = tsv(&dataset.join(format!("{stem}_channels.tsv")));
        assert_eq!(
            channels[0][..5],
            ["name", "component", "type", "tracked_point", "units"]
        );
        assert!(
            motion.iter().all(|r| r.len() == channels.len() - 1),
            "{name}: a row's columns ≠ the channels"
        );
        let sidecar: Value = serde_json::from_slice(
            &std::fs::read(dataset.join(format!("{stem}_motion.json"))).unwrap(),
        )
        .unwrap();
        let rate = sidecar["SamplingFrequency"].as_f64().unwrap();
        assert_eq!(rate, 1000.0, "{name}");
        let events_name = stem.replace("_tracksys-rig", "") + "_events.tsv";
        let events = tsv(&dataset.join(&events_name));
        assert_eq!(
            events[0][..4],
            ["onset", "duration", "trial_type", "trial_id"]
        );
        let trial_id = events[1][3].clone();
        let row = by_id[trial_id.as_str()];
        assert_eq!(events[1][2], row[c("phase")], "{events_name}");
        if row[c("status")] == "complete" {
            let duration: f64 = row[c("duration_s")].parse().unwrap();
            let expected = rate * duration;
            assert!(
                (motion.len() as f64 - expected).abs() <= 1.0,
                "{name}: {} rows, {rate} Hz × {duration} s = {expected}",
                motion.len()
            );
        }
        recorded_ids.push(trial_id);
    }
    assert!(runs >= 2 * 2, "two subjects, two sessions: {runs} runs");
    assert_eq!(written["runs"], runs);
    recorded_ids.sort();
    recorded_ids.dedup();
    assert_eq!(recorded_ids.len(), runs, "one run per recorded attempt");

    // Scans list exactly the motion files of their session.
    let all = files_under(&dataset);
    for (name, _) in all.iter().filter(|(n, _)| n.ends_with("_scans.tsv")) {
        let session = Path::new(name).parent().unwrap();
        let mut listed: Vec<String> = tsv(&dataset.join(name))[1..]
            .iter()
            .map(|r| session.join(&r[0]).to_string_lossy().into_owned())
            .collect();
        listed.sort();
        let present: Vec<&String> = all
            .keys()
            .filter(|n| n.starts_with(&*session.to_string_lossy()) && n.ends_with("_motion.tsv"))
            .collect();
        assert_eq!(listed.iter().collect::<Vec<_>>(), present, "{name}");
    }

    // Participants: the pseudonymous codes only.
    let participants = tsv(&dataset.join("participants.tsv"));
    assert_eq!(
        participants[0],
        [
            "participant_id",
            "code",
            "synthetic",
            "starting_station",
            "consent_version"
        ]
    );
    let codes: Vec<&str> = participants[1..].iter().map(|r| r[1].as_str()).collect();
    assert_eq!(codes, ["S01", "S02"]);
    let description: Value = serde_json::from_slice(&all["dataset_description.json"]).unwrap();
    assert_eq!(description["GeneratedBy"][0]["Name"], "bdft-lab");

    // A required key removed: the validator fails, naming it.
    let broken = dir.path().join("broken");
    for (name, bytes) in &all {
        let path = broken.join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, bytes).unwrap();
    }
    let first_run = all
        .keys()
        .find(|n| n.ends_with("_motion.json") && n.starts_with("sub-"))
        .unwrap();
    let mut sidecar: Value = serde_json::from_slice(&all[first_run]).unwrap();
    sidecar.as_object_mut().unwrap().remove("SamplingFrequency");
    std::fs::write(broken.join(first_run), sidecar.to_string()).unwrap();
    let errors = validation_errors(&broken);
    assert!(
        errors
            .iter()
            .any(|e| e.contains("SIDECAR_KEY_REQUIRED") && e.contains("SamplingFrequency")),
        "{errors:?}"
    );

    // The dashboard's zip: the same files, in one folder.
    let (code, zip) = api.get_bytes(&format!("/api/studies/{copy}/bids.zip"));
    assert_eq!(code, 200);
    let zip_path = dir.path().join("bids.zip");
    std::fs::write(&zip_path, zip).unwrap();
    let unzipped = dir.path().join("unzipped");
    let out = Command::new("python3")
        .args(["-c", "import sys, zipfile; z = zipfile.ZipFile(sys.argv[1]); assert z.testzip() is None; z.extractall(sys.argv[2])"])
        .arg(&zip_path)
        .arg(&unzipped)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let folders: Vec<PathBuf> = std::fs::read_dir(&unzipped)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(folders.len(), 1, "{folders:?}");
    assert_eq!(
        files_under(&folders[0]),
        all,
        "the zip holds the directory's files"
    );

    // Bad requests: an existing directory, a study without a recorded test.
    let again = server_output(export_args(&dataset));
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("never overwrites"));
    let empty = short_study(&api, 3.0, 1.0).to_string();
    let none = server_output([
        "export",
        "--db",
        &db,
        "--study",
        &empty,
        "--kind",
        "bids",
        "--out",
        dir.path().join("none").to_str().unwrap(),
    ]);
    assert!(!none.status.success());
    assert!(
        String::from_utf8_lossy(&none.stderr).contains("has no recorded test"),
        "{}",
        String::from_utf8_lossy(&none.stderr)
    );
    assert!(!dir.path().join("none").exists() && !dir.path().join("none.partial").exists());
    let (code, body) = api.get(&format!("/api/studies/{empty}/bids.zip"));
    assert_eq!(code, 422, "{body}");
    // The dashboard's export is in the audit log.
    let (_, log) = api.get("/api/audit?limit=20");
    assert!(
        log.as_array()
            .unwrap()
            .iter()
            .any(|e| e["action"] == "export"
                && e["detail"] == json!({ "kind": "bids" })
                && e["target"] == format!("study:{copy}")),
        "{log}"
    );
}
