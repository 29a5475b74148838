//! A study's protocol parameters: what the ethics board approved and the experimenter may
//! vary. Stored by the server (locked and hashed once the first subject starts), shown on the
//! dashboard, sent to the pages.

use serde::{Deserialize, Serialize};

use crate::consent;
pub use crate::consent::ConsentForm;
use crate::params::{
    BodyModel, CompensatorKind, CompensatorSpec, MachineCondition, ParamError, PlantParams,
    PopulationParams, Seat, check,
};

mod cancellation;
mod identification;
mod survey;
mod texts;

pub use cancellation::{CancellationArm, CancellationParams, ModelError};
pub use identification::IdentificationParams;
pub use survey::*;
pub use texts::*;

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

/// Most levels of the condition factor: each needs its own subjects.
pub const MAX_CONDITIONS: usize = 6;

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
    /// The compensators compared, each with its design (default: the five of the study).
    /// Its key stays `controllers`, the published parameter name.
    #[serde(rename = "controllers")]
    pub compensators: Vec<CompensatorSpec>,
    /// Compensator used for the practice run (key `practice_controller`).
    #[serde(rename = "practice_controller")]
    pub practice_compensator: CompensatorKind,
    /// The two seats (on the machine, at the desk), both used by every subject (key
    /// `stations`).
    #[serde(rename = "stations")]
    pub seats: Vec<Seat>,
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
    /// Model-based cancellation as a second factor on the machine (`CancellationParams`):
    /// every compensator there runs once per arm, off included; none when absent, and left
    /// out of the JSON then, so the protocol hash of a study that predates it is unchanged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cancellation: Option<CancellationParams>,
    /// The machine's condition for every test on it (`params::MachineCondition`): on the
    /// simulated rig, `plant` under the condition while the compensators stay designed for
    /// `plant` — a fixed design meeting the field; on a real rig, what the lab declares it
    /// stands on, recorded with every test. Default the thesis's rig (`stilts`), left out of
    /// the JSON then, so the protocol hash of a study that predates it is unchanged.
    #[serde(default, skip_serializing_if = "MachineCondition::is_default")]
    #[cfg_attr(feature = "openapi", schema(value_type = String, example = "tires+loaded"))]
    pub condition: MachineCondition,
    /// The machine's condition as a factor between subjects: each subject runs every test
    /// under one of these (`condition_of`: in turn by enrolment order), so one study compares
    /// the machine on them. Empty when the study fixes `condition` (the default), and left out
    /// of the JSON then. Between subjects because a machine's ground and load are set for a
    /// session, not changed between one test and the next.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    #[cfg_attr(feature = "openapi", schema(value_type = Vec<String>, example = json!(["stilts", "tires"])))]
    pub conditions: Vec<MachineCondition>,
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
        if self.compensators.is_empty() || self.compensators.len() > 12 {
            return invalid(
                "controllers",
                format!(
                    "{} controllers given; allowed: 1 to 12",
                    self.compensators.len()
                ),
            );
        }
        for (i, c) in self.compensators.iter().enumerate() {
            c.validate()?;
            if self.compensators[..i].iter().any(|o| o.kind() == c.kind()) {
                return invalid("controllers", format!("{} is listed twice", c.kind()));
            }
        }
        self.condition.apply(&self.plant)?;
        self.check_conditions()?;
        let mut stations = self.seats.clone();
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
            id.validate(&self.compensators, self.practice_compensator)?;
        }
        if let Some(c) = &self.cancellation {
            c.validate(self.identification.is_some())?;
        }
        self.plant.validate()?;
        self.body.validate()?;
        self.population.validate()
    }

    /// The condition factor's levels: 2 to `MAX_CONDITIONS` different conditions the rig
    /// can take, and not beside a fixed condition.
    fn check_conditions(&self) -> Result<(), ParamError> {
        if self.conditions.is_empty() {
            return Ok(());
        }
        let invalid = |message: String| {
            Err(ParamError::Invalid {
                name: "conditions",
                message,
            })
        };
        if !self.condition.is_default() {
            return invalid(format!(
                "the study fixes the condition {} and makes it a factor; give one of condition and conditions",
                self.condition
            ));
        }
        if !(2..=MAX_CONDITIONS).contains(&self.conditions.len()) {
            return invalid(format!(
                "{} given; a factor has 2 to {MAX_CONDITIONS} conditions (one: give it as condition)",
                self.conditions.len()
            ));
        }
        for (i, c) in self.conditions.iter().enumerate() {
            if self.conditions[..i].contains(c) {
                return invalid(format!("{c} is listed twice"));
            }
            c.apply(&self.plant).map_err(|e| ParamError::Invalid {
                name: "conditions",
                message: format!("{c}: {e}"),
            })?;
        }
        Ok(())
    }

    /// Every condition the study's machine runs under: its factor's levels, or its one
    /// condition.
    pub fn machine_conditions(&self) -> Vec<MachineCondition> {
        if self.conditions.is_empty() {
            vec![self.condition]
        } else {
            self.conditions.clone()
        }
    }

    /// The condition of every test of the subject enrolled `enrol_index`-th (from 0): the
    /// factor's levels in turn, each for two consecutive subjects, so that each condition
    /// has as many subjects starting on the machine as at the desk (the starting seat
    /// alternates by enrolment, `schedule::starting_seat`).
    pub fn condition_of(&self, enrol_index: u32) -> MachineCondition {
        let levels = self.machine_conditions();
        levels[(enrol_index as usize / 2) % levels.len()]
    }

    /// The cancellation arms each compensator runs on the machine: off alone without the
    /// factor.
    pub fn machine_arms(&self) -> Vec<CancellationArm> {
        self.cancellation
            .as_ref()
            .map_or(vec![CancellationArm::Off], CancellationParams::machine_arms)
    }

    /// Scored tests on the machine: each compensator once per cancellation arm.
    pub fn tests_on_machine(&self) -> usize {
        self.compensators.len() * self.machine_arms().len()
    }

    /// Scored tests of a subject: those on the machine and one per compensator at the desk.
    pub fn scored_tests(&self) -> usize {
        self.tests_on_machine() + self.compensators.len()
    }

    /// The values of the texts' placeholders for this study, as `render` takes them.
    pub fn text_values(&self) -> Vec<(&'static str, String)> {
        let per_station = self.compensators.len();
        let values = [
            self.scored_tests().to_string(),
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
            tests_on_machine: self.tests_on_machine(),
            tests_at_desk: self.compensators.len(),
            cancelling: self.cancellation.is_some(),
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
