//! The real-time controllers, one per site: health, their links and latches, the E-stop
//! (of one site or all) and its reset.

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson, Done};
use super::extract::{AppQuery, Experimenter};
use crate::engine::accounts::Drive;
use crate::engine::machine::controller_link::ControllerLink;
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
    /// Whether every site's controller is connected.
    pub controller_connected: bool,
}

/// Liveness, and whether every site's controller is connected.
#[utoipa::path(get, path = "/api/health", tag = "controller", responses((status = 200, body = Health)))]
async fn health(State(s): State<AppState>) -> AppJson<Health> {
    AppJson(Health {
        ok: true,
        controller_connected: s.sites.all_connected(),
    })
}

/// A confirmed E-stop.
#[derive(Debug, Serialize, ToSchema)]
pub struct EStopConfirmed {
    pub ok: bool,
    /// From the server's handling of the request to the slowest controller's confirmation
    /// (ms).
    pub confirmed_ms: f64,
    /// The sites stopped.
    pub sites: Vec<String>,
    /// Why the latch could not be written to its file, if it could not: it holds in this
    /// server's memory, but a restart of the server would not keep it (absent when kept).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub latch_not_kept: Option<String>,
}

/// Which site an E-stop or its reset is for.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct SiteQuery {
    /// One site (GET /api/controller lists them); every site when absent.
    site: Option<String>,
}

/// Emergency stop: every valve to zero, every trial stopped, at every site or at `site`
/// alone (every site when it names none served here, or the query does not parse); latched
/// until reset. Answers only once each controller confirms; 503 "NOT
/// confirmed", naming the sites, otherwise. Never waits for the database: the latch is kept
/// outside it and the audit row follows when the store allows.
#[utoipa::path(post, path = "/api/estop", tag = "controller", params(SiteQuery),
    responses((status = 200, body = EStopConfirmed)))]
async fn estop(
    State(s): State<AppState>,
    who: Experimenter,
    q: Result<Query<SiteQuery>, QueryRejection>,
) -> ApiResult<EStopConfirmed> {
    // A query that does not parse stops every site: an E-stop is never refused for its
    // parameters.
    let site = q.ok().and_then(|Query(q)| q.site);
    let stopped = trials::estop(&s.sites, &who.username, site.as_deref()).await?;
    Ok(AppJson(EStopConfirmed {
        ok: true,
        confirmed_ms: stopped.slowest.as_secs_f64() * 1e3,
        sites: stopped.sites,
        latch_not_kept: stopped.latch_not_kept,
    }))
}

/// Clear the E-stop latch of every site, or of `site` alone (refused while every site's is
/// latched). An account limited to sites resets its sites' alone: the latch of every site
/// only when its sites are all the server's (403 otherwise).
#[utoipa::path(post, path = "/api/estop/reset", tag = "controller", params(SiteQuery),
    responses((status = 200, body = Done)))]
async fn estop_reset(
    State(s): State<AppState>,
    who: Experimenter,
    AppQuery(q): AppQuery<SiteQuery>,
) -> ApiResult<Done> {
    match q.site.as_deref() {
        // A site this server does not serve is refused by the reset itself, naming the sites.
        Some(name) if s.sites.named(name).is_ok() => {
            who.may_drive(&s.pool, Drive::Reset, &[name]).await?;
        }
        Some(_) => {}
        None => {
            who.may_drive(&s.pool, Drive::ResetEverySite, &s.sites.names())
                .await?;
        }
    }
    trials::reset_estop(&s.pool, &s.sites, &who.username, q.site.as_deref()).await?;
    Ok(Done::ok())
}

/// The controllers: every site's together (the dashboard's light and latch), and each.
#[derive(Debug, Serialize, ToSchema)]
pub struct ControllerStatus {
    /// Every site together: connected when every site is, latched when any site is, the
    /// first site's pid and rig, the first reason a site went down (named when there are
    /// several).
    #[serde(flatten)]
    pub all: LinkState,
    /// Each site, in the order `serve --site` gave them.
    pub sites: Vec<SiteStatus>,
}

/// One site's controller.
#[derive(Debug, Serialize, ToSchema)]
pub struct SiteStatus {
    pub site: String,
    #[serde(flatten)]
    pub link: LinkState,
}

/// A controller link as the dashboard shows it.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct LinkState {
    pub connected: bool,
    /// Process id of the controller, if this server started it.
    pub pid: Option<u32>,
    /// "sim" or "udp".
    pub rig: Option<String>,
    /// The E-stop latch as starts see it: the controller's, the site's stored one, or that
    /// of every site.
    pub estop_latched: bool,
    /// Whether the E-stop's own connection is up (the control connection carries every
    /// E-stop too).
    pub estop_path: bool,
    /// Why the link last went down, if it did (shown while it is down).
    pub down_because: Option<String>,
}

fn site_status(link: &ControllerLink) -> SiteStatus {
    SiteStatus {
        site: link.site().to_string(),
        link: LinkState {
            connected: link.is_connected(),
            pid: link.pid(),
            rig: link.rig(),
            // Latched if either end holds it: starts are refused on the server's own latch too, so
            // the dashboard must not offer Start while the controller is away and the latch is set.
            estop_latched: link.stopped(),
            estop_path: link.estop_path_up(),
            down_because: link.down_because(),
        },
    }
}

/// Every site's controller: its link, rig and E-stop latch.
#[utoipa::path(get, path = "/api/controller", tag = "controller", responses((status = 200, body = ControllerStatus)))]
async fn controller_status(
    State(s): State<AppState>,
    _who: Experimenter,
) -> ApiResult<ControllerStatus> {
    let sites: Vec<SiteStatus> = s.sites.all().iter().map(site_status).collect();
    let first = &sites[0].link;
    let several = sites.len() > 1;
    let all = LinkState {
        connected: sites.iter().all(|x| x.link.connected),
        pid: first.pid,
        rig: first.rig.clone(),
        estop_latched: sites.iter().any(|x| x.link.estop_latched),
        estop_path: sites.iter().all(|x| x.link.estop_path),
        down_because: sites.iter().find_map(|x| {
            let why = x.link.down_because.as_ref()?;
            Some(match several {
                true => format!("site {:?}: {why}", x.site),
                false => why.clone(),
            })
        }),
    };
    Ok(AppJson(ControllerStatus { all, sites }))
}
