//! Who is asking. Experimenters by session cookie (HttpOnly, SameSite=Strict) with a CSRF
//! header on every state-changing request, checked by [`require_experimenter`], the layer
//! on the whole experimenter router: a route added there is protected by default. Stations
//! and subjects by unguessable bearer tokens scoped to one station or one subject.

use axum::extract::{FromRequestParts, Request, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, Method, header};
use axum::middleware::Next;
use axum::response::Response;
use serde::Serialize;

use super::error::AppError;
use crate::state::AppState;
use crate::store;
use crate::store::stations::Station;
use crate::store::subjects::Subject;

pub const SESSION_COOKIE: &str = "bdft_session";
pub const CSRF_HEADER: &str = "x-csrf-token";

/// A logged-in experimenter (put in the request by [`require_experimenter`]).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Experimenter {
    pub id: i64,
    pub username: String,
    pub csrf: String,
}

pub fn cookie(headers: &HeaderMap, name: &str) -> Option<String> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .find_map(|kv| {
            let (k, v) = kv.trim().split_once('=')?;
            (k == name).then(|| v.to_string())
        })
}

fn bearer(parts: &Parts) -> Option<String> {
    let h = parts.headers.get(header::AUTHORIZATION)?.to_str().ok()?;
    h.strip_prefix("Bearer ").map(|t| t.trim().to_string())
}

/// Constant-time comparison of two secrets.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len()
        && a.bytes()
            .zip(b.bytes())
            .fold(0u8, |acc, (x, y)| acc | (x ^ y))
            == 0
}

/// The layer of the experimenter router: a valid session, and the CSRF token on anything
/// but a read; the experimenter goes into the request for the handler.
pub async fn require_experimenter(
    State(state): State<AppState>,
    mut req: Request,
    next: Next,
) -> Result<Response, AppError> {
    let token = cookie(req.headers(), SESSION_COOKIE).ok_or(AppError::Unauthorized)?;
    let (id, username, csrf) = store::accounts::session(&state.pool, &token)
        .await?
        .ok_or(AppError::Unauthorized)?;
    if !matches!(*req.method(), Method::GET | Method::HEAD | Method::OPTIONS) {
        let sent = req
            .headers()
            .get(CSRF_HEADER)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("");
        if !same(sent, &csrf) {
            return Err(AppError::Forbidden(
                "missing or wrong CSRF token (header X-CSRF-Token)".into(),
            ));
        }
    }
    req.extensions_mut()
        .insert(Experimenter { id, username, csrf });
    Ok(next.run(req).await)
}

impl<S: Send + Sync> FromRequestParts<S> for Experimenter {
    type Rejection = AppError;
    /// Only [`require_experimenter`] puts one here: a handler on another router fails
    /// closed.
    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, AppError> {
        parts
            .extensions
            .get::<Experimenter>()
            .cloned()
            .ok_or(AppError::Unauthorized)
    }
}

/// A paired station, by its bearer token.
#[derive(Debug, Clone)]
pub struct StationAuth(pub Station);

impl FromRequestParts<AppState> for StationAuth {
    type Rejection = AppError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        let token = bearer(parts).ok_or(AppError::Unauthorized)?;
        store::stations::by_token(&state.pool, &token)
            .await?
            .map(Self)
            .ok_or(AppError::Unauthorized)
    }
}

/// A subject, by the token of their own page.
#[derive(Debug, Clone)]
pub struct SubjectAuth(pub Subject);

impl FromRequestParts<AppState> for SubjectAuth {
    type Rejection = AppError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        let token = bearer(parts).ok_or(AppError::Unauthorized)?;
        store::subjects::by_token(&state.pool, &token)
            .await?
            .map(Self)
            .ok_or(AppError::Unauthorized)
    }
}
