//! What a completed identification test measured: its record's feedthrough at the excited
//! frequencies and the seated body fitted to it (`bdft_controller::identification`),
//! computed off the async threads before the filing's transaction and stored in it, with
//! its audit row. In a personalized study the study's LQR designs are tuned to the fitted
//! body there too (`bdft_controller::analysis::personal`), and put in place of the designs
//! of the subject's tests not yet run.

use std::collections::BTreeMap;

use bdft_controller::analysis::personal::{PersonalDesign, personalize};
use bdft_protocol::identification::{BodyFit, FrfPoint, Reported};
use bdft_protocol::params::BodyModel;
use bdft_protocol::records::TestPhase;
use bdft_protocol::study::StudyParams;
use bdft_protocol::trial::{TargetSpec, record_channel};
use serde::Serialize;

use super::cancellation::{self, Planned};
use crate::engine::study::schedule::identification_target;
use crate::engine::study::stability::{MARGIN, study_loop};
use crate::error::Result;
use crate::store::records::Record;
use crate::store::trials::Trial;
use crate::store::{self, Change};

/// The measurement of one identification test: the points (none when the record could
/// not be estimated) and the fit, or why there is none.
#[derive(Debug, Clone)]
pub struct Measured {
    pub points: Vec<FrfPoint>,
    pub fit: std::result::Result<BodyFit, String>,
    /// The study's LQR designs tuned to the fit, in a personalized study (none otherwise;
    /// empty when there is no fit to tune to).
    pub designs: Option<Vec<PersonalDesign>>,
    /// The subject's cancelling cells, in a study with cancellation (`cancellation::plan`).
    pub cancellation: Vec<Planned>,
}

/// The body a subject's designs are tuned to: the fitted one with its gain at the upper
/// end of its 95 % interval, so that a design keeps its margin for every gain the test
/// could not rule out (the gain sets how much of the hand's motion is fed back; the
/// resonances only shape it).
pub fn design_body(fit: &BodyFit) -> BodyModel {
    BodyModel::Seated {
        k_h: fit.k_h.hi,
        torso_f_hz: fit.torso_f_hz.value,
        torso_zeta: fit.torso_zeta.value,
        arm_f_hz: fit.arm_f_hz.value,
        arm_zeta: fit.arm_zeta.value,
    }
}

/// Each of the study's LQR designs tuned to `fit` (`design_body`) to keep the stability
/// gate's margin at the study's K_BF; a design that cannot be built says so in its reason.
pub fn personal_designs(params: &StudyParams, fit: &BodyFit) -> Vec<PersonalDesign> {
    let body = design_body(fit);
    params
        .compensators
        .iter()
        .filter(|spec| spec.kind().is_lqr())
        .map(|spec| {
            let setup = bdft_controller::closed_loop::LoopSetup {
                body,
                ..study_loop(params, spec)
            };
            personalize(&setup, MARGIN * params.k_bf)
                .map(|d| d.expect("an LQR design is tuned"))
                .unwrap_or_else(|e| {
                    PersonalDesign::refused(
                        spec,
                        format!("the design cannot be analysed for this body: {e}"),
                    )
                })
        })
        .collect()
}

/// What `trial`'s record measured, when `trial` is an identification test of a study with
/// `params`; none for any other test.
pub async fn measure(params: &StudyParams, trial: &Trial, record: &Record) -> Option<Measured> {
    if trial.phase != TestPhase::Identification {
        return None;
    }
    let Some(TargetSpec::Identification { excitation, .. }) =
        identification_target(params, trial.target_seed as u64)
    else {
        return Some(Measured {
            points: Vec::new(),
            fit: Err("the study has no identification test".into()),
            designs: None,
            cancellation: Vec::new(),
        });
    };
    let channel = |name| {
        record_channel(name)
            .and_then(|i| record.channels.get(i))
            .cloned()
            .unwrap_or_default()
    };
    let (cab, device, dt) = (channel("cab_accel_mm_s2"), channel("device_mm"), record.dt);
    let params = params.clone();
    // The estimate, fit and tuning take up to a few seconds: not on the async threads.
    let measured = tokio::task::spawn_blocking(move || {
        use bdft_controller::identification::{BodyPrior, estimate, fit_record};
        let (points, fit) = match estimate(&excitation, dt, &cab, &device) {
            Err(e) => (
                Vec::new(),
                Err(format!("the record could not be estimated: {e}")),
            ),
            Ok(points) => {
                // With the record: the intervals are the jackknife's over its periods.
                let prior = BodyPrior::of(&params.population);
                let fit = fit_record(&points, &excitation, dt, &cab, &device, prior.as_ref())
                    .map(BodyFit::checked)
                    .map_err(|e| format!("the body fit failed: {e}"));
                (points, fit)
            }
        };
        // Only a body the data identified whole is tuned to (`BodyFit::identified_body`).
        let personalized = params
            .identification
            .as_ref()
            .is_some_and(|id| id.personalized);
        let designs = personalized.then(|| match &fit {
            Ok(fit) if fit.identified_body().is_ok() => personal_designs(&params, fit),
            _ => Vec::new(),
        });
        // Each cancelling cell checked with the design its tests run.
        let cancellation = cancellation::plan(
            &params,
            fit.as_ref().map_err(String::as_str),
            designs.as_deref(),
        );
        Measured {
            points,
            fit,
            designs,
            cancellation,
        }
    })
    .await;
    Some(measured.unwrap_or_else(|e| Measured {
        points: Vec::new(),
        fit: Err(format!("the estimation stopped: {e}")),
        designs: None,
        cancellation: Vec::new(),
    }))
}

/// What `identification.file` records: the fitted body in brief, or why there is none.
#[derive(Debug, Serialize)]
struct Filed<'a> {
    subject_id: i64,
    points: usize,
    k_h: Option<Reported>,
    torso_f_hz: Option<Reported>,
    arm_f_hz: Option<Reported>,
    residual_rms: Option<f64>,
    unidentified: Option<&'a BTreeMap<String, String>>,
    fit_error: Option<&'a str>,
}

/// Stores `measured` for `trial` in the filing's change, with its audit row.
pub async fn store(change: &mut Change, trial: &Trial, measured: &Measured) -> Result<()> {
    store::identifications::insert(
        change.db(),
        trial.id,
        trial.subject_id,
        &measured.points,
        measured.fit.as_ref().map_err(String::as_str),
        measured.designs.as_deref(),
    )
    .await?;
    if let Some(designs) = &measured.designs {
        personalize_tests(change, trial, designs).await?;
    }
    cancellation::store(change, trial, &measured.cancellation).await?;
    let fit = measured.fit.as_ref().ok();
    change
        .audit_also(
            "identification.file",
            Some(format!("trial:{}", trial.id)),
            Filed {
                subject_id: trial.subject_id,
                points: measured.points.len(),
                k_h: fit.map(|f| f.reported()[0].clone()),
                torso_f_hz: fit.map(|f| f.reported()[1].clone()),
                arm_f_hz: fit.map(|f| f.reported()[3].clone()),
                residual_rms: fit.map(|f| f.residual_rms),
                unidentified: fit.map(|f| &f.unidentified),
                fit_error: measured.fit.as_ref().err().map(String::as_str),
            },
        )
        .await
}

/// What `design.personalize` records: each design tuned to the subject, and how many of
/// their tests now run it.
#[derive(Debug, Serialize)]
struct Personalized<'a> {
    subject_id: i64,
    designs: &'a [PersonalDesign],
    tests: u64,
}

/// Puts each tuned design in place of the subject's scheduled tests of its kind, audited
/// as `design.personalize`; a design that could not be tuned leaves the study's in place
/// (its reason is in the record).
async fn personalize_tests(
    change: &mut Change,
    trial: &Trial,
    designs: &[PersonalDesign],
) -> Result<()> {
    let mut tests = 0;
    for d in designs {
        if let Some(spec) = &d.spec {
            let json = serde_json::to_string(spec).expect("specs serialize");
            tests += store::trials::personalize_scheduled(
                change.db(),
                trial.subject_id,
                d.compensator,
                &json,
            )
            .await?;
        }
    }
    change
        .audit_also(
            "design.personalize",
            Some(format!("subject:{}", trial.subject_id)),
            Personalized {
                subject_id: trial.subject_id,
                designs,
                tests,
            },
        )
        .await
}
