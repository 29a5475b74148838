//! Tests: start, abort, redo, accept as incomplete, and notes.

use axum::extract::State;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::bodies::ReasonBody;
use super::error::{ApiResult, AppJson, Done, optional_json};
use super::extract::{AppPath, Experimenter};
use crate::engine::accounts::Drive;
use crate::engine::procedure::{stations, trials};
use crate::state::AppState;
use crate::store::trials::Trial;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(start_trial))
        .routes(routes!(abort_trial))
        .routes(routes!(redo_trial))
        .routes(routes!(accept_incomplete))
        .routes(routes!(add_note))
}

/// Start the subject's next test on the controller of its site (the account's sites,
/// consent, order, surveys and the rig are checked first).
#[utoipa::path(post, path = "/api/trials/{id}/start", tag = "trials", params(("id" = i64, Path)),
    responses((status = 200, body = Trial)))]
async fn start_trial(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<Trial> {
    let site = stations::site_driven_by(&s.pool, &s.sites, id).await?;
    who.may_drive(&s.pool, Drive::Start, &[&site]).await?;
    Ok(AppJson(
        trials::start(&s.pool, &s.sites, &who.username, id).await?,
    ))
}

/// Stop a running test early; it is filed aborted with the reason. An account limited to
/// sites aborts its sites' tests only (any account may press any site's E-stop).
#[utoipa::path(post, path = "/api/trials/{id}/abort", tag = "trials", params(("id" = i64, Path)),
    request_body = ReasonBody, responses((status = 200, body = Done)))]
async fn abort_trial(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<Done> {
    let site = stations::site_driven_by(&s.pool, &s.sites, id).await?;
    who.may_drive(&s.pool, Drive::Abort, &[&site]).await?;
    trials::abort(&s.pool, &s.sites, &who.username, id, &b.reason).await?;
    Ok(Done::ok())
}

#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RedoBody {
    /// Why (at most 500 characters; kept in the audit log).
    #[serde(default)]
    reason: String,
}

/// Add another attempt of a finished test (its latest attempt only).
#[utoipa::path(post, path = "/api/trials/{id}/redo", tag = "trials", params(("id" = i64, Path)),
    request_body(content = Option<RedoBody>, description = "optional"), responses((status = 200, body = Trial)))]
async fn redo_trial(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    body: axum::body::Bytes,
) -> ApiResult<Trial> {
    let b: RedoBody = optional_json(&body, "redo")?;
    Ok(AppJson(
        trials::redo(&s.pool, &who.username, id, &b.reason).await?,
    ))
}

/// Accept a test as incomplete with a reason (any of its attempts may be named; the latest
/// is accepted): it is not run again and counts as missing with the reason.
#[utoipa::path(post, path = "/api/trials/{id}/incomplete", tag = "trials", params(("id" = i64, Path)),
    request_body = ReasonBody, responses((status = 200, body = Trial)))]
async fn accept_incomplete(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<Trial> {
    Ok(AppJson(
        trials::accept_incomplete(&s.pool, &who.username, id, &b.reason).await?,
    ))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NoteBody {
    /// 1 to 2000 characters.
    text: String,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct NoteAdded {
    pub id: i64,
}

/// Add a note about a test.
#[utoipa::path(post, path = "/api/trials/{id}/note", tag = "trials", params(("id" = i64, Path)),
    request_body = NoteBody, responses((status = 200, body = NoteAdded)))]
async fn add_note(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<NoteBody>,
) -> ApiResult<NoteAdded> {
    Ok(AppJson(NoteAdded {
        id: trials::add_note(&s.pool, &who.username, id, &b.text).await?,
    }))
}
