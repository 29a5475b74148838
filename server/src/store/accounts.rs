//! Experimenter accounts (argon2id hashes, a role, the sites they are limited to, disabled
//! rather than deleted), their sessions, and the one-time set-up tokens.

use serde::{Deserialize, Serialize};
use sqlx::{AnyConnection, AnyExecutor};

use super::db::{now_ms, rfc3339};
use super::tokens::token_hash;
use crate::error::{AppError, Result};

/// What an account may do. The server enforces it (`http::extract`); the dashboard only
/// hides what a role may not do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Everything an experimenter does, and managing accounts.
    Admin,
    /// Runs studies: every route but account management.
    Experimenter,
    /// Reads only (studies, subjects, results, exports, the audit log) and may press the
    /// E-stop.
    Analyst,
}

impl Role {
    pub const ALL: [Role; 3] = [Role::Admin, Role::Experimenter, Role::Analyst];

    pub fn name(self) -> &'static str {
        match self {
            Role::Admin => "admin",
            Role::Experimenter => "experimenter",
            Role::Analyst => "analyst",
        }
    }
}

impl std::str::FromStr for Role {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Role::ALL
            .into_iter()
            .find(|r| r.name() == s)
            .ok_or_else(|| format!("role: one of admin, experimenter, analyst (not {s:?})"))
    }
}

fn stored_role(id: i64, role: &str) -> Result<Role> {
    role.parse()
        .map_err(|e| AppError::Internal(anyhow::anyhow!("stored account {id}: {e}")))
}

/// The account a valid session cookie belongs to (never a disabled one).
#[derive(Debug, Clone)]
pub struct SessionOwner {
    pub id: i64,
    pub username: String,
    pub role: Role,
    pub csrf: String,
}

pub async fn session<'c>(db: impl AnyExecutor<'c>, token: &str) -> Result<Option<SessionOwner>> {
    let row: Option<(i64, String, String, String)> = sqlx::query_as(
        "SELECT e.id, e.username, e.role, s.csrf FROM sessions s JOIN experimenters e ON e.id = s.experimenter_id WHERE s.token_hash = $1 AND s.expires_at > $2 AND e.disabled_at IS NULL",
    )
    .bind(token_hash(token))
    .bind(now_ms())
    .fetch_optional(db)
    .await?;
    row.map(|(id, username, role, csrf)| {
        Ok(SessionOwner {
            role: stored_role(id, &role)?,
            id,
            username,
            csrf,
        })
    })
    .transpose()
}

pub async fn insert_session(
    db: &mut AnyConnection,
    token: &str,
    experimenter_id: i64,
    csrf: &str,
    lifetime_ms: i64,
) -> Result<()> {
    let now = now_ms();
    sqlx::query("INSERT INTO sessions (token_hash, experimenter_id, csrf, created_at, expires_at) VALUES ($1, $2, $3, $4, $5)")
        .bind(token_hash(token))
        .bind(experimenter_id)
        .bind(csrf)
        .bind(now)
        .bind(now + lifetime_ms)
        .execute(db)
        .await?;
    Ok(())
}

pub async fn delete_session(db: &mut AnyConnection, token: &str) -> Result<()> {
    sqlx::query("DELETE FROM sessions WHERE token_hash = $1")
        .bind(token_hash(token))
        .execute(db)
        .await?;
    Ok(())
}

/// What a login checks: the account's id, password hash, role and whether it is disabled.
#[derive(Debug)]
pub struct Credentials {
    pub id: i64,
    pub password_hash: String,
    pub role: Role,
    pub disabled: bool,
}

pub async fn credentials<'c>(
    db: impl AnyExecutor<'c>,
    username: &str,
) -> Result<Option<Credentials>> {
    let row: Option<(i64, String, String, super::db::Flag)> = sqlx::query_as(
        "SELECT id, password_hash, role, disabled_at IS NOT NULL FROM experimenters WHERE username = $1",
    )
    .bind(username)
    .fetch_optional(db)
    .await?;
    row.map(|(id, password_hash, role, disabled)| {
        Ok(Credentials {
            role: stored_role(id, &role)?,
            id,
            password_hash,
            disabled: disabled.0,
        })
    })
    .transpose()
}

pub async fn insert_experimenter(
    db: &mut AnyConnection,
    username: &str,
    password_hash: &str,
    role: Role,
) -> Result<i64> {
    let r = sqlx::query_scalar::<_, i64>(
        "INSERT INTO experimenters (username, password_hash, role, created_at) VALUES ($1, $2, $3, $4) RETURNING id",
    )
    .bind(username)
    .bind(password_hash)
    .bind(role.name())
    .bind(now_ms())
    .fetch_one(db)
    .await;
    match r {
        Ok(r) => Ok(r),
        Err(sqlx::Error::Database(e)) if e.is_unique_violation() => Err(AppError::Conflict(
            format!("the username {username} is taken"),
        )),
        Err(e) => Err(e.into()),
    }
}

pub async fn experimenter_count<'c>(db: impl AnyExecutor<'c>) -> Result<i64> {
    let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM experimenters")
        .fetch_one(db)
        .await?;
    Ok(n)
}

/// An account as the admin's list shows it (no hash).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Account {
    pub id: i64,
    pub username: String,
    pub role: Role,
    /// The sites whose machines it may start, abort and reset and run the bench on, by
    /// name (sorted); absent: every site's. Any account presses any E-stop.
    pub sites: Option<Vec<String>>,
    /// RFC 3339 UTC; absent while the account is active.
    pub disabled_at: Option<String>,
    /// RFC 3339 UTC.
    pub created_at: String,
}

/// id, username, role, disabled_at, created_at
type AccountRow = (i64, String, String, Option<i64>, i64);

fn account_of(
    (id, username, role, disabled_at, created_at): AccountRow,
    sites: Option<Vec<String>>,
) -> Result<Account> {
    Ok(Account {
        role: stored_role(id, &role)?,
        id,
        username,
        sites,
        disabled_at: disabled_at.map(rfc3339),
        created_at: rfc3339(created_at),
    })
}

const ACCOUNT_COLUMNS: &str = "id, username, role, disabled_at, created_at";

pub async fn accounts(db: &mut AnyConnection) -> Result<Vec<Account>> {
    let rows: Vec<AccountRow> = sqlx::query_as(&format!(
        "SELECT {ACCOUNT_COLUMNS} FROM experimenters ORDER BY id"
    ))
    .fetch_all(&mut *db)
    .await?;
    let limits: Vec<(i64, String)> = sqlx::query_as(
        "SELECT experimenter_id, site FROM experimenter_sites ORDER BY experimenter_id, site",
    )
    .fetch_all(db)
    .await?;
    rows.into_iter()
        .map(|row| {
            let sites: Vec<String> = limits
                .iter()
                .filter(|(id, _)| *id == row.0)
                .map(|(_, site)| site.clone())
                .collect();
            account_of(row, (!sites.is_empty()).then_some(sites))
        })
        .collect()
}

pub async fn account(db: &mut AnyConnection, id: i64) -> Result<Account> {
    let row: Option<AccountRow> = sqlx::query_as(&format!(
        "SELECT {ACCOUNT_COLUMNS} FROM experimenters WHERE id = $1"
    ))
    .bind(id)
    .fetch_optional(&mut *db)
    .await?;
    let row = row.ok_or(AppError::NotFound("account"))?;
    account_of(row, sites(db, id).await?)
}

/// The sites account `id` is limited to, sorted by name; `None`: it is not limited (every
/// site).
pub async fn sites<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<Option<Vec<String>>> {
    let sites: Vec<String> = sqlx::query_scalar(
        "SELECT site FROM experimenter_sites WHERE experimenter_id = $1 ORDER BY site",
    )
    .bind(id)
    .fetch_all(db)
    .await?;
    Ok((!sites.is_empty()).then_some(sites))
}

/// Limits account `id` to `sites` (none, or an empty list: every site), replacing what it
/// was limited to.
pub async fn set_sites(db: &mut AnyConnection, id: i64, sites: Option<&[String]>) -> Result<()> {
    sqlx::query("DELETE FROM experimenter_sites WHERE experimenter_id = $1")
        .bind(id)
        .execute(&mut *db)
        .await?;
    for site in sites.unwrap_or_default() {
        sqlx::query("INSERT INTO experimenter_sites (experimenter_id, site) VALUES ($1, $2)")
            .bind(id)
            .bind(site)
            .execute(&mut *db)
            .await?;
    }
    Ok(())
}

/// Active admins other than `id` (the last-admin rule counts them inside its change).
pub async fn other_active_admins<'c>(db: impl AnyExecutor<'c>, id: i64) -> Result<i64> {
    let (n,): (i64,) = sqlx::query_as(
        "SELECT COUNT(*) FROM experimenters WHERE role = 'admin' AND disabled_at IS NULL AND id <> $1",
    )
    .bind(id)
    .fetch_one(db)
    .await?;
    Ok(n)
}

pub async fn set_role(db: &mut AnyConnection, id: i64, role: Role) -> Result<()> {
    sqlx::query("UPDATE experimenters SET role = $1 WHERE id = $2")
        .bind(role.name())
        .bind(id)
        .execute(db)
        .await?;
    Ok(())
}

/// Disables an account and ends its sessions; returns how many sessions ended.
pub async fn disable(db: &mut AnyConnection, id: i64) -> Result<u64> {
    sqlx::query("UPDATE experimenters SET disabled_at = $1 WHERE id = $2 AND disabled_at IS NULL")
        .bind(now_ms())
        .bind(id)
        .execute(&mut *db)
        .await?;
    Ok(
        sqlx::query("DELETE FROM sessions WHERE experimenter_id = $1")
            .bind(id)
            .execute(db)
            .await?
            .rows_affected(),
    )
}

pub async fn enable(db: &mut AnyConnection, id: i64) -> Result<()> {
    sqlx::query("UPDATE experimenters SET disabled_at = NULL WHERE id = $1")
        .bind(id)
        .execute(db)
        .await?;
    Ok(())
}

/// Stores a new set-up token and deletes every unused earlier one (at most one set-up link
/// is valid); returns how many were deleted.
pub async fn replace_setup_token(db: &mut AnyConnection, token: &str) -> Result<u64> {
    let replaced = sqlx::query("DELETE FROM setup_tokens WHERE used_at IS NULL")
        .execute(&mut *db)
        .await?
        .rows_affected();
    sqlx::query("INSERT INTO setup_tokens (token_hash, created_at) VALUES ($1, $2)")
        .bind(token_hash(token))
        .bind(now_ms())
        .execute(db)
        .await?;
    Ok(replaced)
}

/// A stored set-up token: when it was made and used.
#[derive(Debug, sqlx::FromRow)]
pub struct SetupToken {
    pub created_at: i64,
    pub used_at: Option<i64>,
}

pub async fn setup_token<'c>(db: impl AnyExecutor<'c>, token: &str) -> Result<Option<SetupToken>> {
    Ok(
        sqlx::query_as("SELECT created_at, used_at FROM setup_tokens WHERE token_hash = $1")
            .bind(token_hash(token))
            .fetch_optional(db)
            .await?,
    )
}

/// Marks a set-up token used (the caller checked it is unused, inside its transaction).
pub async fn use_setup_token(db: &mut AnyConnection, token: &str) -> Result<()> {
    sqlx::query("UPDATE setup_tokens SET used_at = $1 WHERE token_hash = $2 AND used_at IS NULL")
        .bind(now_ms())
        .bind(token_hash(token))
        .execute(db)
        .await?;
    Ok(())
}
