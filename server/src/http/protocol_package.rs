//! The ethics board's protocol package of a study: a printable HTML page
//! (`engine::operations::protocol_package`), served with the pages' strict headers.

use axum::extract::State;
use axum::response::Response;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::AppError;
use super::extract::{AppPath, Experimenter};
use super::page;
use crate::engine::operations::protocol_package;
use crate::state::AppState;
use crate::store;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(protocol_html))
}

/// The study's protocol for the ethics board as one printable page: consent text,
/// instructions, schedule design, randomization, targets, compensators, surveys, stopping
/// rules and the data kept, rendered from the hashed parameters, with the protocol hash on
/// every printed page (print it to PDF from the browser).
#[utoipa::path(get, path = "/api/studies/{id}/protocol.html", tag = "studies", params(("id" = i64, Path)),
    responses((status = 200, content_type = "text/html", body = String)))]
async fn protocol_html(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> Result<Response, AppError> {
    let study = store::studies::get(&s.pool, id).await?;
    let audit_key = s
        .audit_public
        .as_ref()
        .map(store::audit_chain::public_key_hex);
    let html = protocol_package::render(&study, store::db::now_ms(), audit_key.as_deref());
    Ok(page::response("text/html; charset=utf-8", html))
}
