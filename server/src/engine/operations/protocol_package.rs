//! The protocol package for the ethics board: one printable HTML document of a study — the
//! consent text, the station's instructions, the schedule design, the randomization, the
//! target generation, the compensators with their parameters, the surveys, the stopping
//! rules and the data kept — with the protocol hash the platform locks on every printed page
//! (the print stylesheet `web/protocol.css` repeats the header and footer).
//!
//! One source: everything is rendered from the study's parameters, the very value whose
//! canonical JSON `schedule::protocol_hash` hashes, and that JSON is printed in full at the
//! end, so a reader can recompute the hash. A locked study's document shows the hash it was
//! locked with.
//!
//! *Invariant:* every text that came from a user goes through `plots::esc`; the document
//! has no inline script or style (the pages' CSP forbids them), only `/protocol.css` and
//! `/protocol.js`.

use std::fmt::Write;

use bdft_protocol::params::{BodyModel, PlantParams, Seat};
use bdft_protocol::records::TestPhase;
use bdft_protocol::study::{
    CancellationArm, CancellationParams, MAX_COMMENT_CHARS, OrderDesign, RigKind, StudyParams,
};
use serde_json::Value;

use crate::engine::procedure::queue::MAX_ATTEMPTS;
use crate::engine::procedure::stations::{consent_form, rendered_texts};
use crate::engine::results::export::{self, ColumnType};
use crate::engine::results::plots::esc;
use crate::engine::study::schedule::{canonical_json, protocol_hash, schedule};
use crate::engine::study::williams;
use crate::store::db::rfc3339;
use crate::store::studies::Study;

/// How many subjects' schedules the document shows as examples with random orders.
const EXAMPLE_SUBJECTS: u32 = 4;

/// The hash the document prints: the locked one, or the one locking would take now.
pub fn shown_hash(study: &Study) -> String {
    study
        .protocol_hash
        .clone()
        .unwrap_or_else(|| protocol_hash(&study.params))
}

/// The package of `study`, generated at `now_ms`; `audit_key` is the public key (hex) that
/// signs the audit log's checkpoints, so the board can later check the log it was promised.
pub fn render(study: &Study, now_ms: i64, audit_key: Option<&str>) -> String {
    let p = &study.params;
    let hash = shown_hash(study);
    let now_hash = protocol_hash(p);
    let mut d = Doc::default();
    let state = match study.locked_at {
        Some(at) => format!("locked {}", rfc3339(at)),
        None => "not locked yet: this is the hash the first enrolment will lock".into(),
    };
    d.raw(&format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>Protocol package: {} ({})</title>\n\
         <link rel=\"stylesheet\" href=\"/protocol.css\">\n\
         <script type=\"module\" src=\"/protocol.js\"></script>\n</head>\n<body>\n",
        esc(&study.name),
        &hash[..12.min(hash.len())],
    ));
    // A table whose head and foot the browser repeats on every printed page.
    let running = format!(
        "<div class=\"running\">Study {} “{}” · protocol SHA-256 <code class=\"hash\">{hash}</code> · {}</div>",
        study.id,
        esc(&study.name),
        esc(&state)
    );
    d.raw(&format!(
        "<table class=\"pages\">\n<thead><tr><td>{running}</td></tr></thead>\n\
         <tfoot><tr><td><div class=\"running\">Protocol SHA-256 <code class=\"hash\">{hash}</code> · bdft-lab {} · generated {}</div></td></tr></tfoot>\n\
         <tbody><tr><td>\n<main>\n",
        env!("CARGO_PKG_VERSION"),
        rfc3339(now_ms)
    ));
    d.raw("<p class=\"no-print\"><button id=\"print\" type=\"button\">Print or save as PDF</button></p>\n");
    d.raw(&format!(
        "<h1>Protocol package: {}</h1>\n",
        esc(&study.name)
    ));
    d.table(
        &["", ""],
        [
            vec!["Study".into(), format!("{} (id {})", study.name, study.id)],
            vec!["Protocol hash (SHA-256)".into(), hash.clone()],
            vec!["Protocol".into(), state.clone()],
            vec!["Seed of every random draw".into(), study.seed.to_string()],
            vec![
                "Machine".into(),
                match p.rig {
                    RigKind::Simulated => "simulated (no machine moves; the display on the machine seat shakes with the simulated cab)".into(),
                    RigKind::Real => "the real machine".into(),
                },
            ],
            vec!["Generated".into(), rfc3339(now_ms)],
            vec![
                "Audit log signing key (Ed25519, public)".into(),
                audit_key.map_or_else(
                    || "none: rendered without a running server".into(),
                    |k| format!("{k} — every entry of the audit log is hash-chained and checkpoints of the chain are signed with this key; `bdft-server audit verify --public-key KEY` checks a copy of the database against it"),
                ),
            ],
        ],
    );
    if now_hash != hash {
        d.p_class(
            "warning",
            &format!(
                "The parameters as this release writes them hash to {now_hash}: the study was locked with {hash} by an earlier release. The parameters below are the stored ones."
            ),
        );
    }
    d.p("This document is generated from the study's parameters: the same value whose canonical JSON (Appendix) the protocol hash is the SHA-256 of. The seed is stored with the study and locked with it, but is not part of the hashed parameters.");
    consent(&mut d, study);
    instructions(&mut d, p);
    schedule_design(&mut d, p);
    randomization(&mut d, study);
    targets(&mut d, p);
    compensators(&mut d, p);
    surveys(&mut d, p);
    stopping_rules(&mut d, study);
    data_kept(&mut d, p);
    d.h2("appendix", "Appendix: the hashed parameters");
    d.p(&format!(
        "The canonical JSON of the parameters (keys sorted, no whitespace). Its SHA-256 is {now_hash}."
    ));
    d.raw(&format!(
        "<pre class=\"canonical\">{}</pre>\n",
        esc(&canonical_json(p))
    ));
    d.raw("</main>\n</td></tr></tbody>\n</table>\n</body>\n</html>\n");
    d.out
}

/// The document being written: raw markup, or text that is escaped on the way in.
#[derive(Default)]
struct Doc {
    out: String,
}

impl Doc {
    fn raw(&mut self, markup: &str) {
        self.out.push_str(markup);
    }

    fn h2(&mut self, id: &str, title: &str) {
        let _ = writeln!(self.out, "<h2 id=\"{id}\">{}</h2>", esc(title));
    }

    fn h3(&mut self, title: &str) {
        let _ = writeln!(self.out, "<h3>{}</h3>", esc(title));
    }

    fn p(&mut self, text: &str) {
        let _ = writeln!(self.out, "<p>{}</p>", esc(text));
    }

    fn p_class(&mut self, class: &str, text: &str) {
        let _ = writeln!(self.out, "<p class=\"{class}\">{}</p>", esc(text));
    }

    /// A text of the study (in its language `lang`), paragraphs separated by blank lines.
    fn study_text(&mut self, lang: &str, text: &str) {
        let _ = writeln!(
            self.out,
            "<div class=\"study-text\" lang=\"{}\">",
            esc(lang)
        );
        for para in text.split("\n\n").filter(|s| !s.trim().is_empty()) {
            self.p(para.trim());
        }
        self.raw("</div>\n");
    }

    /// A table; an empty header row is left out.
    fn table(&mut self, head: &[&str], rows: impl IntoIterator<Item = Vec<String>>) {
        self.raw("<table class=\"grid\">\n");
        if head.iter().any(|h| !h.is_empty()) {
            self.raw("<thead><tr>");
            for h in head {
                let _ = write!(self.out, "<th>{}</th>", esc(h));
            }
            self.raw("</tr></thead>\n");
        }
        self.raw("<tbody>\n");
        for row in rows {
            self.raw("<tr>");
            for cell in row {
                let _ = write!(self.out, "<td>{}</td>", esc(&cell));
            }
            self.raw("</tr>\n");
        }
        self.raw("</tbody>\n</table>\n");
    }

    fn list(&mut self, items: impl IntoIterator<Item = String>) {
        self.raw("<ul>\n");
        for i in items {
            let _ = writeln!(self.out, "<li>{}</li>", esc(&i));
        }
        self.raw("</ul>\n");
    }
}

/// A number as the document shows it: whole numbers without a decimal point, others as JSON
/// writes them (the shortest text that reads back as the same value).
fn num(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{}", v as i64)
    } else {
        Value::from(v).to_string()
    }
}

fn seat(s: Seat) -> &'static str {
    match s {
        Seat::On => "on the machine",
        Seat::Off => "at the desk",
    }
}

fn consent(d: &mut Doc, study: &Study) {
    let form = consent_form(study);
    let form_hash = bdft_protocol::hex::sha256(form.text.as_bytes());
    let kept = if study.consent_text.is_some() {
        "kept as the lock rendered it"
    } else {
        "as the first enrolment will lock it"
    };
    d.h2("consent", "Consent");
    d.p(&format!(
        "The subject reads this form (version {}) at the station before anything else and agrees or declines; a subject who declines takes no part. The form as the station shows it ({kept}), its description of the tests, the shaking and the exposure budget generated from the parameters; its text's SHA-256, which every subject's decision records, is {form_hash}:",
        form.version
    ));
    d.study_text(&study.params.texts.language, &form.text);
}

fn instructions(d: &mut Doc, p: &StudyParams) {
    let (_, t) = rendered_texts(p);
    d.h2("instructions", "Instructions and the station's texts");
    d.p(&format!(
        "What the station shows the subject besides the consent form and the survey (language: {}).",
        t.language
    ));
    for (when, text) in [
        ("Before every test, the practice included", &t.instructions),
        ("Before the practice", &t.before_practice),
        ("Before a scored test", &t.before_test),
        ("While the test waits for the experimenter", &t.ready),
        ("Moving to the seat on the machine", &t.move_to_on),
        ("Moving to the seat at the desk", &t.move_to_off),
        ("Under either move", &t.move_note),
    ] {
        d.h3(when);
        d.study_text(&t.language, text);
    }
    for (when, title, text) in [
        ("The end: every test done", &t.finished_title, &t.finished),
        ("The end: consent declined", &t.declined_title, &t.declined),
        (
            "The end: the subject withdrew",
            &t.withdrawn_title,
            &t.withdrawn,
        ),
    ] {
        d.h3(when);
        d.study_text(&t.language, &format!("{title}\n\n{text}"));
    }
}

fn schedule_design(d: &mut Doc, p: &StudyParams) {
    let k = p.compensators.len();
    let tests = p.scored_tests();
    let minutes = (p.practice_s + tests as f64 * p.trial_s) / 60.0;
    d.h2("schedule", "Schedule design");
    let mut items = Vec::new();
    if p.practice_s > 0.0 {
        items.push(format!(
            "A practice of {} s at the desk with the {} compensator, not scored.",
            num(p.practice_s),
            p.practice_compensator
        ));
    } else {
        items.push("No practice.".into());
    }
    items.extend([
        format!(
            "Within subjects: every subject runs every one of the {k} compensators {} on the machine (with feedthrough) and once at the desk beside it: {tests} scored tests of {} s.",
            match p.machine_arms().len() {
                1 => "once".to_string(),
                n => format!("{n} times (once per cancellation arm, below)"),
            },
            num(p.trial_s)
        ),
        "The first block of tests is at the starting seat, the second at the other seat; the starting seat alternates with the order of enrolment (on the machine, at the desk, on the machine, …) to balance learning effects.".into(),
        format!(
            "Tracking time about {} minutes in all; a session with the surveys and the move between seats takes longer.",
            num((minutes * 10.0).ceil() / 10.0)
        ),
        "Subjects are blind to the compensator: they see “Controller 1…k”, a numbering drawn for each subject and kept across both seats.".into(),
        "A survey follows every scored test.".into(),
    ]);
    if let Some(id) = &p.identification {
        let m = &id.excitation;
        items.push(format!(
            "An identification test of {} s first in each subject's block on the machine, not scored and without a survey: the seat is moved by a sum of {} sines between {} and {} Hz (the cylinder reference {} mm r.m.s., driven by the {} design; the subject's input is recorded but never moves the machine) while the subject is asked: “{}” It measures the subject's feedthrough; the vibration counts against the daily budget like every test on the machine.",
            num(m.duration_s()),
            m.lines,
            num(m.f_min_hz),
            num(m.f_max_hz),
            num(m.rms_mm),
            id.compensator_or(p.practice_compensator),
            id.instructions_for()
        ));
        if id.personalized {
            items.push(format!(
                "Personalized designs: the identification test comes first of all the subject's tests (on the machine, whichever seat they start at). From the body fitted to it — its gain k_h at the upper end of its 95 % interval — each LQR design is tuned to the subject: the tracking weight α as large, the cab-feedback weight β as small as keeps the design stable up to {} × K_BF on the machine and stable off it, within α/16–2α and 0–max(8, 4β) of the study's weights. The subject's tests of that design run the tuned one, recorded with every test; when no weight in the band keeps the margin, or the body could not be fitted, the subject runs the study's design, with the reason recorded.",
                num(crate::engine::study::stability::MARGIN)
            ));
        }
    }
    if let Some(c) = &p.cancellation {
        items.push(cancellation_design(p, c));
    }
    if let Some(item) = condition_design(p) {
        items.push(item);
    }
    items.extend([
        format!(
            "A test that fails (stopped, faulted, or invalid for its display) is run again at the end of its block, at most {MAX_ATTEMPTS} attempts in all, unless the experimenter accepts it as incomplete (with a reason); no test is skipped silently."
        ),
    ]);
    d.list(items);
}

/// The machine's condition as the board reads it, when it is not the thesis's rig on stilts:
/// the one the study fixes, or its factor's levels and how subjects are assigned to them.
fn condition_design(p: &StudyParams) -> Option<String> {
    let rig = match p.rig {
        RigKind::Simulated => {
            "the simulated machine is changed by the rules of docs/machine-conditions.md while the compensators stay designed for the rig on stilts"
        }
        RigKind::Real => "the lab sets the machine up so before the subject's session",
    };
    if !p.conditions.is_empty() {
        let levels: Vec<String> = p.conditions.iter().map(|c| format!("“{c}”")).collect();
        return Some(format!(
            "Between subjects, the machine's condition: {}. Each subject runs every test under one of them, assigned in turn by the order of enrolment, two subjects each (so that each condition has subjects starting at both seats); {rig}. The stability of every compensator is checked on every condition before anyone runs it.",
            levels.join(", ")
        ));
    }
    (!p.condition.is_default()).then(|| {
        format!(
            "Every test runs with the machine in the condition “{}” (not the thesis's rig on stilts); {rig}. The stability of every compensator is checked on it before anyone runs it.",
            p.condition
        )
    })
}

/// The cancellation factor as the board reads it: what each arm cancels with, how it is
/// balanced and hidden, the check before a cancelling test and the guard during one.
fn cancellation_design(p: &StudyParams, c: &CancellationParams) -> String {
    let arms: Vec<String> = c
        .arms
        .iter()
        .map(|arm| match arm {
            CancellationArm::Personal => {
                "“personal”, the subject's own body as their identification test measured it"
                    .to_string()
            }
            CancellationArm::Generic => {
                "“generic”, the population's median body, one model for every subject".into()
            }
            CancellationArm::Wrong => match c.wrong {
                Some(e) => format!(
                    "“wrong”, the subject's own body deliberately misstated (gain × {}, a phase lag of {}° at {} Hz), to test how robust cancellation is to a poor model",
                    num(e.gain),
                    num(e.phase_lag_deg),
                    num(e.phase_ref_hz)
                ),
                // (validation requires the error with the arm)
                None => "“wrong”".into(),
            },
            CancellationArm::Off => "off".into(),
        })
        .collect();
    format!(
        "Cancellation, a second factor on the machine: every compensator runs there uncancelled and cancelled with each of {} — {} cells in all, ordered by the study's order design like the compensators, under labels that do not tell the subject which. Cancelling subtracts from the subject's input what their body is predicted to add from the cab's measured acceleration (u = device − Ĥ·a_cab), the model fixed during a test; at the desk nothing is cancelled. When the identification test is filed, each arm's model is checked against the body fitted to it and against each end of its 95 % intervals: it must nowhere between 0.5 and 5 Hz leave more feedthrough than no cancellation, and the cancelled loop must stay stable at {} × the study's feedthrough gain. A model that fails, or a body that could not be identified, leaves that cell not run, recorded with the reason before the subject's first test. During a test, a guard turns cancellation off for the rest of it when its output exceeds {} mm (recorded and audited; the test continues uncancelled and is marked so).",
        arms.join("; "),
        p.tests_on_machine(),
        num(crate::engine::study::stability::MARGIN),
        num(c.limit_mm)
    )
}

fn randomization(d: &mut Doc, study: &Study) {
    let p = &study.params;
    let k = p.compensators.len();
    d.h2("randomization", "Randomization");
    d.list([
        format!("Seed: {} (chosen when the study was created).", study.seed),
        "Generator: xoshiro256++, each use of the seed in its own stream derived from it (the schedule, each subject by enrolment index), so a subject's schedule and targets are a function of the parameters, the seed and the enrolment index only, and can be drawn again to check them.".into(),
        match p.order_design {
            OrderDesign::Random => "Orders (random, the original protocol): at each seat a uniformly random permutation of the compensators (Fisher–Yates shuffle); the second seat's order is drawn again until it differs from the first.".into(),
            OrderDesign::Williams => format!(
                "Orders (Williams design, a balanced Latin square of {} rows): the subject enrolled i-th (from 0) runs row i mod R on the machine and row (i + R/2) mod R at the desk (R rows); over every R consecutive subjects each compensator is at every position, and follows every other one, equally often at each seat.",
                williams::rows(k).len()
            ),
        },
        "Blinded labels: a random numbering 1…k of the compensators per subject.".into(),
        "Each test's target has its own seed, drawn from the subject's stream.".into(),
    ]);
    if p.order_design == OrderDesign::Williams {
        d.h3("The Williams design's rows");
        let kinds: Vec<String> = p
            .compensators
            .iter()
            .map(|c| c.kind().to_string())
            .collect();
        d.table(
            &["Row", "Order"],
            williams::rows(k).into_iter().enumerate().map(|(r, row)| {
                vec![
                    r.to_string(),
                    row.iter()
                        .map(|&c| kinds[c].as_str())
                        .collect::<Vec<_>>()
                        .join(" → "),
                ]
            }),
        );
    }
    let shown = match p.order_design {
        OrderDesign::Random => EXAMPLE_SUBJECTS,
        OrderDesign::Williams => williams::rows(k).len() as u32,
    };
    d.h3(&format!(
        "The schedules of the first {shown} subjects, as this seed draws them"
    ));
    d.table(
        &["Subject", "Starts", "First block", "Second block", "Labels"],
        (0..shown).map(|i| {
            let tests = schedule(p, study.seed, i);
            // The block's tests in queue order: an identification test first, by its phase.
            let block = |b: u32| {
                let mut of_block: Vec<_> = tests.iter().filter(|t| t.block == b).collect();
                of_block.sort_by_key(|t| t.queue_order);
                of_block
                    .iter()
                    .map(|t| match t.phase {
                        TestPhase::Test => t.compensator.to_string(),
                        phase => phase.to_string(),
                    })
                    .collect::<Vec<_>>()
                    .join(" → ")
            };
            let mut labels: Vec<String> = tests
                .iter()
                .filter(|t| t.block == 1 && t.phase == TestPhase::Test)
                .map(|t| format!("{} = {}", t.compensator, t.blinded_label))
                .collect();
            labels.sort();
            let start = tests
                .iter()
                .find(|t| t.block == 1 && t.phase == TestPhase::Test)
                .map(|t| t.seat);
            vec![
                format!("S{:02}", i + 1),
                start.map_or("", seat).into(),
                block(1),
                block(2),
                labels.join(", "),
            ]
        }),
    );
}

fn targets(d: &mut Doc, p: &StudyParams) {
    d.h2("targets", "Target generation");
    let mut items = vec![
        format!(
            "Every test's target is a series of steps, one every {} s, its levels within ±{} mm (the machine's desired range of motion).",
            num(p.step_interval_s),
            num(p.target_range_mm)
        ),
        format!(
            "Every target has mean exactly 0 mm and standard deviation exactly {} mm (up to rounding), so that no compensator gets a harder signal; each test's seed, realized mean and standard deviation are recorded with it.",
            num(p.target_std_mm)
        ),
    ];
    items.push(if p.matched_targets {
        format!(
            "Difficulty matched: every target also has the same mean-squared step change, 2 × {}² = {} mm², recorded with each test.",
            num(p.target_std_mm),
            num(2.0 * p.target_std_mm * p.target_std_mm)
        )
    } else {
        "Difficulty not matched beyond mean and standard deviation (the original protocol); each test's mean-squared step change is recorded.".into()
    });
    items.push(
        "A new target is drawn for every subject and every test, the practice included.".into(),
    );
    d.list(items);
}

/// A JSON value as rows of (path, value): objects by key, arrays by index.
fn flatten(prefix: &str, v: &Value, out: &mut Vec<Vec<String>>) {
    let at = |k: &str| {
        if prefix.is_empty() {
            k.to_string()
        } else {
            format!("{prefix}.{k}")
        }
    };
    match v {
        Value::Object(m) => m.iter().for_each(|(k, v)| flatten(&at(k), v, out)),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, v)| flatten(&format!("{prefix}[{i}]"), v, out)),
        Value::String(s) => out.push(vec![prefix.into(), s.clone()]),
        other => out.push(vec![prefix.into(), other.to_string()]),
    }
}

fn flat(v: &Value) -> Vec<Vec<String>> {
    let mut rows = Vec::new();
    flatten("", v, &mut rows);
    rows
}

fn compensators(d: &mut Doc, p: &StudyParams) {
    d.h2("compensators", "Compensators");
    d.p(&format!(
        "The compensators compared, each with every parameter of its design as the controller builds it. The feedthrough gain K_BF is {}; the practice uses the {} compensator.",
        num(p.k_bf),
        p.practice_compensator
    ));
    for c in &p.compensators {
        d.h3(c.kind().name());
        d.table(
            &["Parameter", "Value"],
            flat(&serde_json::to_value(c).expect("a design serializes")),
        );
    }
    d.h3("The machine and body models");
    d.p(&format!(
        "Rig: {}. The display on the machine shakes with the simulated cab by a gain of {}.",
        match p.rig {
            RigKind::Simulated => "simulated",
            RigKind::Real => "the real machine",
        },
        num(p.display_shake_gain)
    ));
    let models = Models {
        plant: &p.plant,
        body: &p.body,
    };
    d.table(
        &["Parameter", "Value"],
        flat(&serde_json::to_value(models).expect("the models serialize")),
    );
}

/// The machine's and the body's models, under the names the study's parameters give them.
#[derive(serde::Serialize)]
struct Models<'a> {
    plant: &'a PlantParams,
    body: &'a BodyModel,
}

fn surveys(d: &mut Doc, p: &StudyParams) {
    let s = &p.survey;
    d.h2("surveys", "Surveys");
    d.p(&format!(
        "After every scored test the subject rates it on {}-point scales (1 = the low end, {} = the high end; higher is better), every rating required, and may answer the open question in at most {MAX_COMMENT_CHARS} characters.",
        s.scale_points, s.scale_points
    ));
    d.raw(&format!("<div lang=\"{}\">\n", esc(&p.texts.language)));
    d.table(
        &["Item", "Question", "1 =", &format!("{} =", s.scale_points)],
        s.items.iter().map(|i| {
            vec![
                i.key.clone(),
                i.label.clone(),
                i.low_anchor.clone(),
                i.high_anchor.clone(),
            ]
        }),
    );
    d.p(&format!("Open question: {}", s.open_question));
    d.raw("</div>\n");
}

fn stopping_rules(d: &mut Doc, study: &Study) {
    let p = &study.params;
    d.h2("stopping", "Stopping rules");
    let mut items = vec![
        format!(
            "Cab-vibration interlock: the RMS cab acceleration over a sliding 1 s window above {} mm/s² stops the test at once (valve command zero); the test is filed as a fault.",
            num(p.max_cab_rms_mm_s2)
        ),
        format!(
            "Vibration exposure budget (ISO 2631-1, W_d-weighted fore-aft seat acceleration; Directive 2002/44/EC): per subject and day, A(8) {} m/s² and VDV {} m/s^1.75 (the action values are 0.5 and 9.1, the limit values 1.15 and 21, which the budget cannot exceed). Only tests on the machine count, over the 24 hours before each test. A test on the machine starts only with what is left of the budget, and the controller stops it (valve command zero) once its weighted cab acceleration has used that up; when nothing is left the test is refused before it starts. Reaching an action value is recorded in the audit log.",
            num(p.exposure_budget_a8_m_s2),
            num(p.exposure_budget_vdv_m_s175)
        ),
        format!(
            "Stale input: operator input older than {} ms stops the test.",
            num(p.stale_input_ms)
        ),
        format!(
            "Display validity: a station page hidden for more than {} ms in all during a test, or drawing no frame (or sending no display report) for more than {} ms, stops the test and files it invalid; an invalid test never counts.",
            num(p.max_hidden_ms),
            num(p.max_frame_gap_ms)
        ),
        "E-stop: always visible on the experimenter's dashboard (an analyst may press it too); it reaches the controller on a connection of its own, stops every test (valve command zero) and stays latched — also across a restart of the server — until an experimenter resets it. The station tells the subject to let go of the input.".into(),
        "A lost or silent controller, a silent rig, or a reading that cannot be true stops the test; it is filed incomplete and run again.".into(),
        "The subject may stop at any time without a reason: withdrawing (at the station through the experimenter, or on their own page) stops a running test at once, and their data leave every result and export.".into(),
        "Stability gate: before the protocol locks, every compensator is analysed with the feedthrough loop closed at the study's K_BF; a study for the real machine with a design unstable there cannot be locked.".into(),
    ];
    if let Some(ack) = &study.instability_ack {
        items.push(format!(
            "An instability on the simulated machine was acknowledged by {} at {}: {}",
            ack.by,
            rfc3339(ack.at),
            ack.reason
        ));
    }
    d.list(items);
}

fn data_kept(d: &mut Doc, p: &StudyParams) {
    d.h2("data", "Data kept");
    d.list([
        "Subjects are pseudonymous: a code (S01, …), never a name; the server stores nothing that names a person.".into(),
        "The consent decision with the form's version and time; every test attempt with its result, timing figures and full-rate record; the survey answers; the experimenters' notes and reasons; an append-only audit log of who did what when.".into(),
        "A withdrawn subject's data leave every result and export (the subjects export still says who withdrew).".into(),
        "On request an admin erases a subject's data: their tests, records, surveys, notes and identifying fields are removed, and the audit log keeps only that the erasure happened, when, by whom, why, and the subject's code. Backups made before the erasure still hold the data until they are deleted; the platform lists them.".into(),
    ]);
    d.p("The exports an analyst receives, column by column (the codebook's table):");
    for (kind, columns) in export::data_kept(&p.survey) {
        d.h3(&format!("Export “{}”", kind.name()));
        d.table(
            &["Column", "Type", "Unit", "Meaning"],
            columns.into_iter().map(|c| {
                vec![
                    c.name.into_owned(),
                    match c.ty {
                        ColumnType::Number { .. } => format!(
                            "number (to {})",
                            c.ty.resolution().map(num).unwrap_or_default()
                        ),
                        other => other.name().into(),
                    },
                    c.unit.into_owned(),
                    c.meaning.into_owned(),
                ]
            }),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::study::schedule::default_params;

    fn study(name: &str, params: StudyParams) -> Study {
        Study {
            id: 7,
            name: name.into(),
            params,
            seed: 42,
            version: 1,
            locked_at: None,
            protocol_hash: None,
            consent_text: None,
            consent_sha256: None,
            created_at: 0,
            instability_ack: None,
            population_version: 0,
            dry_run: None,
        }
    }

    #[test]
    fn every_user_text_is_escaped() {
        let mut p = default_params();
        p.consent.text = "Agree? <script>alert(1)</script> & \"more\"".into();
        p.survey.open_question = "<img src=x onerror=alert(2)>".into();
        p.texts.ready = "<b>ready</b>".into();
        let html = render(&study("<script>alert(0)</script>", p), 0, None);
        for raw in ["<script>alert", "<img", "<b>ready"] {
            assert!(!html.contains(raw), "{raw} left unescaped");
        }
        assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt; &amp; &quot;more&quot;"));
        assert!(html.contains("&lt;img src=x onerror=alert(2)&gt;"));
        // The only script is the external module; no inline style or handler.
        assert_eq!(html.matches("<script").count(), 1);
        assert!(html.contains("<script type=\"module\" src=\"/protocol.js\"></script>"));
        assert!(
            !html.contains("<style") && !html.contains(" style=") && !html.contains(" onclick")
        );
    }

    #[test]
    fn the_hash_is_on_every_page_and_is_the_locked_one() {
        let p = default_params();
        let mut s = study("s", p.clone());
        let html = render(&s, 0, None);
        let hash = protocol_hash(&p);
        // Header, footer (repeated on every printed page), the summary and the appendix.
        assert_eq!(html.matches(hash.as_str()).count(), 4);
        assert!(html.contains("not locked yet"));
        // A locked study shows the hash it was locked with, and says when the release's
        // hash differs.
        s.locked_at = Some(1_000_000_000_000);
        s.protocol_hash = Some("0".repeat(64));
        let html = render(&s, 0, None);
        assert!(html.contains(&format!("<code class=\"hash\">{}</code>", "0".repeat(64))));
        assert!(html.contains("locked 2001-09-09T01:46:40.000Z"));
        assert!(html.contains(&format!("hash to {hash}")));
    }

    #[test]
    fn the_document_follows_the_parameters() {
        let p = default_params();
        let mut q = p.clone();
        q.max_cab_rms_mm_s2 = 4321.5;
        q.order_design = OrderDesign::Williams;
        q.exposure_budget_a8_m_s2 = 0.35;
        let (a, b) = (
            render(&study("s", p), 0, None),
            render(&study("s", q), 0, None),
        );
        assert!(b.contains("A(8) 0.35 m/s²") && a.contains("A(8) 0.5 m/s²"));
        assert_ne!(a, b);
        assert!(b.contains("above 4321.5 mm/s²") && !a.contains("4321.5"));
        assert!(b.contains("The Williams design's rows") && !a.contains("Williams design's rows"));
    }

    #[test]
    fn a_cancelling_study_describes_its_factor_to_the_board() {
        use bdft_protocol::study::{
            CancellationArm, CancellationParams, IdentificationParams, ModelError,
        };
        let mut p = default_params();
        p.identification = Some(IdentificationParams::default());
        p.cancellation = Some(CancellationParams {
            arms: vec![CancellationArm::Personal, CancellationArm::Wrong],
            wrong: Some(ModelError {
                gain: 1.3,
                phase_lag_deg: 20.0,
                phase_ref_hz: 2.0,
            }),
            limit_mm: 4.0,
        });
        p.validate().unwrap();
        let doc = render(&study("s", p), 0, None);
        for want in [
            // 5 compensators × (off, personal, wrong) on the machine, 5 at the desk.
            "5 compensators 3 times (once per cancellation arm, below)",
            ": 20 scored tests",
            "15 cells in all",
            "gain × 1.3, a phase lag of 20° at 2 Hz",
            "exceeds 4 mm",
        ] {
            assert!(doc.contains(want), "{want} missing");
        }
        assert!(!doc.contains("“generic”"));
        let plain = render(&study("s", default_params()), 0, None);
        assert!(
            plain.contains("compensators once on the machine")
                && plain.contains(": 10 scored tests")
        );
        assert!(!plain.contains("Cancellation, a second factor"));
    }
}
