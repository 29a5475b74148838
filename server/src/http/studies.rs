//! Studies: the published protocol's defaults, creating, reading and editing a study.

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use bdft_protocol::study::StudyParams;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::bodies::ReasonBody;
use super::error::{ApiResult, AppError, AppJson};
use super::extract::{AppPath, Experimenter};
use crate::engine::study::schedule::default_params;
use crate::engine::study::stability::StabilityReport;
use crate::engine::study::studies;
use crate::state::AppState;
use crate::store;
use crate::store::studies::{Edit, Study};

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(defaults))
        .routes(routes!(list_studies, create_study))
        .routes(routes!(get_study, update_study))
        .routes(routes!(stability))
        .routes(routes!(acknowledge_instability))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StudyBody {
    /// 1 to 200 characters.
    name: String,
    /// Default: the published protocol. Required when editing.
    params: Option<StudyParams>,
    /// Seed of every random draw (schedules, targets); default random. Below 2^53; fixed
    /// at creation.
    seed: Option<u64>,
    /// When editing (required): the `version` of the study the edit is based on. An edit
    /// based on an older version is refused with 409 and the current study.
    version: Option<i64>,
}

/// The answer to an edit based on an older version of the study: nothing was saved.
#[derive(Debug, Serialize, ToSchema)]
pub struct StaleEdit {
    /// What happened and what to do, in words for the experimenter.
    error: String,
    /// The study's version now.
    current_version: i64,
    /// The study as it is now (with the other change).
    current: Study,
}

/// Default study parameters (the published protocol).
#[utoipa::path(get, path = "/api/defaults", tag = "studies", responses((status = 200, body = StudyParams)))]
async fn defaults(_who: Experimenter) -> AppJson<StudyParams> {
    AppJson(default_params())
}

/// Every study.
#[utoipa::path(get, path = "/api/studies", tag = "studies", responses((status = 200, body = Vec<Study>)))]
async fn list_studies(State(s): State<AppState>, _who: Experimenter) -> ApiResult<Vec<Study>> {
    Ok(AppJson(store::studies::all(&s.pool).await?))
}

/// Create a study (default parameters: the published protocol).
#[utoipa::path(post, path = "/api/studies", tag = "studies", request_body = StudyBody,
    responses((status = 200, body = Study)))]
async fn create_study(
    State(s): State<AppState>,
    who: Experimenter,
    AppJson(b): AppJson<StudyBody>,
) -> ApiResult<Study> {
    if b.version.is_some() {
        return Err(AppError::BadRequest(
            "version: only when editing (a new study is version 1)".into(),
        ));
    }
    let params = b.params.unwrap_or_else(default_params);
    let id = studies::create(&s.pool, &who.username, &b.name, &params, b.seed).await?;
    s.stability.prefetch(&params);
    Ok(AppJson(store::studies::get(&s.pool, id).await?))
}

/// One study.
#[utoipa::path(get, path = "/api/studies/{id}", tag = "studies", params(("id" = i64, Path)),
    responses((status = 200, body = Study)))]
async fn get_study(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<Study> {
    Ok(AppJson(store::studies::get(&s.pool, id).await?))
}

/// Edit a study's name and parameters (until its protocol is locked by the first
/// enrolment). The body names the version it was based on; if the study changed since, the
/// edit is refused with 409 and the current study, so no change is silently lost.
#[utoipa::path(put, path = "/api/studies/{id}", tag = "studies", params(("id" = i64, Path)),
    request_body = StudyBody, responses((status = 200, body = Study),
        (status = 409, body = StaleEdit, description = "the study changed since `version` (the answer has the current study), or its protocol is locked (an ErrorBody)")))]
async fn update_study(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<StudyBody>,
) -> Result<Response, AppError> {
    let params = b
        .params
        .ok_or_else(|| AppError::BadRequest("params: required".into()))?;
    let version = b.version.ok_or_else(|| {
        AppError::BadRequest(
            "version: required, the version of the study this edit is based on (as GET /api/studies/{id} gave it)".into(),
        )
    })?;
    if b.seed.is_some() {
        return Err(AppError::BadRequest(
            "seed: fixed when the study is created".into(),
        ));
    }
    match studies::update(&s.pool, &who.username, id, version, &b.name, &params).await? {
        Edit::Saved => {
            s.stability.prefetch(&params);
            Ok(AppJson(store::studies::get(&s.pool, id).await?).into_response())
        }
        Edit::Stale(current) => Ok((
            StatusCode::CONFLICT,
            AppJson(StaleEdit {
                error: format!(
                    "study #{id} was changed by someone else since version {version} (it is at version {}): nothing was saved; look at the current study and make the edit again",
                    current.version
                ),
                current_version: current.version,
                current: *current,
            }),
        )
            .into_response()),
    }
}

/// Every compensator of the study analysed at its K_BF with its plant and body, on and off
/// the machine: the verdict, the largest stable K_BF and whether it keeps the margin.
#[utoipa::path(get, path = "/api/studies/{id}/stability", tag = "studies", params(("id" = i64, Path)),
    responses((status = 200, body = StabilityReport)))]
async fn stability(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<StabilityReport> {
    let study = store::studies::get(&s.pool, id).await?;
    Ok(AppJson(s.stability.report(&study.params).await?))
}

/// Acknowledge that a design of a simulated study is unstable on the machine, so the study
/// can be locked and run in simulation (refused for the real machine).
#[utoipa::path(post, path = "/api/studies/{id}/acknowledge-instability", tag = "studies",
    params(("id" = i64, Path)), request_body = ReasonBody, responses((status = 200, body = StabilityReport)))]
async fn acknowledge_instability(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<StabilityReport> {
    Ok(AppJson(
        studies::acknowledge_instability(&s.pool, &s.stability, &who.username, id, &b.reason)
            .await?,
    ))
}
