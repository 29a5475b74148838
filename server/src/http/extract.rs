//! Who is asking. Experimenters by session cookie (HttpOnly, SameSite=Strict) with a CSRF
//! header on every state-changing request and the account's role, checked by
//! [`require_experimenter`], the layer on the whole experimenter router: a route added there
//! is protected by default, and a new state-changing route is refused to analysts by
//! default. Stations and subjects by unguessable bearer tokens scoped to one station or one
//! subject.

use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::extract::{FromRequestParts, MatchedPath, Path, Query, Request, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, Method, header};
use axum::middleware::Next;
use axum::response::Response;
use serde::Serialize;

use super::error::AppError;
use crate::engine::accounts::{self, Drive};
use crate::state::AppState;
use crate::store;
use crate::store::accounts::Role;
use crate::store::stations::Station;
use crate::store::subjects::Subject;

pub const SESSION_COOKIE: &str = "bdft_session";
pub const CSRF_HEADER: &str = "x-csrf-token";

/// The E-stop's route.
pub const ESTOP_PATH: &str = "/api/estop";

/// A logged-in experimenter (put in the request by [`require_experimenter`]).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Experimenter {
    pub id: i64,
    pub username: String,
    pub role: Role,
    pub csrf: String,
}

impl Experimenter {
    /// Refuses (403, naming the account's sites) when this account is limited to sites and
    /// `action` drives the machine of one of `sites` not among them. Handlers that start,
    /// abort or reset a machine or run the bench call it before acting; the E-stop never
    /// does (any account stops any machine).
    pub async fn may_drive(
        &self,
        pool: &sqlx::AnyPool,
        action: Drive,
        sites: &[&str],
    ) -> Result<(), AppError> {
        accounts::may_drive(pool, self.id, action, sites).await
    }
}

/// `Query` whose rejection is the documented JSON error: 422 naming the field that does not
/// parse. Every handler takes its query through this, never axum's own, whose rejection is
/// plain text (but the E-stop's, which stops every site when its query does not parse).
#[derive(Debug, FromRequestParts)]
#[from_request(via(Query), rejection(AppError))]
pub struct AppQuery<T>(pub T);

impl From<QueryRejection> for AppError {
    fn from(r: QueryRejection) -> Self {
        Self::BadRequest(format!("the query: {}", r.body_text()))
    }
}

/// `Path` whose rejection is the documented JSON error: an address whose parameter does not
/// parse (`/api/studies/abc`) is a 422 saying which; a route that does not match its
/// handler's parameters is a bug, 500. Every handler takes its path parameters through
/// this, never axum's own, whose rejection is plain text.
#[derive(Debug, FromRequestParts)]
#[from_request(via(Path), rejection(AppError))]
pub struct AppPath<T>(pub T);

impl From<PathRejection> for AppError {
    fn from(r: PathRejection) -> Self {
        match r.status() {
            s if s.is_client_error() => Self::BadRequest(format!("the address: {}", r.body_text())),
            _ => Self::Internal(anyhow::anyhow!("path parameters: {}", r.body_text())),
        }
    }
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

/// The routes only admins may call, by path prefix (as registered), with what the refusal
/// says they do: account management, backups (a backup holds every subject's data), and
/// erasing a subject's data with the list of erasures.
const ADMIN_ONLY: &[(&str, &str)] = &[
    ("/api/accounts", "manages accounts"),
    ("/api/backups", "manages backups"),
    ("/api/subjects/{id}/erase", "erases a subject's data"),
    ("/api/erasures", "erases a subject's data"),
];

/// The state-changing routes an analyst may call. The E-stop is among them on purpose: in a
/// lab anyone logged in who sees a person in danger must be able to stop the machine, the
/// read-only analyst too. Resetting it is not: that lets the machine move again. The power
/// planner is a POST for its body but changes nothing: planning is an analyst's work.
const ANALYST_MAY_CHANGE: &[&str] = &[
    "/api/estop",
    "/api/logout",
    "/api/studies/{id}/plan",
    "/api/studies/{id}/plan-job",
];

/// What `role` may do on the route `path` (as registered) with `method`: anything not
/// listed for it is refused, so a new route fails closed.
fn role_allows(role: Role, method: &Method, path: &str) -> Result<(), AppError> {
    let admin_only = ADMIN_ONLY.iter().find(|(prefix, _)| {
        path.strip_prefix(prefix)
            .is_some_and(|rest| rest.is_empty() || rest.starts_with('/'))
    });
    if let Some((_, what)) = admin_only
        && role != Role::Admin
    {
        return Err(AppError::Forbidden(format!(
            "your role is {}: only an admin {what}",
            role.name()
        )));
    }
    let reads = matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS);
    if role == Role::Analyst && !reads && !ANALYST_MAY_CHANGE.contains(&path) {
        return Err(AppError::Forbidden(
            "your role is analyst: it may read studies, subjects, results, exports and the audit log, plan a study's power, and press the E-stop, but change nothing".into(),
        ));
    }
    Ok(())
}

/// The layer of the experimenter router: a valid session of an active account, the CSRF
/// token on anything but a read, and the account's role allowing the route; the
/// experimenter goes into the request for the handler.
pub async fn require_experimenter(
    State(state): State<AppState>,
    mut req: Request,
    next: Next,
) -> Result<Response, AppError> {
    let token = cookie(req.headers(), SESSION_COOKIE).ok_or(AppError::Unauthorized)?;
    // The E-stop trusts a session the store confirmed recently: a busy store must not delay
    // it (`estop_sessions`); every other route asks the store.
    let remembered = (*req.method() == Method::POST && req.uri().path() == ESTOP_PATH)
        .then(|| state.estop_sessions.owner(&token))
        .flatten();
    let owner = match remembered {
        Some(owner) => owner,
        None => {
            let owner = store::accounts::session(&state.pool, &token)
                .await?
                .ok_or(AppError::Unauthorized)?;
            state.estop_sessions.confirmed(&token, &owner);
            owner
        }
    };
    if !matches!(*req.method(), Method::GET | Method::HEAD | Method::OPTIONS) {
        let sent = req
            .headers()
            .get(CSRF_HEADER)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("");
        if !same(sent, &owner.csrf) {
            return Err(AppError::Forbidden(
                "missing or wrong CSRF token (header X-CSRF-Token)".into(),
            ));
        }
    }
    // A route layer runs after routing, so the registered path is known; without one
    // (never, on this router) nothing is allowed but reads.
    let path = req
        .extensions()
        .get::<MatchedPath>()
        .map_or("", MatchedPath::as_str);
    role_allows(owner.role, req.method(), path)?;
    req.extensions_mut().insert(Experimenter {
        id: owner.id,
        username: owner.username,
        role: owner.role,
        csrf: owner.csrf,
    });
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_analyst_only_reads_and_stops() {
        let a = Role::Analyst;
        assert!(role_allows(a, &Method::GET, "/api/studies/{id}/export/{kind}").is_ok());
        assert!(role_allows(a, &Method::POST, "/api/estop").is_ok());
        assert!(role_allows(a, &Method::POST, "/api/estop/reset").is_err());
        assert!(role_allows(a, &Method::POST, "/api/some-new-route").is_err());
        assert!(role_allows(a, &Method::POST, "").is_err());
    }

    #[test]
    fn only_an_admin_manages_accounts_and_backups_and_erases() {
        for role in [Role::Experimenter, Role::Analyst] {
            assert!(role_allows(role, &Method::GET, "/api/accounts").is_err());
            assert!(role_allows(role, &Method::POST, "/api/accounts/{id}/role").is_err());
            let e = role_allows(role, &Method::GET, "/api/backups").unwrap_err();
            assert!(
                e.to_string().contains("only an admin manages backups"),
                "{e}"
            );
        }
        assert!(role_allows(Role::Experimenter, &Method::GET, "/api/backupsfoo").is_ok());
        assert!(role_allows(Role::Admin, &Method::POST, "/api/accounts/{id}/role").is_ok());
        for role in [Role::Experimenter, Role::Analyst] {
            let e = role_allows(role, &Method::POST, "/api/subjects/{id}/erase").unwrap_err();
            assert!(
                e.to_string()
                    .contains("only an admin erases a subject's data"),
                "{e}"
            );
            assert!(role_allows(role, &Method::GET, "/api/erasures").is_err());
        }
        assert!(role_allows(Role::Experimenter, &Method::GET, "/api/subjects/{id}").is_ok());
        assert!(role_allows(Role::Admin, &Method::POST, "/api/subjects/{id}/erase").is_ok());
        assert!(role_allows(Role::Admin, &Method::POST, "/api/backups").is_ok());
        assert!(role_allows(Role::Experimenter, &Method::POST, "/api/studies").is_ok());
    }
}
