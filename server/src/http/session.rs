//! Logging in and out, and the first account: the session cookie is set here.

use std::net::SocketAddr;

use axum::extract::{ConnectInfo, State};
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppError, AppJson, Done};
use super::extract::{Experimenter, SESSION_COOKIE, cookie};
use crate::engine::accounts::{self, NewSession, SESSION_HOURS};
use crate::state::AppState;
use crate::store;
use crate::store::accounts::Role;

/// Routes anyone may call.
pub fn public() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(setup_status, setup))
        .routes(routes!(login))
}

/// Routes of a logged-in experimenter.
pub fn experimenter() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(me))
        .routes(routes!(logout))
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Credentials {
    pub username: String,
    pub password: String,
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SetupRequest {
    /// The token of the one-time set-up link printed at the first start.
    pub token: String,
    pub username: String,
    pub password: String,
}

/// A new session: the cookie is set, the CSRF token is for the `X-CSRF-Token` header.
#[derive(Debug, Serialize, ToSchema)]
pub struct SessionStarted {
    pub username: String,
    pub csrf: String,
    /// What the account may do (the dashboard hides the rest; the server refuses it).
    pub role: Role,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct SetupStatus {
    /// Whether the first experimenter account must still be created.
    pub needs_setup: bool,
}

/// The session cookie; `Secure` when the server speaks HTTPS, so a browser never sends it
/// over plain HTTP.
fn session_cookie(token: &str, max_age_s: i64, https: bool) -> HeaderValue {
    let secure = if https { "; Secure" } else { "" };
    HeaderValue::from_str(&format!(
        "{SESSION_COOKIE}={token}; HttpOnly; SameSite=Strict; Path=/; Max-Age={max_age_s}{secure}"
    ))
    .expect("tokens are hex")
}

fn started(username: &str, session: NewSession, https: bool) -> Response {
    (
        [(
            header::SET_COOKIE,
            session_cookie(&session.token, SESSION_HOURS * 3600, https),
        )],
        AppJson(SessionStarted {
            username: username.to_string(),
            csrf: session.csrf,
            role: session.role,
        }),
    )
        .into_response()
}

/// Log in: sets an HttpOnly session cookie and returns the CSRF token. Failed attempts are
/// limited per username and client address and per address (a minute's window); each is
/// in the audit log. A disabled account cannot log in.
#[utoipa::path(post, path = "/api/login", tag = "session", request_body = Credentials,
    responses((status = 200, body = SessionStarted), (status = 403, body = super::error::ErrorBody, description = "wrong username or password"),
        (status = 429, body = super::error::ErrorBody, description = "too many failed attempts: wait a minute")))]
async fn login(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    AppJson(c): AppJson<Credentials>,
) -> Result<Response, AppError> {
    let session = accounts::login(
        &state.pool,
        &state.login,
        &c.username,
        &c.password,
        peer.ip(),
    )
    .await?;
    Ok(started(&c.username, session, state.https))
}

/// Log out: ends the session.
#[utoipa::path(post, path = "/api/logout", tag = "session", responses((status = 200, body = Done)))]
async fn logout(
    State(state): State<AppState>,
    who: Experimenter,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let token = cookie(&headers, SESSION_COOKIE);
    if let Some(t) = &token {
        state.estop_sessions.ended(t);
    }
    accounts::end_session(&state.pool, &who.username, token.as_deref()).await?;
    Ok((
        [(header::SET_COOKIE, session_cookie("", 0, state.https))],
        Done::ok(),
    )
        .into_response())
}

/// Create the first experimenter with the one-time set-up token (valid for an hour; only
/// the link printed at the server's last start works, and only once).
#[utoipa::path(post, path = "/api/setup", tag = "session", request_body = SetupRequest,
    responses((status = 200, body = SessionStarted), (status = 403, body = super::error::ErrorBody, description = "the set-up link is mistyped, replaced by a newer one, or expired"),
        (status = 409, body = super::error::ErrorBody, description = "set-up is done: an account exists (or the link was used)")))]
async fn setup(
    State(state): State<AppState>,
    AppJson(req): AppJson<SetupRequest>,
) -> Result<Response, AppError> {
    let id = accounts::first_account(&state.pool, &req.token, &req.username, &req.password).await?;
    let session = accounts::new_session(
        &state.pool,
        id,
        &req.username,
        Role::Admin,
        accounts::Login::Setup,
    )
    .await?;
    Ok(started(&req.username, session, state.https))
}

/// Whether the first experimenter account must still be created.
#[utoipa::path(get, path = "/api/setup", tag = "session", responses((status = 200, body = SetupStatus)))]
async fn setup_status(State(state): State<AppState>) -> ApiResult<SetupStatus> {
    Ok(AppJson(SetupStatus {
        needs_setup: store::accounts::experimenter_count(&state.pool).await? == 0,
    }))
}

/// The logged-in experimenter as `GET /api/me` shows them.
#[derive(Debug, Serialize, ToSchema)]
pub struct Me {
    #[serde(flatten)]
    pub who: Experimenter,
    /// The sites whose machines the account may start, abort, reset and run the bench on;
    /// absent: every site's.
    pub sites: Option<Vec<String>>,
}

/// The logged-in experimenter, their role, the sites they are limited to and the CSRF token.
#[utoipa::path(get, path = "/api/me", tag = "session", responses((status = 200, body = Me)))]
async fn me(State(state): State<AppState>, who: Experimenter) -> ApiResult<Me> {
    let sites = store::accounts::sites(&state.pool, who.id).await?;
    Ok(AppJson(Me { who, sites }))
}
