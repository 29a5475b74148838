//! Erasure on request (admins only, `extract`): erase a subject's data, and the erasures so
//! far with the backups that still hold each one's data.

use axum::extract::State;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::bodies::ReasonBody;
use super::error::{ApiResult, AppJson};
use super::extract::{AppPath, Experimenter};
use crate::engine::operations::erasure::{self, Erasure, ErasureReport};
use crate::state::AppState;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(erase))
        .routes(routes!(list_erasures))
}

/// Erase the subject's data (admins only): their tests, records, surveys, notes and
/// identifying fields are removed, and the details of the audit log's rows about them; the
/// audit log keeps that the erasure happened, when, by whom, why, and the subject's code.
/// The answer lists the backups made before it, which still hold the data.
#[utoipa::path(post, path = "/api/subjects/{id}/erase", tag = "subjects", params(("id" = i64, Path)),
    request_body = ReasonBody,
    responses((status = 200, body = ErasureReport),
        (status = 409, body = super::error::ErrorBody, description = "the subject has a running test, or was erased already")))]
async fn erase(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<ErasureReport> {
    Ok(AppJson(
        erasure::erase(&s.pool, &who.username, id, &b.reason, s.backups.dir()).await?,
    ))
}

/// The erasures so far, each with the backups that still hold its data.
#[derive(Debug, Serialize, ToSchema)]
pub struct Erasures {
    /// The backup directory looked in (`serve --backup-dir`); absent when none is set, and then
    /// no backup could be checked.
    pub backup_dir: Option<String>,
    pub erasures: Vec<Erasure>,
}

/// Every erasure, oldest first, with the backups older than it (admins only).
#[utoipa::path(get, path = "/api/erasures", tag = "subjects", responses((status = 200, body = Erasures)))]
async fn list_erasures(State(s): State<AppState>, _who: Experimenter) -> ApiResult<Erasures> {
    Ok(AppJson(Erasures {
        backup_dir: s.backups.dir().map(|d| d.display().to_string()),
        erasures: erasure::erasures(&s.pool, s.backups.dir()).await?,
    }))
}
