//! What a completed identification test measured: its record's feedthrough at the excited
//! frequencies and the seated body fitted to it (`bdft_controller::identification`),
//! computed off the async threads before the filing's transaction and stored in it, with
//! its audit row.

use bdft_protocol::identification::{BodyFit, Estimate, FrfPoint};
use bdft_protocol::records::TestPhase;
use bdft_protocol::trial::{TargetSpec, record_channel};
use serde::Serialize;

use crate::engine::study::schedule::identification_target;
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
}

/// What `trial`'s record measured, when `trial` is an identification test of a study with
/// `params`; none for any other test.
pub async fn measure(
    params: &bdft_protocol::study::StudyParams,
    trial: &Trial,
    record: &Record,
) -> Option<Measured> {
    if trial.phase != TestPhase::Identification {
        return None;
    }
    let Some(TargetSpec::Identification { excitation, .. }) =
        identification_target(params, trial.target_seed as u64)
    else {
        return Some(Measured {
            points: Vec::new(),
            fit: Err("the study has no identification test".into()),
        });
    };
    let channel = |name| {
        record_channel(name)
            .and_then(|i| record.channels.get(i))
            .cloned()
            .unwrap_or_default()
    };
    let (cab, device, dt) = (channel("cab_accel_mm_s2"), channel("device_mm"), record.dt);
    // The estimate and fit take up to a second: not on the async threads.
    let measured = tokio::task::spawn_blocking(move || {
        use bdft_controller::identification::{estimate, fit_body};
        match estimate(&excitation, dt, &cab, &device) {
            Err(e) => Measured {
                points: Vec::new(),
                fit: Err(format!("the record could not be estimated: {e}")),
            },
            Ok(points) => {
                let fit = fit_body(&points).map_err(|e| format!("the body fit failed: {e}"));
                Measured { points, fit }
            }
        }
    })
    .await;
    Some(measured.unwrap_or_else(|e| Measured {
        points: Vec::new(),
        fit: Err(format!("the estimation stopped: {e}")),
    }))
}

/// What `identification.file` records: the fitted body in brief, or why there is none.
#[derive(Debug, Serialize)]
struct Filed<'a> {
    subject_id: i64,
    points: usize,
    k_h: Option<Estimate>,
    torso_f_hz: Option<Estimate>,
    arm_f_hz: Option<Estimate>,
    residual_rms: Option<f64>,
    unidentified: Option<&'a [String]>,
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
    )
    .await?;
    let fit = measured.fit.as_ref().ok();
    change
        .audit_also(
            "identification.file",
            Some(format!("trial:{}", trial.id)),
            Filed {
                subject_id: trial.subject_id,
                points: measured.points.len(),
                k_h: fit.map(|f| f.k_h),
                torso_f_hz: fit.map(|f| f.torso_f_hz),
                arm_f_hz: fit.map(|f| f.arm_f_hz),
                residual_rms: fit.map(|f| f.residual_rms),
                unidentified: fit.map(|f| f.unidentified.as_slice()),
                fit_error: measured.fit.as_ref().err().map(String::as_str),
            },
        )
        .await
}
