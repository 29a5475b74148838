//! A study's protocol parameters: what the ethics board approved and the experimenter may
//! vary. Stored by the server (locked and hashed once the first subject starts), shown on the
//! dashboard, sent to the pages.

use serde::{Deserialize, Serialize};

use crate::params::{
    BodyModel, CompensatorKind, CompensatorSpec, ParamError, PlantParams, Seat, check,
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

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ConsentForm {
    pub version: String,
    pub text: String,
}

impl Default for ConsentForm {
    fn default() -> Self {
        Self {
            version: "1.0".into(),
            text: "You will control a machine's boom with a hand-held input device, following a \
                   moving target on a screen, for about one hour: a short practice, then ten tests \
                   of 140 seconds, five of them while seated on the machine, which vibrates, and \
                   five at a desk beside it. After each test you answer a few questions. Risks: \
                   whole-body vibration comparable to operating construction equipment, and \
                   fatigue. You may stop at any time without giving a reason, and ask for your \
                   data to be withdrawn. Your data are stored under a code, never your name."
                .into(),
        }
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
    pub k_bf: f64,
    pub survey: SurveyParams,
    pub consent: ConsentForm,
    pub rig: RigKind,
    /// Simulated rig and operator body.
    pub plant: PlantParams,
    pub body: BodyModel,
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
            return invalid("step_interval_s", "a test needs at least two steps".into());
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
        for i in &s.items {
            if i.label.trim().is_empty()
                || i.label.len() > 300
                || i.low_anchor.len() > 60
                || i.high_anchor.len() > 60
            {
                return invalid(
                    "survey.items",
                    "each item needs a label (≤ 300 characters) and anchors (≤ 60)".into(),
                );
            }
        }
        if s.open_question.len() > 300 {
            return invalid("survey.open_question", "at most 300 characters".into());
        }
        if self.consent.version.trim().is_empty()
            || self.consent.version.len() > 40
            || self.consent.text.trim().is_empty()
            || self.consent.text.len() > 20_000
        {
            return invalid(
                "consent",
                "a version (≤ 40 characters) and a text (≤ 20,000) are required".into(),
            );
        }
        self.plant.validate()?;
        self.body.validate()
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
