//! A study's identification test: its multisine, task and personalization.

use serde::{Deserialize, Serialize};

use super::texts::{MAX_TEXT_CHARS, shown};
use crate::identification::{IdentificationTask, MultisineSpec};
use crate::params::{CompensatorKind, CompensatorSpec, ParamError};

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
    /// it: one of the study's compensators (default the practice's, which must then be one),
    /// so that the stability gate has analysed the loop the test runs — that design without
    /// feedthrough, its verdict `stable_off`. The person's input never reaches it. Its key in
    /// the study's parameters is `controller`.
    #[serde(
        rename = "controller",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub compensator: Option<CompensatorKind>,
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
    pub fn compensator_or(&self, practice: CompensatorKind) -> CompensatorKind {
        self.compensator.unwrap_or(practice)
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

    pub(super) fn validate(
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
        let kind = self.compensator_or(practice);
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
