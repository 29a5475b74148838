//! The survey after each test: its items and scale, and the checks of a subject's answers.

use serde::{Deserialize, Serialize};

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
