//! Stations for the experimenter: pairing by the shown code, the list, assigning a subject,
//! and what a station shows now (the live monitor's view).

use axum::extract::State;
use bdft_protocol::records::StationRole;
use bdft_protocol::server_to_browser::MonitorView;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson, Done};
use super::extract::{AppPath, Experimenter};
use crate::engine::procedure::{lsl, stations};
use crate::state::AppState;
use crate::store;
use crate::store::stations::Station;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_stations, pair_station))
        .routes(routes!(assign_station))
        .routes(routes!(monitor_view))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PairBody {
    /// The code the station shows.
    pairing_code: String,
    /// 1 to 200 characters.
    name: String,
    /// The seats the station serves: on, off or both.
    role: StationRole,
    /// The site it is at (`serve --site`; GET /api/controller lists them): the server's
    /// first site when absent.
    #[serde(default)]
    site: Option<String>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Paired {
    pub id: i64,
    pub name: String,
    pub role: StationRole,
    pub site: String,
}

/// Pair the station showing the code with the study.
#[utoipa::path(post, path = "/api/studies/{id}/stations", tag = "stations", params(("id" = i64, Path)),
    request_body = PairBody, responses((status = 200, body = Paired)))]
async fn pair_station(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(study_id): AppPath<i64>,
    AppJson(b): AppJson<PairBody>,
) -> ApiResult<Paired> {
    let site = match &b.site {
        Some(name) => s.sites.named(name)?,
        None => s.sites.first(),
    }
    .site()
    .to_string();
    let new = stations::NewStation {
        name: &b.name,
        role: b.role,
        site: &site,
    };
    let id = stations::pair(
        &s.pool,
        &s.pairing,
        &who.username,
        study_id,
        &b.pairing_code,
        new,
    )
    .await?;
    Ok(AppJson(Paired {
        id,
        name: b.name,
        role: b.role,
        site,
    }))
}

/// The study's stations.
#[utoipa::path(get, path = "/api/studies/{id}/stations", tag = "stations", params(("id" = i64, Path)),
    responses((status = 200, body = Vec<Station>)))]
async fn list_stations(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(study_id): AppPath<i64>,
) -> ApiResult<Vec<Station>> {
    Ok(AppJson(store::stations::of_study(&s.pool, study_id).await?))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AssignBody {
    /// A subject of the station's study, or null for none.
    subject_id: Option<i64>,
}

/// Assign a subject to the station (or none).
#[utoipa::path(post, path = "/api/stations/{id}/assign", tag = "stations", params(("id" = i64, Path)),
    request_body = AssignBody, responses((status = 200, body = Done)))]
async fn assign_station(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<AssignBody>,
) -> ApiResult<Done> {
    stations::assign(&s.pool, &s.sites, &who.username, id, b.subject_id).await?;
    lsl::station_assigned(&s.pool, &s.sites, id).await;
    Ok(Done::ok())
}

/// What the station shows now, with the compensator of the test at hand.
#[utoipa::path(get, path = "/api/stations/{id}/state", tag = "stations", params(("id" = i64, Path)),
    responses((status = 200, body = MonitorView)))]
async fn monitor_view(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<MonitorView> {
    Ok(AppJson(
        stations::monitor_view(&s.pool, &s.sockets, id).await?,
    ))
}
