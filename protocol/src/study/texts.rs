//! The texts a station shows besides the consent form and the survey, and their
//! placeholders' renderer.

use serde::{Deserialize, Serialize};

use crate::params::ParamError;

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
    pub(super) fn fields_mut(&mut self) -> [(&'static str, &mut String); 13] {
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
pub(super) fn shown(v: f64) -> String {
    ((v * 10.0).round() / 10.0).to_string()
}
