//! A subject's cancelling tests (issue 38), decided when their identification test is filed:
//! for each compensator and cancelling arm of the study, the model the arm cancels with for
//! this subject (`CancellationParams::model`) and the check of it against the body the test
//! identified and its interval's ends (`bdft_controller::cancellation::check`: nowhere worse
//! than no cancellation, and the cancelled loop stable at the stability gate's margin, MARGIN
//! × the study's K_BF). A model that passes is put on the subject's scheduled tests of that
//! cell; a cell without one — the body not identified, or the check failed — is filed
//! incomplete with the reason, before any of them runs: the schedule says so, never
//! silently. A cancelling test without a model is refused at its start (409).

use bdft_controller::analysis::personal::PersonalDesign;
use bdft_controller::cancellation::check::{bodies_of, check};
use bdft_protocol::cancellation::CancellationModel;
use bdft_protocol::identification::BodyFit;
use bdft_protocol::params::CompensatorKind;
use bdft_protocol::study::{CancellationArm, StudyParams};
use serde::Serialize;

use crate::engine::study::stability::{MARGIN, study_loop};
use crate::error::{AppError, Result};
use crate::store::trials::Trial;
use crate::store::{self, Change};

/// One cell's decision for a subject: the model its tests cancel with, or why they cannot.
#[derive(Debug, Clone, Serialize)]
pub struct Planned {
    #[serde(rename = "compensator")]
    pub compensator: CompensatorKind,
    pub arm: CancellationArm,
    pub model: Option<CancellationModel>,
    /// Why the cell does not run (none when it does).
    pub reason: Option<String>,
}

/// Each cancelling cell of a study with `params` for a subject whose identification gave
/// `fit`; the study's designs, or the subject's own where `designs` tuned one. Empty for a
/// study without the factor. Runs the stability analysis: call it off the async threads.
pub fn plan(
    params: &StudyParams,
    fit: std::result::Result<&BodyFit, &str>,
    designs: Option<&[PersonalDesign]>,
) -> Vec<Planned> {
    let Some(factor) = &params.cancellation else {
        return Vec::new();
    };
    let bodies = fit.map_err(str::to_string).and_then(bodies_of);
    let own = fit
        .map_err(str::to_string)
        .and_then(BodyFit::identified_body);
    let mut out = Vec::new();
    for spec in &params.compensators {
        let spec = designs
            .and_then(|ds| ds.iter().find(|d| d.compensator == spec.kind()))
            .and_then(|d| d.spec.clone())
            .unwrap_or_else(|| spec.clone());
        let mut setup = study_loop(params, &spec);
        setup.loop_params.k_bf = MARGIN * params.k_bf;
        for &arm in &factor.arms {
            let decided = factor
                .model(arm, own.as_ref().ok(), &params.population)
                .map_err(|e| match &own {
                    // Say which parameter and why.
                    Err(why) => format!("{e}: {why}"),
                    Ok(_) => e,
                })
                .and_then(|model| {
                    let bodies = bodies
                        .as_ref()
                        .map_err(|e| format!("no body to check the model against: {e}"))?;
                    let verdict = check(&model, bodies, &setup)
                        .map_err(|e| format!("the check could not be run: {e}"))?;
                    match verdict.failure() {
                        None => Ok(model),
                        Some(why) => Err(format!(
                            "the model fails the check before a cancelling test ({MARGIN} × \
                             K_BF {}): {why}",
                            params.k_bf
                        )),
                    }
                });
            let (model, reason) = match decided {
                Ok(m) => (Some(m), None),
                Err(why) => (None, Some(why)),
            };
            out.push(Planned {
                compensator: spec.kind(),
                arm,
                model,
                reason,
            });
        }
    }
    out
}

/// What `cancellation.plan` records: each cell's decision and the tests it touched.
#[derive(Debug, Serialize)]
struct Recorded<'a> {
    subject_id: i64,
    cells: &'a [Planned],
    tests_cancelling: u64,
    tests_not_run: u64,
}

/// Puts each planned model on the subject's scheduled tests of its cell, and files each
/// cell without one incomplete with its reason ("not run: …"), audited as
/// `cancellation.plan` in the identification's filing.
pub async fn store(change: &mut Change, trial: &Trial, planned: &[Planned]) -> Result<()> {
    if planned.is_empty() {
        return Ok(());
    }
    let (mut cancelling, mut not_run) = (0, 0);
    for p in planned {
        match (&p.model, &p.reason) {
            (Some(model), _) => {
                let json = serde_json::to_string(model).expect("models serialize");
                cancelling += store::trials::set_cancellation_scheduled(
                    change.db(),
                    trial.subject_id,
                    p.compensator,
                    p.arm,
                    &json,
                )
                .await?;
            }
            (None, reason) => {
                let why = format!(
                    "not run: no {} cancellation for this subject — {}",
                    p.arm,
                    reason.as_deref().unwrap_or("no model")
                );
                let ids = store::trials::scheduled_cancelling(
                    change.db(),
                    trial.subject_id,
                    p.compensator,
                    p.arm,
                )
                .await?;
                for id in ids {
                    store::trials::accept_incomplete(change.db(), id, &why).await?;
                    not_run += 1;
                }
            }
        }
    }
    change
        .audit_also(
            "cancellation.plan",
            Some(format!("subject:{}", trial.subject_id)),
            Recorded {
                subject_id: trial.subject_id,
                cells: planned,
                tests_cancelling: cancelling,
                tests_not_run: not_run,
            },
        )
        .await
}

/// The model `trial` cancels with as it starts: none for an uncancelled test; a 409 for a
/// cancelling one that has none (its subject's identification not filed yet).
pub fn model_of(trial: &Trial) -> Result<Option<CancellationModel>> {
    if trial.cancellation == CancellationArm::Off {
        return Ok(None);
    }
    let json = trial.cancellation_json.as_deref().ok_or_else(|| {
        AppError::Conflict(format!(
            "trial {} cancels with the {} model, which is set when the subject's \
             identification test is filed and the model passes its check; it has none yet",
            trial.id, trial.cancellation
        ))
    })?;
    let model: CancellationModel = serde_json::from_str(json).map_err(|e| {
        AppError::Internal(anyhow::anyhow!(
            "trial {}'s cancellation model does not parse: {e}",
            trial.id
        ))
    })?;
    Ok(Some(model))
}
