//! The consent form: the lab's own text, and the description of what the study does that
//! is generated from its parameters (`{procedure}`), so what a subject agrees to is what
//! the locked protocol runs — every kind of test with its count and length, the shaking of
//! the seat, and the exposure budget — however the lab edits either.

use serde::{Deserialize, Serialize};

use crate::exposure::{ACTION_A8_M_S2, ACTION_VDV_M_S175};
use crate::identification::{IdentificationTask, MultisineSpec};

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
            version: "1.1".into(),
            text: "You will control a machine's boom with a hand-held input device, following a \
                   moving target on a screen.\n\n{procedure}\n\nRisks: whole-body vibration \
                   comparable to operating construction equipment, and fatigue. You may stop at \
                   any time without giving a reason, and ask for your data to be withdrawn. \
                   Your data are stored under a code, never your name."
                .into(),
        }
    }
}

/// A length or figure as the form says it: at most one decimal (two below 1), none when
/// whole.
fn figure(v: f64) -> String {
    let places = if v.abs() < 1.0 { 100.0 } else { 10.0 };
    ((v * places).round() / places).to_string()
}

fn plural(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// What the form's description tells, as a study's parameters give it
/// (`StudyParams::procedure`).
#[derive(Debug, Clone, Copy)]
pub struct Procedure<'a> {
    pub practice_s: f64,
    pub trial_s: f64,
    /// Scored tests on the machine (each compensator once per cancellation arm) and at the
    /// desk (each compensator once).
    pub tests_on_machine: usize,
    pub tests_at_desk: usize,
    /// Some tests on the machine cancel the feedthrough, the subject not told which.
    pub cancelling: bool,
    /// The identification test, when the study has one.
    pub identification: Option<IdentificationTest<'a>>,
    pub budget_a8_m_s2: f64,
    pub budget_vdv_m_s175: f64,
    /// The interlock: RMS cab acceleration over a second that stops a test.
    pub max_cab_rms_m_s2: f64,
}

/// What the form says of the identification test.
#[derive(Debug, Clone, Copy)]
pub struct IdentificationTest<'a> {
    pub excitation: &'a MultisineSpec,
    pub task: IdentificationTask,
    pub personalized: bool,
}

impl Procedure<'_> {
    /// What the study does, in the order a subject meets it (the server's schedule follows
    /// the same parameters: practice at the desk, then one block per seat, the
    /// identification test on the machine).
    pub fn text(&self) -> String {
        let (on, desk) = (self.tests_on_machine, self.tests_at_desk);
        let tests = on + desk;
        let mut s = Vec::new();
        if self.practice_s > 0.0 {
            s.push(format!(
                "First, a practice run of {} seconds at the desk beside the machine, to get to \
                 know the display and the input device; it is not scored.",
                figure(self.practice_s)
            ));
        }
        s.push(format!(
            "{} {} of {} seconds each: {on} while seated on the machine, which vibrates \
             as you control it, and {desk} at a desk beside it, one seat after the other. \
             After each test you answer a few questions about it.",
            if self.practice_s > 0.0 {
                "Then"
            } else {
                "You take"
            },
            plural(tests, "test", "tests"),
            figure(self.trial_s),
        ));
        if let Some(id) = &self.identification {
            let what = match id.task {
                IdentificationTask::HoldStill => "hold the input device still",
                IdentificationTask::Relax => {
                    "hold the input device lightly and let your arm go with the motion"
                }
            };
            let mut when = String::new();
            if id.personalized {
                when += " It comes before your first scored test: what it measures of your arm \
                          is used to tune some of the controllers to you.";
            }
            if self.cancelling {
                when += " What it measures of your arm is used in some of the tests on the \
                          machine to take out of your input the part the machine's vibration \
                          puts into it; you are not told which tests these are.";
            }
            s.push(format!(
                "On the machine there is one more test, of {} seconds, that is not scored: the \
                 machine shakes the seat by itself, with vibrations between {} and {} Hz, while \
                 you {what}.{when}",
                figure(id.excitation.duration_s()),
                figure(id.excitation.f_min_hz),
                figure(id.excitation.f_max_hz),
            ));
        }
        s.push(format!(
            "A test that has to be stopped (by you, the experimenter or a technical fault) may \
             be repeated. In all about {} minutes of tests, besides the questions and breaks.",
            figure(self.minutes())
        ));
        let limits = if self.budget_a8_m_s2 <= ACTION_A8_M_S2
            && self.budget_vdv_m_s175 <= ACTION_VDV_M_S175
        {
            "within the action values of the European directive 2002/44/EC"
        } else {
            "above the action values of the European directive 2002/44/EC, within its limit values"
        };
        s.push(format!(
            "The vibration you are exposed to on a day is kept within a budget of A(8) {} m/s² \
             and VDV {} m/s^1.75 (ISO 2631-1; {limits}), and the machine stops a test by itself \
             when the seat shakes more than {} m/s² (RMS over a second).",
            figure(self.budget_a8_m_s2),
            figure(self.budget_vdv_m_s175),
            figure(self.max_cab_rms_m_s2),
        ));
        s.join(" ")
    }

    /// Minutes of tests in all (practice, scored and identification tests), rounded up.
    pub fn minutes(&self) -> f64 {
        let tests = (self.tests_on_machine + self.tests_at_desk) as f64;
        let identification = self
            .identification
            .map_or(0.0, |id| id.excitation.duration_s());
        ((self.practice_s + tests * self.trial_s + identification) / 60.0).ceil()
    }
}
