//! The station's own API (bearer token of a paired station, acting for the subject assigned
//! to it): registering for a pairing code and waiting to be paired, what to show now,
//! consent, surveys and the display's timing figures.

use std::net::SocketAddr;
use std::time::Instant;

use axum::extract::{ConnectInfo, State};
use bdft_protocol::browser_to_server::{ConsentRequest, SurveySubmission, TimingReport};
use bdft_protocol::server_to_browser::StationView;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppError, AppJson, Done, ErrorBody};
use super::extract::StationAuth;
use crate::engine::procedure::stations::{PAIRING_WAIT, PairingState};
use crate::engine::procedure::{stations, subjects};
use crate::state::AppState;

/// Anyone may register a browser as a station (it is useless until paired).
pub fn public() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(register))
        .routes(routes!(pairing))
}

/// Routes of a paired station.
pub fn station() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(state))
        .routes(routes!(consent))
        .routes(routes!(survey))
        .routes(routes!(timing))
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Registered {
    /// The station's bearer token (kept by the browser).
    pub token: String,
    /// The code the station shows for the experimenter to pair it.
    pub pairing_code: String,
}

/// Register this browser as a station: a token and a pairing code to show. 429 with
/// Retry-After past an address's registrations per minute; an address showing its most codes
/// at once has its oldest withdrawn; 503 while the server shows all the codes it keeps.
#[utoipa::path(post, path = "/api/station/register", tag = "station", responses(
    (status = 200, body = Registered),
    (status = 429, body = ErrorBody, description = "too many registrations from this address; Retry-After says when to ask again"),
    (status = 503, body = ErrorBody, description = "the server shows all the pairing codes it keeps")))]
async fn register(
    State(s): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
) -> ApiResult<Registered> {
    let (token, pairing_code) = s
        .pairing
        .register(peer.ip().to_canonical(), Instant::now())?;
    Ok(AppJson(Registered {
        token,
        pairing_code,
    }))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PairingQuery {
    /// The token `register` gave.
    token: String,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct PairingAnswer {
    /// The experimenter paired the station: its token now works.
    pub paired: bool,
}

/// Wait for the experimenter to pair this station: answers as soon as it is paired, or
/// `paired: false` after 25 s (ask again); 404 when the code expired or is unknown
/// (register again). The page waits here instead of polling its state.
#[utoipa::path(post, path = "/api/station/pairing", tag = "station", request_body = PairingQuery,
    responses((status = 200, body = PairingAnswer)))]
async fn pairing(
    State(s): State<AppState>,
    AppJson(q): AppJson<PairingQuery>,
) -> ApiResult<PairingAnswer> {
    match s.pairing.wait(&s.pool, &q.token, PAIRING_WAIT).await? {
        PairingState::Paired => Ok(AppJson(PairingAnswer { paired: true })),
        PairingState::Pending => Ok(AppJson(PairingAnswer { paired: false })),
        PairingState::Unknown => Err(AppError::NotFound(
            "pairing code (it expired or the server restarted; register again)",
        )),
    }
}

/// What the station shows now (never a compensator's name).
#[utoipa::path(get, path = "/api/station/state", tag = "station", responses((status = 200, body = StationView)))]
async fn state(
    State(s): State<AppState>,
    StationAuth(station): StationAuth,
) -> ApiResult<StationView> {
    Ok(AppJson(stations::station_view(&s.pool, &station).await?))
}

/// The subject agrees to or declines the consent form; answers what to show next.
#[utoipa::path(post, path = "/api/station/consent", tag = "station", request_body = ConsentRequest,
    responses((status = 200, body = StationView)))]
async fn consent(
    State(s): State<AppState>,
    StationAuth(station): StationAuth,
    AppJson(b): AppJson<ConsentRequest>,
) -> ApiResult<StationView> {
    let subject_id = stations::subject_of(&station)?;
    subjects::consent(&s.pool, subject_id, b.decision, &station.name).await?;
    Ok(AppJson(stations::station_view(&s.pool, &station).await?))
}

/// The subject's survey of a completed test; answers what to show next.
#[utoipa::path(post, path = "/api/station/survey", tag = "station", request_body = SurveySubmission,
    responses((status = 200, body = StationView)))]
async fn survey(
    State(s): State<AppState>,
    StationAuth(station): StationAuth,
    AppJson(b): AppJson<SurveySubmission>,
) -> ApiResult<StationView> {
    let trial = stations::own_trial(&s.pool, &station, b.trial_id).await?;
    subjects::answer_survey(&s.pool, &trial, &b).await?;
    Ok(AppJson(stations::station_view(&s.pool, &station).await?))
}

/// How the display kept up during a test (frames, long frames, input round trip).
#[utoipa::path(post, path = "/api/station/timing", tag = "station", request_body = TimingReport,
    responses((status = 200, body = Done)))]
async fn timing(
    State(s): State<AppState>,
    StationAuth(station): StationAuth,
    AppJson(b): AppJson<TimingReport>,
) -> ApiResult<Done> {
    stations::own_trial(&s.pool, &station, b.trial_id).await?;
    subjects::report_timing(&s.pool, &station.name, &b).await?;
    Ok(Done::ok())
}
