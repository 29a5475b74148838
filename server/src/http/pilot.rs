//! Pilot runs from the dashboard: synthetic subjects through the whole protocol, in the
//! background, with progress, always in a dry run (a study's dry-run copy), never in a
//! study with people.

use axum::extract::State;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson};
use super::extract::{AppPath, Experimenter};
use crate::engine::dry_runs::job::JobStatus;
use crate::engine::dry_runs::pilot::{PilotReport, PilotStatus};
use crate::engine::study::dry_run::{self, DryRunInfo};
use crate::state::AppState;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(start_pilot))
        .routes(routes!(pilot_status))
        .routes(routes!(dry_run_info, make_dry_run))
}

/// Whether the study is a dry run (synthetic subjects only), which study it copies, and its
/// dry-run copy if it has one.
#[utoipa::path(get, path = "/api/studies/{id}/dry-run", tag = "pilot", params(("id" = i64, Path)),
    responses((status = 200, body = DryRunInfo)))]
async fn dry_run_info(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<DryRunInfo> {
    Ok(AppJson(dry_run::info(&s.pool, id).await?))
}

/// The study's dry-run copy (same parameters and seed), made now if it has none: where
/// synthetic subjects and pilots go.
#[utoipa::path(post, path = "/api/studies/{id}/dry-run", tag = "pilot", params(("id" = i64, Path)),
    responses((status = 200, body = DryRunInfo)))]
async fn make_dry_run(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<DryRunInfo> {
    let copy = dry_run::for_pilot(&s.pool, &who.username, id).await?;
    Ok(AppJson(dry_run::info(&s.pool, copy).await?))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PilotBody {
    /// Synthetic subjects to run: 1 to 50.
    subjects: u32,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct PilotStarted {
    pub started: bool,
}

/// Dry-run the protocol with synthetic subjects in the background, in the study's dry-run
/// copy (progress at GET /api/pilot).
#[utoipa::path(post, path = "/api/studies/{id}/pilot", tag = "pilot", params(("id" = i64, Path)),
    request_body = PilotBody, responses((status = 200, body = PilotStarted)))]
async fn start_pilot(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<PilotBody>,
) -> ApiResult<PilotStarted> {
    s.pilot
        .start(&s.pool, &who.username, id, b.subjects)
        .await?;
    Ok(AppJson(PilotStarted { started: true }))
}

/// Where the dashboard's pilot run stands.
#[utoipa::path(get, path = "/api/pilot", tag = "pilot", responses((status = 200, body = JobStatus<PilotReport>)))]
async fn pilot_status(State(s): State<AppState>, _who: Experimenter) -> AppJson<PilotStatus> {
    AppJson(s.pilot.status())
}
