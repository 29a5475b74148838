//! The names and contents of a BIDS dataset's files: labels and paths, the TSV tables and
//! their JSON sidecars. Every column of a table is described by the same definitions the
//! tidy exports and the codebook use (`columns`), so the two cannot drift apart.

use std::collections::{BTreeMap, BTreeSet};

use bdft_protocol::study::SurveyParams;
use bdft_protocol::trial::{RECORD_CHANNELS, RecordColumn};
use serde::Serialize;

use super::super::columns::{self, Column};
use super::super::sink::tsv_cell;
use super::super::tables::trial_cells;
use super::{TASK, TRACKSYS};
use crate::store::db::rfc3339;
use crate::store::exports::{SubjectExportRow, TrialExportRow};
use crate::store::records::Record;
use crate::store::studies::Study;

/// The BIDS version the dataset follows.
const BIDS_VERSION: &str = "1.10.0";

/// Each remaining subject's BIDS label (code → label): the code's letters and digits (BIDS
/// labels are alphanumeric); a code with none, or whose label another code already took,
/// gets `x` and its enrolment number.
pub fn participant_labels<'a>(
    subjects: impl Iterator<Item = &'a SubjectExportRow>,
) -> BTreeMap<String, String> {
    let mut taken = BTreeSet::new();
    let mut labels = BTreeMap::new();
    for s in subjects {
        let alnum: String = s.code.chars().filter(char::is_ascii_alphanumeric).collect();
        let mut label = alnum.clone();
        let mut n = s.enrol_index + 1;
        while label.is_empty() || taken.contains(&label) {
            label = format!("x{n}");
            n += 1_000_000;
        }
        taken.insert(label.clone());
        labels.insert(s.code.clone(), label);
    }
    labels
}

/// One run: a recorded test attempt of a subject in a session.
pub struct Run<'a> {
    pub label: &'a str,
    pub session: &'a str,
    pub number: usize,
}

impl Run<'_> {
    fn dir(&self) -> String {
        format!("sub-{}/ses-{}/motion", self.label, self.session)
    }

    /// `sub-S01_ses-on_task-tracking`: the entities every file of the run starts with.
    fn entities(&self) -> String {
        format!("sub-{}_ses-{}_task-{TASK}", self.label, self.session)
    }

    fn motion_name(&self, suffix: &str) -> String {
        format!(
            "{}_tracksys-{TRACKSYS}_run-{}_{suffix}",
            self.entities(),
            self.number
        )
    }

    /// The path of the run's motion file `suffix` (`motion.tsv`, `channels.tsv`,
    /// `motion.json`) from the dataset's root.
    pub fn motion_file(&self, suffix: &str) -> String {
        format!("{}/{}", self.dir(), self.motion_name(suffix))
    }

    /// The path of the run's events (which BIDS names without the tracking system).
    pub fn events_file(&self) -> String {
        format!(
            "{}/{}_run-{}_events.tsv",
            self.dir(),
            self.entities(),
            self.number
        )
    }

    /// The motion file's name as the session's `_scans.tsv` lists it (from the session).
    pub fn scan_name(&self) -> String {
        format!("motion/{}", self.motion_name("motion.tsv"))
    }
}

/// A sidecar as the file holds it: pretty JSON ending in a newline.
fn pretty(v: &impl Serialize) -> Vec<u8> {
    let mut bytes = serde_json::to_vec_pretty(v).unwrap_or_default();
    bytes.push(b'\n');
    bytes
}

fn hash_text(study: &Study) -> String {
    study
        .protocol_hash
        .as_deref()
        .map_or_else(|| "not locked".into(), |h| format!("SHA-256 {h}"))
}

#[derive(Serialize)]
#[serde(rename_all = "PascalCase")]
struct DatasetDescription<'a> {
    name: &'a str,
    #[serde(rename = "BIDSVersion")]
    bids_version: &'static str,
    dataset_type: &'static str,
    generated_by: [GeneratedBy; 1],
}

#[derive(Serialize)]
#[serde(rename_all = "PascalCase")]
struct GeneratedBy {
    name: &'static str,
    version: &'static str,
    description: String,
}

pub fn dataset_description(study: &Study) -> Vec<u8> {
    pretty(&DatasetDescription {
        name: &study.name,
        bids_version: BIDS_VERSION,
        dataset_type: "raw",
        generated_by: [GeneratedBy {
            name: "bdft-lab",
            version: env!("CARGO_PKG_VERSION"),
            description: format!(
                "bdft-server export --kind bids of study {} (protocol hash: {})",
                study.id,
                hash_text(study)
            ),
        }],
    })
}

/// A column as a sidecar describes it.
#[derive(Serialize)]
#[serde(rename_all = "PascalCase")]
struct Described {
    description: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    units: Option<String>,
    #[serde(skip_serializing_if = "Vec::is_empty", serialize_with = "as_map")]
    levels: Vec<(&'static str, &'static str)>,
}

fn as_map<S: serde::Serializer>(
    levels: &[(&'static str, &'static str)],
    s: S,
) -> Result<S::Ok, S::Error> {
    s.collect_map(levels.iter().copied())
}

fn described(description: &str) -> Described {
    Described {
        description: description.into(),
        units: None,
        levels: Vec::new(),
    }
}

fn with_levels(description: &str, levels: &[(&'static str, &'static str)]) -> Described {
    Described {
        levels: levels.to_vec(),
        ..described(description)
    }
}

pub fn readme(study: &Study) -> String {
    format!(
        "# {name}\n\n\
         Manual tracking of a random-step target with a hydraulic machine's compensators, on the \
         machine (session `on`, the operator riding it: biodynamic feedthrough) and at a desk \
         beside it (session `off`). Exported by bdft-lab {version} from study {id}; protocol \
         hash: {hash}.\n\n\
         - `participants.tsv`: pseudonymous subject codes only.\n\
         - `sub-*/ses-*/motion/`: one run per recorded test attempt (practice included), the \
         full-rate record of the rig as BIDS motion data, with the attempt's events.\n\
         - `sub-*/ses-*/beh/`: one row per test attempt: status, tracking error, cab \
         acceleration and the subject's ratings (`task-{TASK}_beh.json` describes every column).\n\
         - `sub-*/ses-*/*_scans.tsv`: when each run was recorded.\n",
        name = study.name,
        version = env!("CARGO_PKG_VERSION"),
        id = study.id,
        hash = hash_text(study),
    )
}

pub fn participants_json() -> Vec<u8> {
    let columns: BTreeMap<&str, Described> = [
        (
            "participant_id",
            described("BIDS label of the subject's pseudonymous code"),
        ),
        (
            "code",
            described("the subject's pseudonymous code in the study"),
        ),
        (
            "synthetic",
            with_levels(
                "whether the subject is simulated (a pilot's synthetic subject)",
                &[("0", "a person"), ("1", "simulated")],
            ),
        ),
        (
            "starting_station",
            with_levels(
                "the station the subject's schedule started at",
                &[("on", "on the machine"), ("off", "at the desk beside it")],
            ),
        ),
        (
            "consent_version",
            described("version of the consent form the subject answered"),
        ),
    ]
    .into_iter()
    .collect();
    pretty(&columns)
}

pub fn participants_tsv(
    subjects: &[SubjectExportRow],
    labels: &BTreeMap<String, String>,
) -> String {
    let mut out =
        String::from("participant_id\tcode\tsynthetic\tstarting_station\tconsent_version\n");
    for s in subjects {
        let Some(label) = labels.get(&s.code) else {
            continue;
        };
        out.push_str(&format!(
            "sub-{label}\t{}\t{}\t{}\t{}\n",
            one_line(&s.code),
            u8::from(s.synthetic),
            s.starting_seat,
            s.consent_version.as_deref().map_or("n/a".into(), one_line),
        ));
    }
    out
}

fn one_line(s: &str) -> String {
    s.replace(['\t', '\n', '\r'], " ")
}

/// A record channel as BIDS motion describes it: type, component, tracked point, units.
fn motion_channel(c: &RecordColumn) -> [&'static str; 4] {
    match c.name {
        "target_mm" => ["POS", "x", "target", "mm"],
        "hand_mm" | "feedthrough_mm" => ["POS", "x", "hand", "mm"],
        "cyl_ref_mm" | "cyl_pos_mm" => ["POS", "x", "cylinder", "mm"],
        "device_mm" | "cancellation_mm" => ["POS", "x", "device", "mm"],
        "cab_accel_mm_s2" => ["ACCEL", "x", "cab", "mm/s^2"],
        "tick_latency_us" => ["LATENCY", "n/a", "n/a", "us"],
        // A channel this list does not know yet is still exported, as a miscellaneous one.
        _ => ["MISC", "n/a", "n/a", "n/a"],
    }
}

pub fn channels_tsv() -> Vec<u8> {
    let mut out = String::from("name\tcomponent\ttype\ttracked_point\tunits\tdescription\n");
    for c in &RECORD_CHANNELS {
        let [ty, component, point, units] = motion_channel(c);
        out.push_str(&format!(
            "{}\t{component}\t{ty}\t{point}\t{units}\t{}\n",
            c.name, c.meaning
        ));
    }
    out.into_bytes()
}

/// The channel types of BIDS motion (the ones `motion_channel` gives among them).
const MOTION_TYPES: [&str; 10] = [
    "ACCEL", "ANGACCEL", "GYRO", "JNTANG", "LATENCY", "MAGN", "MISC", "ORNT", "POS", "VEL",
];

/// The motion sidecar every run inherits: the task and the channels.
#[derive(Serialize)]
#[serde(rename_all = "PascalCase")]
struct TaskMotion {
    task_name: &'static str,
    task_description: &'static str,
    instructions: String,
    tracking_system_name: &'static str,
    motion_channel_count: usize,
    tracked_points_count: usize,
    /// `POSChannelCount`, `ACCELChannelCount`, …: one per channel type.
    #[serde(flatten)]
    channel_counts: BTreeMap<String, usize>,
    missing_values: &'static str,
    software_versions: String,
}

pub fn task_motion_json(study: &Study) -> Vec<u8> {
    // Every channel type BIDS motion knows is counted, the absent ones as 0.
    let mut channel_counts: BTreeMap<String, usize> = MOTION_TYPES
        .iter()
        .map(|ty| (format!("{ty}ChannelCount"), 0))
        .collect();
    let mut points = BTreeSet::new();
    for c in &RECORD_CHANNELS {
        let [ty, _, point, _] = motion_channel(c);
        *channel_counts
            .entry(format!("{ty}ChannelCount"))
            .or_default() += 1;
        if point != "n/a" {
            points.insert(point);
        }
    }
    pretty(&TaskMotion {
        task_name: TASK,
        task_description: "pursuit tracking of a random-step target with a hydraulic cylinder through an input device",
        instructions: study
            .params
            .rendered_texts()
            .map(|(_, t)| t.instructions)
            .unwrap_or_else(|_| study.params.texts.instructions.clone()),
        tracking_system_name: "bdft-lab rig: the machine's sensors, or the validated simulation of them",
        motion_channel_count: RECORD_CHANNELS.len(),
        tracked_points_count: points.len(),
        channel_counts,
        missing_values: "n/a",
        software_versions: format!("bdft-lab {}", env!("CARGO_PKG_VERSION")),
    })
}

/// The run's own motion sidecar: its rate and length.
#[derive(Serialize)]
#[serde(rename_all = "PascalCase")]
struct RunMotion {
    task_name: &'static str,
    sampling_frequency: f64,
    recording_duration: f64,
}

pub fn run_motion_json(record: &Record) -> Vec<u8> {
    let samples = record.channels.first().map_or(0, Vec::len);
    pretty(&RunMotion {
        task_name: TASK,
        sampling_frequency: sampling_frequency(record.dt),
        recording_duration: samples as f64 * record.dt,
    })
}

/// Samples a second, rounded to what the period's f64 means (1000, not 999.9999999).
fn sampling_frequency(dt: f64) -> f64 {
    if dt > 0.0 {
        (1e6 / dt).round() / 1e6
    } else {
        0.0
    }
}

/// The event columns after BIDS's `onset`, `duration` and `trial_type`.
const EVENT_COLUMNS: [(&str, &str); 8] = [
    ("trial_id", "the attempt's trial_id in the trials export"),
    (
        "attempt",
        "attempt number of the test (a redo is a new attempt)",
    ),
    (
        "controller",
        "compensator the test ran (n/a for the practice)",
    ),
    (
        "blinded_label",
        "the compensator's label as the subject saw it (n/a for the practice)",
    ),
    (
        "status",
        "how the attempt ended: complete, aborted, faulted, incomplete, invalid",
    ),
    ("status_reason", "why, when it did not complete"),
    (
        "valid",
        "1 when the attempt is a completed test that the analyses may count",
    ),
    ("latest", "1 when it is the latest attempt of its test"),
];

pub fn events_json() -> Vec<u8> {
    let mut columns: BTreeMap<&str, Described> = EVENT_COLUMNS
        .into_iter()
        .map(|(name, meaning)| (name, described(meaning)))
        .collect();
    columns.insert(
        "trial_type",
        with_levels(
            "the phase of the attempt",
            &[
                ("practice", "practice before the scored tests"),
                ("test", "a scored test"),
                (
                    "identification",
                    "the cab moved by a multisine while the subject held the device (unscored)",
                ),
            ],
        ),
    );
    pretty(&columns)
}

/// The attempt as one event from the record's start over its length.
pub fn events_tsv(row: &TrialExportRow, record: &Record) -> Vec<u8> {
    let samples = record.channels.first().map_or(0, Vec::len);
    let mut out = String::from("onset\tduration\ttrial_type");
    for (name, _) in EVENT_COLUMNS {
        out.push('\t');
        out.push_str(name);
    }
    let test_only = |s: &str| {
        if row.phase.scored() {
            one_line(s)
        } else {
            "n/a".to_string()
        }
    };
    let cells = [
        row.trial_id.to_string(),
        row.attempt.to_string(),
        test_only(row.controller.name()),
        test_only(&row.blinded_label),
        row.status.as_str().to_string(),
        row.status_reason.as_deref().map_or("n/a".into(), one_line),
        u8::from(crate::engine::results::study_data::valid(row)).to_string(),
        u8::from(row.latest).to_string(),
    ];
    out.push_str(&format!(
        "\n0\t{}\t{}",
        bdft_protocol::numbers::format_number(samples as f64 * record.dt, 3),
        row.phase.as_str()
    ));
    for c in cells {
        out.push('\t');
        out.push_str(&c);
    }
    out.push('\n');
    out.into_bytes()
}

/// The behaviour sidecar: the task, and every column as the codebook describes it.
#[derive(Serialize)]
struct BehSidecar {
    #[serde(rename = "TaskName")]
    task_name: &'static str,
    #[serde(flatten)]
    columns: BTreeMap<String, Described>,
}

pub fn beh_json(study: &Study) -> Vec<u8> {
    let columns = columns::trials(&study.params.survey)
        .into_iter()
        .map(|c| {
            let units = (!c.unit.is_empty() && c.unit != "1").then(|| c.unit.to_string());
            (
                c.name.to_string(),
                Described {
                    units,
                    ..described(&c.meaning)
                },
            )
        })
        .collect();
    pretty(&BehSidecar {
        task_name: TASK,
        columns,
    })
}

/// One session's test attempts as the trials export's rows, in BIDS TSV.
pub fn beh_tsv(rows: &[&TrialExportRow], survey: &SurveyParams) -> String {
    let columns: Vec<Column> = columns::trials(survey);
    let mut out: String = columns
        .iter()
        .map(|c| c.name.to_string())
        .collect::<Vec<_>>()
        .join("\t");
    out.push('\n');
    for r in rows {
        let line: Vec<String> = trial_cells(r)
            .iter()
            .zip(&columns)
            .map(|(cell, c)| tsv_cell(cell, c.ty))
            .collect();
        out.push_str(&line.join("\t"));
        out.push('\n');
    }
    out
}

/// The session's runs and when each was recorded.
pub fn scans_tsv(runs: &[super::Scan]) -> String {
    let mut out = String::from("filename\tacq_time\n");
    for (name, at) in runs {
        out.push_str(&format!("{name}\t{}\n", at.map_or("n/a".into(), rfc3339)));
    }
    out
}
