//! A study's protocol parameters: what the ethics board approved and the experimenter may
//! vary. Stored by the server (locked and hashed once the first subject starts), shown on the
//! dashboard, sent to the pages.

use serde::{Deserialize, Serialize};

use crate::consent;
pub use crate::consent::ConsentForm;
use crate::identification::{IdentificationTask, MultisineSpec};
use crate::params::{
    BodyModel, CompensatorKind, CompensatorSpec, ParamError, PlantParams, PopulationParams, Seat,
    check,
};

/// The four ratings asked after every test, by key (export columns `rating_<key>`).
pub const RATING_KEYS: [&str; 4] = ["accuracy", "speed", "smoothness", "controllability"];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct SurveyItem {
    /// One of `RATING_KEYS`.
    pub key: String,
    pub label: String,
    /// Words at the two ends of the scale (low = 1, high = scale_points).
    pub low_anchor: String,
    pub high_anchor: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct SurveyParams {
    pub items: Vec<SurveyItem>,
    /// Ratings are integers 1..=scale_points, higher is better.
    pub scale_points: u8,
    pub open_question: String,
}

impl Default for SurveyParams {
    fn default() -> Self {
        let item = |key: &str, label: &str, low: &str, high: &str| SurveyItem {
            key: key.into(),
            label: label.into(),
            low_anchor: low.into(),
            high_anchor: high.into(),
        };
        Self {
            items: vec![
                item(
                    "accuracy",
                    "Accuracy: how well could you follow the target?",
                    "very poorly",
                    "very well",
                ),
                item(
                    "speed",
                    "Speed of response: how quickly did the machine respond?",
                    "very slowly",
                    "very quickly",
                ),
                item(
                    "smoothness",
                    "Smoothness: how smooth was the motion?",
                    "very jerky",
                    "very smooth",
                ),
                item(
                    "controllability",
                    "Overall controllability: how easy was the machine to control?",
                    "very hard",
                    "very easy",
                ),
            ],
            scale_points: 7,
            open_question: "What did you like or dislike about this controller?".into(),
        }
    }
}

/// The texts a station shows its subject besides the consent form and the survey, in the
/// study's language. Each may hold placeholders (`PLACEHOLDERS`, written `{name}`; `{{` and
/// `}}` for a literal brace) that the server fills in from the study's parameters
/// (`StudyParams::rendered_texts`), so a text follows the study's durations and counts. In a
/// `StationView` they arrive filled in. Paragraphs are separated by a blank line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct StudyTexts {
    /// BCP 47 language tag of these texts and of the consent form ("en", "de-CH"): the
    /// station page's `<html lang>`.
    pub language: String,
    /// Before every test, the practice included: how the display works.
    pub instructions: String,
    /// Before the practice, after the instructions.
    pub before_practice: String,
    /// Before a scored test, after the instructions.
    pub before_test: String,
    /// Under the instructions while the test waits for the experimenter.
    pub ready: String,
    /// The next test is at the seat on the machine / at the desk.
    pub move_to_on: String,
    pub move_to_off: String,
    /// Under either move heading.
    pub move_note: String,
    /// The end: every test done.
    pub finished_title: String,
    pub finished: String,
    /// The end: the subject declined consent.
    pub declined_title: String,
    pub declined: String,
    /// The end: the subject withdrew.
    pub withdrawn_title: String,
    pub withdrawn: String,
}

impl Default for StudyTexts {
    fn default() -> Self {
        Self {
            language: "en".into(),
            instructions: "You will see two lines moving from right to left: the yellow target \
                           and the blue machine line.\n\nMove the machine so that the blue line \
                           follows the yellow line as closely as you can: move the pointer \
                           (mouse, pen or finger) up and down over the display, or use the input \
                           device."
                .into(),
            before_practice: "The test lasts {practice_s} seconds.\n\nThis is a practice run to \
                              get familiar with the display and the input. It is not scored."
                .into(),
            before_test: "The test lasts {trial_s} seconds.".into(),
            ready: "The experimenter will start it. Please get ready.".into(),
            move_to_on: "Please move to the seat on the machine".into(),
            move_to_off: "Please move to the seat at the desk".into(),
            move_note: "The experimenter will help you. The next test starts there.".into(),
            finished_title: "Thank you!".into(),
            finished: "That was the last test. Thank you very much for taking part. The \
                       experimenter will be with you shortly."
                .into(),
            declined_title: "Thank you for your time".into(),
            declined: "You chose not to take part, and that is completely fine. Nothing more is \
                       needed from you. Please let the experimenter know."
                .into(),
            withdrawn_title: "Thank you for your time".into(),
            withdrawn: "The session has ended. Thank you for the time you gave us. Please let the \
                        experimenter know."
                .into(),
        }
    }
}

impl StudyTexts {
    /// Every text with its parameter name, for validation and rendering.
    fn fields_mut(&mut self) -> [(&'static str, &mut String); 13] {
        [
            ("texts.instructions", &mut self.instructions),
            ("texts.before_practice", &mut self.before_practice),
            ("texts.before_test", &mut self.before_test),
            ("texts.ready", &mut self.ready),
            ("texts.move_to_on", &mut self.move_to_on),
            ("texts.move_to_off", &mut self.move_to_off),
            ("texts.move_note", &mut self.move_note),
            ("texts.finished_title", &mut self.finished_title),
            ("texts.finished", &mut self.finished),
            ("texts.declined_title", &mut self.declined_title),
            ("texts.declined", &mut self.declined),
            ("texts.withdrawn_title", &mut self.withdrawn_title),
            ("texts.withdrawn", &mut self.withdrawn),
        ]
    }
}

/// The placeholders a text may use: scored tests in all and at each seat, the durations of
/// a test and of the practice (s), the minutes of tests in all (practice and identification
/// included, rounded up), and the description of what the study does
/// (`consent::Procedure`).
pub const PLACEHOLDERS: [&str; 6] = [
    "tests",
    "tests_per_station",
    "trial_s",
    "practice_s",
    "minutes",
    "procedure",
];

/// Longest text besides the consent form's.
pub const MAX_TEXT_CHARS: usize = 2000;

/// Fills in the placeholders of the text `name`: `{key}` by its value in `values`, `{{` and
/// `}}` by a brace. An unknown placeholder or an unclosed brace is an error naming the text,
/// the placeholder and the allowed ones.
pub fn render(
    name: &'static str,
    text: &str,
    values: &[(&str, String)],
) -> Result<String, ParamError> {
    let invalid = |message: String| ParamError::Invalid { name, message };
    let allowed = || {
        values
            .iter()
            .map(|(k, _)| format!("{{{k}}}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(i) = rest.find(['{', '}']) {
        out.push_str(&rest[..i]);
        let tail = &rest[i..];
        if tail.starts_with("{{") || tail.starts_with("}}") {
            out.push_str(&tail[..1]);
            rest = &tail[2..];
        } else if let Some(after) = tail.strip_prefix('}') {
            // A lone closing brace is just a brace.
            out.push('}');
            rest = after;
        } else {
            let Some(end) = tail.find('}') else {
                return Err(invalid(format!(
                    "a {{ without its }}; write {{{{ for a brace, or a placeholder: {}",
                    allowed()
                )));
            };
            let key = &tail[1..end];
            let Some((_, value)) = values.iter().find(|(k, _)| *k == key) else {
                return Err(invalid(format!(
                    "unknown placeholder {{{key}}}; allowed: {}",
                    allowed()
                )));
            };
            out.push_str(value);
            rest = &tail[end + 1..];
        }
    }
    out.push_str(rest);
    Ok(out)
}

/// A duration or count as a text shows it: at most one decimal, none when whole.
fn shown(v: f64) -> String {
    ((v * 10.0).round() / 10.0).to_string()
}

/// How each subject's order of compensators at a seat is chosen.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum OrderDesign {
    /// The original protocol: a seeded random order per seat, the second seat's different.
    #[default]
    Random,
    /// A Williams design (balanced Latin square): over its rows every compensator is in
    /// every position equally often and follows every other one equally often.
    Williams,
}

impl OrderDesign {
    fn is_random(&self) -> bool {
        *self == Self::Random
    }
}

/// Whether trials run on the simulated rig or a real machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum RigKind {
    Simulated,
    Real,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct StudyParams {
    /// The controllers compared, each with its design (default: the five of the study).
    pub controllers: Vec<CompensatorSpec>,
    /// Controller used for the practice run.
    pub practice_controller: CompensatorKind,
    /// The two operator stations, both used by every subject.
    pub stations: Vec<Seat>,
    pub trial_s: f64,
    pub practice_s: f64,
    pub step_interval_s: f64,
    /// Target levels stay within ±target_range_mm.
    pub target_range_mm: f64,
    /// Every target's standard deviation (realized within ±5 %).
    pub target_std_mm: f64,
    /// Difficulty-matched targets: every target of the study also has the same mean-squared
    /// step change, 2·target_std_mm² (see `signals::StepTarget::generate_matched`). One
    /// value for the whole study rather than per subject: no compensator and no subject gets
    /// a harder target, and each target stays a function of its own seed. Off by default
    /// (the original protocol); left out of the JSON when off, so the protocol hash of a
    /// study that predates it is unchanged.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub matched_targets: bool,
    /// How the orders of compensators are chosen (default `random`; left out of the JSON
    /// when `random`, for the same reason).
    #[serde(default, skip_serializing_if = "OrderDesign::is_random")]
    pub order_design: OrderDesign,
    pub k_bf: f64,
    pub survey: SurveyParams,
    /// The consent form; its text may hold the placeholders of `texts`.
    pub consent: ConsentForm,
    /// What the station says besides the consent form and the survey (default: the English
    /// texts of the published protocol).
    #[serde(default)]
    pub texts: StudyTexts,
    pub rig: RigKind,
    /// Simulated rig and operator body.
    pub plant: PlantParams,
    pub body: BodyModel,
    /// The synthetic subjects of a dry run: what each draws its own operator, body and
    /// survey habits from (`population: {"body": "preset"}` keeps the study's `body` for all).
    #[serde(default)]
    pub population: PopulationParams,
    /// How much the on-machine station's display shakes with the simulated cab (0 = off).
    pub display_shake_gain: f64,
    /// Operator input older than this stops a test (ms).
    #[serde(default = "default_stale_input_ms")]
    pub stale_input_ms: f64,
    /// The cab-vibration interlock: RMS cab acceleration over a 1 s sliding window above
    /// this stops a test (mm/s²).
    #[serde(default = "default_max_cab_rms")]
    pub max_cab_rms_mm_s2: f64,
    /// Display limits of a person's test (ms): a station page hidden (Page Visibility) for
    /// longer than `max_hidden_ms` in all, or drawing no frame for longer than
    /// `max_frame_gap_ms`, or sending no display report for longer than that, stops the test
    /// and files it invalid. Half a second hidden is a glance at another window; a second
    /// without a frame is a display the subject cannot track on.
    #[serde(default = "default_max_hidden_ms")]
    pub max_hidden_ms: f64,
    #[serde(default = "default_max_frame_gap_ms")]
    pub max_frame_gap_ms: f64,
    /// The study's daily vibration exposure budget per subject (ISO 2631-1 W_d, fore-aft,
    /// seated; `exposure`): A(8) in m/s² and VDV in m/s^1.75 over the subject's day. By
    /// default the 2002/44/EC action values; never above the limit values (1.15, 21). Left
    /// out of the JSON at the default, so the protocol hash of a study that predates the
    /// budget is unchanged (its tests ran under no budget: the default is what it now gets).
    #[serde(
        default = "default_budget_a8",
        skip_serializing_if = "is_default_budget_a8"
    )]
    pub exposure_budget_a8_m_s2: f64,
    #[serde(
        default = "default_budget_vdv",
        skip_serializing_if = "is_default_budget_vdv"
    )]
    pub exposure_budget_vdv_m_s175: f64,
    /// An identification test per subject at the start of their block on the machine
    /// (`IdentificationParams`); none when absent, and left out of the JSON then, so the
    /// protocol hash of a study that predates it is unchanged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identification: Option<IdentificationParams>,
}

/// A study's identification test: what moves the cab, with which design, and what the
/// subject is asked to do. It runs once per subject, first in their block on the machine
/// (the desk is not moved, so there is nothing to measure there).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct IdentificationParams {
    #[serde(default)]
    pub task: IdentificationTask,
    /// The multisine. Its `seed` must be left at 0: each subject's phases are drawn from
    /// the study seed at enrolment.
    #[serde(default)]
    pub excitation: MultisineSpec,
    /// The compensator that closes the cylinder's position loop while the multisine drives
    /// it: one of the study's controllers (default the practice controller, which must then
    /// be one), so that the stability gate has analysed the loop the test runs — that
    /// design without feedthrough, its verdict `stable_off`. The person's input never
    /// reaches it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller: Option<CompensatorKind>,
    /// What the station tells the subject before the test; empty: the task's default text
    /// (`IdentificationParams::instructions_for`).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub instructions: String,
    /// Each subject's LQR designs tuned to the body their identification test fitted
    /// (`bdft_controller::analysis::personal`): the test then runs first of all their
    /// tests, and every trial records whether its design was the subject's own. Left out
    /// of the JSON when false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub personalized: bool,
}

impl IdentificationParams {
    /// The compensator the test runs with in a study whose practice runs `practice`.
    pub fn controller_or(&self, practice: CompensatorKind) -> CompensatorKind {
        self.controller.unwrap_or(practice)
    }

    /// The instructions the station shows: the study's own, or the task's default.
    pub fn instructions_for(&self) -> String {
        if !self.instructions.trim().is_empty() {
            return self.instructions.clone();
        }
        let s = shown(self.excitation.duration_s());
        match self.task {
            IdentificationTask::HoldStill => format!(
                "In this test you do not steer. For about {s} seconds the seat will move by \
                 itself. Hold the control as you normally do and keep the pointer as still as \
                 you can at the centre."
            ),
            IdentificationTask::Relax => format!(
                "In this test you do not steer. For about {s} seconds the seat will move by \
                 itself. Keep your hand on the control but relax your arm and let it go with \
                 the motion."
            ),
        }
    }

    fn validate(
        &self,
        controllers: &[CompensatorSpec],
        practice: CompensatorKind,
    ) -> Result<(), ParamError> {
        self.excitation.validate()?;
        if self.excitation.seed != 0 {
            return Err(ParamError::Invalid {
                name: "identification.excitation.seed",
                message: "leave it at 0: each subject's phases are drawn from the study seed"
                    .into(),
            });
        }
        let kind = self.controller_or(practice);
        if !controllers.iter().any(|c| c.kind() == kind) {
            return Err(ParamError::Invalid {
                name: "identification.controller",
                message: format!(
                    "{kind} is not one of the study's controllers; the test runs one of them, \
                     whose loop the stability gate has analysed"
                ),
            });
        }
        if self.personalized && !controllers.iter().any(|c| c.kind().is_lqr()) {
            return Err(ParamError::Invalid {
                name: "identification.personalized",
                message: "the study has no LQR design to tune to its subjects (lqr, lqr-cabvel \
                          or lqr-cabacc)"
                    .into(),
            });
        }
        if self.instructions.chars().count() > MAX_TEXT_CHARS {
            return Err(ParamError::Invalid {
                name: "identification.instructions",
                message: format!("at most {MAX_TEXT_CHARS} characters"),
            });
        }
        Ok(())
    }
}

fn default_budget_a8() -> f64 {
    crate::exposure::ACTION_A8_M_S2
}

fn default_budget_vdv() -> f64 {
    crate::exposure::ACTION_VDV_M_S175
}

fn is_default_budget_a8(v: &f64) -> bool {
    *v == default_budget_a8()
}

fn is_default_budget_vdv(v: &f64) -> bool {
    *v == default_budget_vdv()
}

fn default_max_hidden_ms() -> f64 {
    500.0
}

fn default_max_frame_gap_ms() -> f64 {
    1000.0
}

fn default_stale_input_ms() -> f64 {
    100.0
}

fn default_max_cab_rms() -> f64 {
    crate::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2
}

impl StudyParams {
    pub fn validate(&self) -> Result<(), ParamError> {
        let invalid = |name, message: String| Err(ParamError::Invalid { name, message });
        if self.controllers.is_empty() || self.controllers.len() > 12 {
            return invalid(
                "controllers",
                format!(
                    "{} controllers given; allowed: 1 to 12",
                    self.controllers.len()
                ),
            );
        }
        for (i, c) in self.controllers.iter().enumerate() {
            c.validate()?;
            if self.controllers[..i].iter().any(|o| o.kind() == c.kind()) {
                return invalid("controllers", format!("{} is listed twice", c.kind()));
            }
        }
        let mut stations = self.stations.clone();
        stations.sort_by_key(|s| s.as_str());
        if stations != [Seat::Off, Seat::On] {
            return invalid(
                "stations",
                "a study uses both stations, on and off, once each".into(),
            );
        }
        check("trial_s", self.trial_s, 1.0, 1800.0)?;
        check("practice_s", self.practice_s, 0.0, 1800.0)?;
        check("step_interval_s", self.step_interval_s, 0.1, 60.0)?;
        if self.trial_s / self.step_interval_s < 2.0 {
            return invalid(
                "trial_s",
                format!(
                    "{} s holds fewer than two steps of {} s (step_interval_s); a test needs at least {} s",
                    self.trial_s,
                    self.step_interval_s,
                    2.0 * self.step_interval_s
                ),
            );
        }
        check("target_range_mm", self.target_range_mm, 1.0, 500.0)?;
        check(
            "target_std_mm",
            self.target_std_mm,
            0.1,
            0.8 * self.target_range_mm,
        )?;
        check("k_bf", self.k_bf, 0.01, crate::params::MAX_KBF)?;
        check("display_shake_gain", self.display_shake_gain, 0.0, 10.0)?;
        check("stale_input_ms", self.stale_input_ms, 5.0, 10_000.0)?;
        check("max_cab_rms_mm_s2", self.max_cab_rms_mm_s2, 10.0, 1e6)?;
        check("max_hidden_ms", self.max_hidden_ms, 0.0, 60_000.0)?;
        check("max_frame_gap_ms", self.max_frame_gap_ms, 250.0, 60_000.0)?;
        check(
            "exposure_budget_a8_m_s2",
            self.exposure_budget_a8_m_s2,
            0.01,
            crate::exposure::LIMIT_A8_M_S2,
        )?;
        check(
            "exposure_budget_vdv_m_s175",
            self.exposure_budget_vdv_m_s175,
            0.1,
            crate::exposure::LIMIT_VDV_M_S175,
        )?;
        let s = &self.survey;
        if !(2..=11).contains(&s.scale_points) {
            return invalid(
                "survey.scale_points",
                format!("{} points; allowed: 2 to 11", s.scale_points),
            );
        }
        let keys: Vec<&str> = s.items.iter().map(|i| i.key.as_str()).collect();
        if keys != RATING_KEYS {
            return invalid(
                "survey.items",
                format!("the items must be, in order: {}", RATING_KEYS.join(", ")),
            );
        }
        // Lengths are in characters, as the messages say: a label in another script is
        // allowed as many as an English one.
        let chars = |t: &str| t.chars().count();
        for i in &s.items {
            if i.label.trim().is_empty()
                || chars(&i.label) > 300
                || chars(&i.low_anchor) > 60
                || chars(&i.high_anchor) > 60
            {
                return invalid(
                    "survey.items",
                    "each item needs a label (≤ 300 characters) and anchors (≤ 60)".into(),
                );
            }
        }
        if chars(&s.open_question) > 300 {
            return invalid("survey.open_question", "at most 300 characters".into());
        }
        if self.consent.version.trim().is_empty()
            || chars(&self.consent.version) > 40
            || self.consent.text.trim().is_empty()
            || chars(&self.consent.text) > 20_000
        {
            return invalid(
                "consent",
                "a version (≤ 40 characters) and a text (≤ 20,000) are required".into(),
            );
        }
        self.check_texts()?;
        if let Some(id) = &self.identification {
            id.validate(&self.controllers, self.practice_controller)?;
        }
        self.plant.validate()?;
        self.body.validate()?;
        self.population.validate()
    }

    /// The values of the texts' placeholders for this study, as `render` takes them.
    pub fn text_values(&self) -> Vec<(&'static str, String)> {
        let per_station = self.controllers.len();
        let tests = per_station * self.stations.len();
        let values = [
            tests.to_string(),
            per_station.to_string(),
            shown(self.trial_s),
            shown(self.practice_s),
            shown(self.procedure().minutes()),
            self.procedure().text(),
        ];
        PLACEHOLDERS.into_iter().zip(values).collect()
    }

    /// What the consent form's description tells of this study.
    pub fn procedure(&self) -> consent::Procedure<'_> {
        consent::Procedure {
            practice_s: self.practice_s,
            trial_s: self.trial_s,
            tests_per_seat: self.controllers.len(),
            seats: self.stations.len(),
            identification: self
                .identification
                .as_ref()
                .map(|id| consent::IdentificationTest {
                    excitation: &id.excitation,
                    task: id.task,
                    personalized: id.personalized,
                }),
            budget_a8_m_s2: self.exposure_budget_a8_m_s2,
            budget_vdv_m_s175: self.exposure_budget_vdv_m_s175,
            max_cab_rms_m_s2: self.max_cab_rms_mm_s2 / 1000.0,
        }
    }

    /// The consent form and the station's texts with their placeholders filled in. A
    /// consent text that does not place `{procedure}` gets it appended: no form leaves out
    /// what the protocol does.
    pub fn rendered_texts(&self) -> Result<(ConsentForm, StudyTexts), ParamError> {
        let values = self.text_values();
        let mut text = render("consent.text", &self.consent.text, &values)?;
        let procedure = self.procedure().text();
        if !text.contains(&procedure) {
            text = format!("{}\n\n{procedure}", text.trim_end());
        }
        let consent = ConsentForm {
            version: self.consent.version.clone(),
            text,
        };
        let mut texts = self.texts.clone();
        for (name, text) in texts.fields_mut() {
            *text = render(name, text, &values)?;
        }
        Ok((consent, texts))
    }

    fn check_texts(&self) -> Result<(), ParamError> {
        let lang = &self.texts.language;
        let tag_ok = (1..=35).contains(&lang.len())
            && lang.starts_with(|c: char| c.is_ascii_alphabetic())
            && lang.chars().all(|c| c.is_ascii_alphanumeric() || c == '-');
        if !tag_ok {
            return Err(ParamError::Invalid {
                name: "texts.language",
                message: format!(
                    "{lang:?} is not a language tag; use a BCP 47 tag such as \"en\" or \"de-CH\""
                ),
            });
        }
        for (name, text) in self.texts.clone().fields_mut() {
            if text.chars().count() > MAX_TEXT_CHARS {
                return Err(ParamError::Invalid {
                    name,
                    message: format!("at most {MAX_TEXT_CHARS} characters"),
                });
            }
        }
        self.rendered_texts().map(|_| ())
    }
}

/// A survey answer as a subject submits it (validated against the study's scale).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct SurveyAnswer {
    pub accuracy: Option<i64>,
    pub speed: Option<i64>,
    pub smoothness: Option<i64>,
    pub controllability: Option<i64>,
    #[serde(default)]
    pub comment: String,
}

/// Longest open-question answer.
pub const MAX_COMMENT_CHARS: usize = 2000;

/// A field of a survey and what is wrong with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct FieldError {
    pub field: String,
    pub message: String,
}

impl SurveyAnswer {
    /// All problems at once (so a form can mark every field), or the four ratings.
    pub fn validate(&self, scale_points: u8) -> Result<[u8; 4], Vec<FieldError>> {
        let mut errors = Vec::new();
        let mut out = [0u8; 4];
        let values = [
            self.accuracy,
            self.speed,
            self.smoothness,
            self.controllability,
        ];
        for (i, (key, v)) in RATING_KEYS.iter().zip(values).enumerate() {
            match v {
                None => errors.push(FieldError {
                    field: (*key).into(),
                    message: "please choose a rating".into(),
                }),
                Some(v) if v < 1 || v > i64::from(scale_points) => errors.push(FieldError {
                    field: (*key).into(),
                    message: format!(
                        "{v} is not on the scale; choose a whole number from 1 to {scale_points}"
                    ),
                }),
                Some(v) => out[i] = v as u8,
            }
        }
        let chars = self.comment.chars().count();
        if chars > MAX_COMMENT_CHARS {
            errors.push(FieldError {
                field: "comment".into(),
                message: format!("{chars} characters; at most {MAX_COMMENT_CHARS} are allowed"),
            });
        }
        if errors.is_empty() {
            Ok(out)
        } else {
            Err(errors)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values() -> Vec<(&'static str, String)> {
        vec![("tests", "10".into()), ("trial_s", "140".into())]
    }

    #[test]
    fn placeholders_are_filled_in_and_unknown_ones_named() {
        let v = values();
        assert_eq!(
            render("t", "{tests} tests of {trial_s} s", &v).unwrap(),
            "10 tests of 140 s"
        );
        assert_eq!(render("t", "{{tests}} } {", &v).ok(), None);
        assert_eq!(render("t", "{{tests}} }", &v).unwrap(), "{tests} }");
        assert_eq!(render("t", "", &v).unwrap(), "");
        let err = render("consent.text", "ten {tests_total}", &v)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("consent.text: unknown placeholder {tests_total}"),
            "{err}"
        );
        assert!(err.contains("allowed: {tests}, {trial_s}"), "{err}");
        let err = render("texts.ready", "a {tests", &v)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("texts.ready:") && err.contains("{{"),
            "{err}"
        );
        // Multi-byte text around placeholders.
        assert_eq!(render("t", "é{tests}ü", &v).unwrap(), "é10ü");
    }

    #[test]
    fn numbers_are_shown_with_at_most_one_decimal() {
        assert_eq!(shown(140.0), "140");
        assert_eq!(shown(0.5), "0.5");
        assert_eq!(shown(2.34), "2.3");
    }

    #[test]
    fn survey_validation_reports_every_bad_field() {
        let ok = SurveyAnswer {
            accuracy: Some(1),
            speed: Some(7),
            smoothness: Some(4),
            controllability: Some(2),
            comment: "fine".into(),
        };
        assert_eq!(ok.validate(7), Ok([1, 7, 4, 2]));
        let bad = SurveyAnswer {
            accuracy: None,
            speed: Some(8),
            smoothness: Some(0),
            controllability: Some(3),
            comment: "x".repeat(2001),
        };
        let errs = bad.validate(7).unwrap_err();
        let fields: Vec<&str> = errs.iter().map(|e| e.field.as_str()).collect();
        assert_eq!(fields, ["accuracy", "speed", "smoothness", "comment"]);
        assert!(errs[1].message.contains("1 to 7"));
        // Characters, not bytes: 2000 two-byte characters are allowed.
        let long = SurveyAnswer {
            comment: "é".repeat(2000),
            ..ok
        };
        assert!(long.validate(7).is_ok());
    }
}
