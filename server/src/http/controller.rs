//! The real-time controller: health, its link and latch, the E-stop and its reset.

use axum::extract::State;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson, Done};
use super::extract::Experimenter;
use crate::engine::procedure::trials;
use crate::state::AppState;

pub fn public() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(health))
}

pub fn experimenter() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(estop))
        .routes(routes!(estop_reset))
        .routes(routes!(controller_status))
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    pub ok: bool,
    pub controller_connected: bool,
}

/// Liveness, and whether the controller is connected.
#[utoipa::path(get, path = "/api/health", tag = "controller", responses((status = 200, body = Health)))]
async fn health(State(s): State<AppState>) -> AppJson<Health> {
    AppJson(Health {
        ok: true,
        controller_connected: s.controller.is_connected(),
    })
}

/// A confirmed E-stop.
#[derive(Debug, Serialize, ToSchema)]
pub struct EStopConfirmed {
    pub ok: bool,
    /// From the server's handling of the request to the controller's confirmation (ms).
    pub confirmed_ms: f64,
}

/// Emergency stop: every valve to zero, every trial stopped; latched until reset. Answers
/// only once the controller confirms; 503 "NOT confirmed" otherwise.
#[utoipa::path(post, path = "/api/estop", tag = "controller", responses((status = 200, body = EStopConfirmed)))]
async fn estop(State(s): State<AppState>, who: Experimenter) -> ApiResult<EStopConfirmed> {
    let took = trials::estop(&s.pool, &s.controller, &who.username).await?;
    Ok(AppJson(EStopConfirmed {
        ok: true,
        confirmed_ms: took.as_secs_f64() * 1e3,
    }))
}

/// Clear the E-stop latch.
#[utoipa::path(post, path = "/api/estop/reset", tag = "controller", responses((status = 200, body = Done)))]
async fn estop_reset(State(s): State<AppState>, who: Experimenter) -> ApiResult<Done> {
    trials::reset_estop(&s.pool, &s.controller, &who.username).await?;
    Ok(Done::ok())
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ControllerStatus {
    pub connected: bool,
    /// Process id of the controller this server started, if any.
    pub pid: Option<u32>,
    /// "sim" or "udp".
    pub rig: Option<String>,
    /// The E-stop latch as starts see it: the controller's or the server's stored one.
    pub estop_latched: bool,
    /// Whether the E-stop's own connection is up (the control connection carries every
    /// E-stop too).
    pub estop_path: bool,
    /// Why the link last went down, if it did (shown while it is down).
    pub down_because: Option<String>,
}

/// The controller's link, rig and E-stop latch.
#[utoipa::path(get, path = "/api/controller", tag = "controller", responses((status = 200, body = ControllerStatus)))]
async fn controller_status(
    State(s): State<AppState>,
    _who: Experimenter,
) -> ApiResult<ControllerStatus> {
    // Latched if either end holds it: starts are refused on the server's own latch too, so
    // the dashboard must not offer Start while the controller is away and the latch is set.
    let stored = crate::store::latch::latched(&s.pool).await?;
    Ok(AppJson(ControllerStatus {
        connected: s.controller.is_connected(),
        pid: s.controller.pid(),
        rig: s.controller.rig(),
        estop_latched: s.controller.estop_latched() || stored,
        estop_path: s.controller.estop_path_up(),
        down_because: s.controller.down_because(),
    }))
}
