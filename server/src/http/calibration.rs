//! Calibration from the dashboard: fit a study's synthetic population to a table of cell
//! means or to its own completed tests, in the background, with progress and cancel; the
//! result is the study's next population version.

use axum::extract::State;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson};
use super::extract::{AppPath, Experimenter};
use crate::engine::dry_runs::calibration::run::{
    CalibrateRequest, CalibrationReport, CalibrationStatus,
};
use crate::engine::dry_runs::job::JobStatus;
use crate::state::AppState;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(start_calibration))
        .routes(routes!(calibration_status))
        .routes(routes!(cancel_calibration))
}

#[derive(Debug, Serialize, ToSchema)]
pub struct CalibrationStarted {
    pub started: bool,
}

/// Calibrate the study's population in the background (progress at GET /api/calibration);
/// a bad table (unknown controller, a cell the study cannot run, a negative mean, too few
/// cells) is refused with a 422 naming the row.
#[utoipa::path(post, path = "/api/studies/{id}/calibrate", tag = "pilot", params(("id" = i64, Path)),
    request_body = CalibrateRequest, responses((status = 200, body = CalibrationStarted)))]
async fn start_calibration(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(req): AppJson<CalibrateRequest>,
) -> ApiResult<CalibrationStarted> {
    s.calibration.start(&s.pool, &who.username, id, req).await?;
    Ok(AppJson(CalibrationStarted { started: true }))
}

/// Where the background calibration stands: progress (simulated trials), then its report or
/// error.
#[utoipa::path(get, path = "/api/calibration", tag = "pilot", responses((status = 200, body = JobStatus<CalibrationReport>)))]
async fn calibration_status(
    State(s): State<AppState>,
    _who: Experimenter,
) -> AppJson<CalibrationStatus> {
    AppJson(s.calibration.status())
}

/// Stops the running calibration (nothing is stored).
#[utoipa::path(post, path = "/api/calibration/cancel", tag = "pilot", responses((status = 200, body = CalibrationStarted)))]
async fn cancel_calibration(
    State(s): State<AppState>,
    _who: Experimenter,
) -> AppJson<CalibrationStarted> {
    s.calibration.cancel();
    AppJson(CalibrationStarted { started: false })
}
