//! Versioned controller configurations: list, create a version, get one; a study's pick of
//! versions.

use axum::extract::State;
use bdft_protocol::params::CompensatorSpec;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson};
use super::extract::{AppPath, Experimenter};
use crate::engine::study::configs;
use crate::state::AppState;
use crate::store;
use crate::store::configs::ConfigVersion;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_configs, create_config))
        .routes(routes!(get_config))
        .routes(routes!(study_configs, pick_configs))
}

/// Every configuration version, by name then version.
#[utoipa::path(get, path = "/api/configs", tag = "configs", responses((status = 200, body = Vec<ConfigVersion>)))]
async fn list_configs(
    State(s): State<AppState>,
    _who: Experimenter,
) -> ApiResult<Vec<ConfigVersion>> {
    Ok(AppJson(store::configs::all(&s.pool).await?))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ConfigBody {
    /// 1 to 200 characters; an existing name gets its next version.
    name: String,
    /// The design (validated, and built on the published plant as the controller builds it).
    spec: CompensatorSpec,
}

/// A new version of a configuration (the next version of `name`); versions never change.
#[utoipa::path(post, path = "/api/configs", tag = "configs", request_body = ConfigBody,
    responses((status = 200, body = ConfigVersion)))]
async fn create_config(
    State(s): State<AppState>,
    who: Experimenter,
    AppJson(b): AppJson<ConfigBody>,
) -> ApiResult<ConfigVersion> {
    Ok(AppJson(
        configs::create(&s.pool, &who.username, &b.name, &b.spec).await?,
    ))
}

#[utoipa::path(get, path = "/api/configs/{id}", tag = "configs", params(("id" = i64, Path)),
    responses((status = 200, body = ConfigVersion)))]
async fn get_config(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<ConfigVersion> {
    Ok(AppJson(store::configs::get(&s.pool, id).await?))
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PickBody {
    /// Configuration versions, at most one per compensator kind; each replaces the study's
    /// design of its kind.
    config_ids: Vec<i64>,
}

/// The versions the study picked (kind → version id).
#[utoipa::path(get, path = "/api/studies/{id}/configs", tag = "configs", params(("id" = i64, Path)),
    responses((status = 200, body = Vec<ConfigVersion>)))]
async fn study_configs(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<Vec<ConfigVersion>> {
    store::studies::get(&s.pool, id).await?;
    let mut out = Vec::new();
    for (_, config_id) in store::configs::picked(&s.pool, id).await? {
        out.push(store::configs::get(&s.pool, config_id).await?);
    }
    Ok(AppJson(out))
}

/// Puts the versions in place of the study's designs of their kinds (a new study version);
/// 409 once the study is locked.
#[utoipa::path(put, path = "/api/studies/{id}/configs", tag = "configs", params(("id" = i64, Path)),
    request_body = PickBody, responses((status = 200, body = Vec<ConfigVersion>)))]
async fn pick_configs(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<PickBody>,
) -> ApiResult<Vec<ConfigVersion>> {
    configs::pick(&s.pool, &who.username, id, &b.config_ids).await?;
    study_configs(State(s), who, AppPath(id)).await
}
