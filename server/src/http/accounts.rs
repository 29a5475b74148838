//! Account management, for admins only (the experimenter layer refuses everyone else on
//! `/api/accounts…`): create, list, change role, limit to sites, disable or enable. Accounts are never
//! deleted, so every audit row keeps naming a real person.

use axum::extract::State;
use serde::Deserialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppError, AppJson};
use super::extract::{AppPath, Experimenter};
use crate::engine::accounts::{self, SiteLimit};
use crate::state::AppState;
use crate::store::accounts::{Account, Role};

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_accounts, create_account))
        .routes(routes!(set_role))
        .routes(routes!(set_sites))
        .routes(routes!(disable))
        .routes(routes!(enable))
}

/// `role` as sent: checked here so the error lists the roles.
fn role_of(name: &str) -> Result<Role, AppError> {
    name.parse().map_err(AppError::BadRequest)
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewAccount {
    /// 3 to 40 letters, digits, '.', '_' or '-'.
    pub username: String,
    /// At least 10 characters (at most 200 bytes).
    pub password: String,
    /// `admin`, `experimenter` or `analyst`.
    pub role: String,
    /// The sites (of GET /api/controller) whose machines it may start, abort, reset and run
    /// the bench on; absent or null: every site's.
    #[serde(default)]
    pub sites: Option<Vec<String>>,
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SitesBody {
    /// At least one of the server's sites (GET /api/controller lists them); null: every
    /// site.
    pub sites: Option<Vec<String>>,
}

#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RoleBody {
    /// `admin`, `experimenter` or `analyst`.
    pub role: String,
}

/// Every account (active and disabled).
#[utoipa::path(get, path = "/api/accounts", tag = "accounts", responses((status = 200, body = Vec<Account>)))]
async fn list_accounts(State(s): State<AppState>) -> ApiResult<Vec<Account>> {
    Ok(AppJson(accounts::list(&s.pool).await?))
}

/// Create an account with a role, limited to some of the server's sites if `sites` names
/// them.
#[utoipa::path(post, path = "/api/accounts", tag = "accounts", request_body = NewAccount,
    responses((status = 200, body = Account), (status = 409, body = super::error::ErrorBody, description = "the username is taken")))]
async fn create_account(
    State(s): State<AppState>,
    who: Experimenter,
    AppJson(b): AppJson<NewAccount>,
) -> ApiResult<Account> {
    let role = role_of(&b.role)?;
    let served = s.sites.names();
    let limit = b.sites.as_deref().map(|sites| SiteLimit {
        sites,
        served: &served,
    });
    Ok(AppJson(
        accounts::create_account(
            &s.pool,
            &who.username,
            &b.username,
            &b.password,
            role,
            limit,
        )
        .await?,
    ))
}

/// Limit an account to some of the server's sites: it then starts, aborts and resets the
/// E-stop of, and runs the bench on, those sites' machines only (any account presses any
/// E-stop). Null: every site's. Applies to its sessions at once.
#[utoipa::path(post, path = "/api/accounts/{id}/sites", tag = "accounts", params(("id" = i64, Path)), request_body = SitesBody,
    responses((status = 200, body = Account), (status = 422, body = super::error::ErrorBody, description = "a site the server does not serve (the error lists its sites), or an empty list")))]
async fn set_sites(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<SitesBody>,
) -> ApiResult<Account> {
    let served = s.sites.names();
    let limit = b.sites.as_deref().map(|sites| SiteLimit {
        sites,
        served: &served,
    });
    Ok(AppJson(
        accounts::set_sites(&s.pool, &who.username, id, limit).await?,
    ))
}

/// Give an account another role. The last active admin cannot be demoted.
#[utoipa::path(post, path = "/api/accounts/{id}/role", tag = "accounts", params(("id" = i64, Path)), request_body = RoleBody,
    responses((status = 200, body = Account), (status = 409, body = super::error::ErrorBody, description = "it is the last active admin")))]
async fn set_role(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<RoleBody>,
) -> ApiResult<Account> {
    let role = role_of(&b.role)?;
    Ok(AppJson(
        accounts::set_role(&s.pool, &who.username, id, role).await?,
    ))
}

/// Disable an account: it cannot log in, and its sessions end at once. The last active
/// admin cannot be disabled.
#[utoipa::path(post, path = "/api/accounts/{id}/disable", tag = "accounts", params(("id" = i64, Path)),
    responses((status = 200, body = Account), (status = 409, body = super::error::ErrorBody, description = "it is the last active admin")))]
async fn disable(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<Account> {
    Ok(AppJson(
        accounts::set_disabled(&s.pool, &who.username, id, true).await?,
    ))
}

/// Enable a disabled account again.
#[utoipa::path(post, path = "/api/accounts/{id}/enable", tag = "accounts", params(("id" = i64, Path)),
    responses((status = 200, body = Account)))]
async fn enable(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<Account> {
    Ok(AppJson(
        accounts::set_disabled(&s.pool, &who.username, id, false).await?,
    ))
}
