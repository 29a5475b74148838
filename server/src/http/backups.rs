//! Backups, for admins only (the experimenter layer refuses everyone else on
//! `/api/backups`): the backup directory with its schedule and the backups it holds, and a
//! backup made now. Restoring is done on a stopped server (`bdft-server restore`), never
//! over HTTP.

use axum::extract::State;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson, ErrorBody};
use super::extract::Experimenter;
use crate::engine::operations::manifest::Manifest;
use crate::engine::operations::schedule::BackupsView;
use crate::state::AppState;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(list_backups, back_up_now))
}

/// The backup directory, its schedule, and the backups it holds with their manifests,
/// newest first.
#[utoipa::path(get, path = "/api/backups", tag = "backups", responses((status = 200, body = BackupsView)))]
async fn list_backups(State(s): State<AppState>) -> ApiResult<BackupsView> {
    Ok(AppJson(s.backups.view()?))
}

/// Back the database up now into the backup directory: answers with the manifest once the
/// copy has passed its checks (the oldest beyond the number kept are then deleted).
#[utoipa::path(post, path = "/api/backups", tag = "backups",
    responses((status = 200, body = Manifest),
              (status = 409, body = ErrorBody, description = "backups are off (no --backup-dir, or a PostgreSQL store), or a backup is being made")))]
async fn back_up_now(State(s): State<AppState>, who: Experimenter) -> ApiResult<Manifest> {
    Ok(AppJson(s.backups.now(&s.pool, &who.username).await?))
}
