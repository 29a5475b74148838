//! Who is asking: experimenters by session cookie (argon2 passwords, HttpOnly SameSite=Strict
//! cookie, CSRF token on every state-changing request, rate-limited login), stations and
//! subjects by unguessable bearer tokens scoped to one station or one subject. Only hashes of
//! tokens are stored.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use argon2::Argon2;
use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString};
use axum::extract::{ConnectInfo, FromRequestParts, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, HeaderValue, Method, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use sqlx::SqlitePool;

use crate::db::{now_ms, random_token, token_hash};
use crate::error::{AppError, AppJson};
use crate::state::AppState;

pub const SESSION_COOKIE: &str = "bdft_session";
pub const CSRF_HEADER: &str = "x-csrf-token";
const SESSION_HOURS: i64 = 12;
const MIN_PASSWORD: usize = 10;
/// Failed logins allowed per user and address per minute.
const LOGIN_ATTEMPTS: usize = 5;

/// A logged-in experimenter.
#[derive(Debug, Clone, Serialize)]
pub struct Experimenter {
    pub id: i64,
    pub username: String,
    pub csrf: String,
}

fn cookie(headers: &HeaderMap, name: &str) -> Option<String> {
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

impl FromRequestParts<AppState> for Experimenter {
    type Rejection = AppError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        let token = cookie(&parts.headers, SESSION_COOKIE).ok_or(AppError::Unauthorized)?;
        let row: Option<(i64, String, String)> = sqlx::query_as(
            "SELECT e.id, e.username, s.csrf FROM sessions s JOIN experimenters e ON e.id = s.experimenter_id WHERE s.token_hash = ? AND s.expires_at > ?",
        )
        .bind(token_hash(&token))
        .bind(now_ms())
        .fetch_optional(&state.pool)
        .await?;
        let (id, username, csrf) = row.ok_or(AppError::Unauthorized)?;
        if !matches!(parts.method, Method::GET | Method::HEAD | Method::OPTIONS) {
            let sent = parts
                .headers
                .get(CSRF_HEADER)
                .and_then(|v| v.to_str().ok())
                .unwrap_or("");
            if !same(sent, &csrf) {
                return Err(AppError::Forbidden(
                    "missing or wrong CSRF token (header X-CSRF-Token)".into(),
                ));
            }
        }
        Ok(Self { id, username, csrf })
    }
}

/// A paired operator station.
#[derive(Debug, Clone, Serialize, sqlx::FromRow)]
pub struct StationAuth {
    pub id: i64,
    pub study_id: i64,
    pub name: String,
    pub role: String,
    pub subject_id: Option<i64>,
}

pub async fn station_by_token(
    pool: &SqlitePool,
    token: &str,
) -> Result<Option<StationAuth>, AppError> {
    Ok(sqlx::query_as(
        "SELECT id, study_id, name, role, subject_id FROM stations WHERE token_hash = ?",
    )
    .bind(token_hash(token))
    .fetch_optional(pool)
    .await?)
}

impl FromRequestParts<AppState> for StationAuth {
    type Rejection = AppError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        let token = bearer(parts).ok_or(AppError::Unauthorized)?;
        station_by_token(&state.pool, &token)
            .await?
            .ok_or(AppError::Unauthorized)
    }
}

/// A subject, by the token of their own page.
#[derive(Debug, Clone, Serialize, sqlx::FromRow)]
pub struct SubjectAuth {
    pub id: i64,
    pub study_id: i64,
    pub code: String,
}

impl FromRequestParts<AppState> for SubjectAuth {
    type Rejection = AppError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        let token = bearer(parts).ok_or(AppError::Unauthorized)?;
        sqlx::query_as("SELECT id, study_id, code FROM subjects WHERE token_hash = ?")
            .bind(token_hash(&token))
            .fetch_optional(&state.pool)
            .await?
            .ok_or(AppError::Unauthorized)
    }
}

pub fn hash_password(password: &str) -> anyhow::Result<String> {
    let mut salt = [0u8; 16];
    getrandom::fill(&mut salt).map_err(|e| anyhow::anyhow!("random salt: {e}"))?;
    let salt = SaltString::encode_b64(&salt).map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(Argon2::default()
        .hash_password(password.as_bytes(), &salt)
        .map_err(|e| anyhow::anyhow!("{e}"))?
        .to_string())
}

/// A real hash of a random password, so that unknown usernames cost the same verification.
fn dummy_hash() -> String {
    static DUMMY: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    DUMMY
        .get_or_init(|| hash_password(&random_token()).unwrap_or_default())
        .clone()
}

fn verify_password(password: &str, phc: &str) -> bool {
    PasswordHash::new(phc).is_ok_and(|h| {
        Argon2::default()
            .verify_password(password.as_bytes(), &h)
            .is_ok()
    })
}

fn check_new_credentials(username: &str, password: &str) -> Result<(), AppError> {
    let ok_name = (3..=40).contains(&username.len())
        && username
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c));
    if !ok_name {
        return Err(AppError::BadRequest(
            "username: 3 to 40 letters, digits, '.', '_' or '-'".into(),
        ));
    }
    if password.chars().count() < MIN_PASSWORD || password.len() > 200 {
        return Err(AppError::BadRequest(format!(
            "password: at least {MIN_PASSWORD} characters (at most 200 bytes)"
        )));
    }
    Ok(())
}

pub async fn create_experimenter(
    pool: &SqlitePool,
    username: &str,
    password: &str,
) -> Result<i64, AppError> {
    check_new_credentials(username, password)?;
    let pw = password.to_string();
    let hash = tokio::task::spawn_blocking(move || hash_password(&pw))
        .await
        .map_err(anyhow::Error::from)??;
    let r = sqlx::query(
        "INSERT INTO experimenters (username, password_hash, created_at) VALUES (?, ?, ?)",
    )
    .bind(username)
    .bind(hash)
    .bind(now_ms())
    .execute(pool)
    .await;
    match r {
        Ok(r) => Ok(r.last_insert_rowid()),
        Err(sqlx::Error::Database(e)) if e.is_unique_violation() => Err(AppError::Conflict(
            format!("the username {username} is taken"),
        )),
        Err(e) => Err(e.into()),
    }
}

pub async fn experimenter_count(pool: &SqlitePool) -> Result<i64, AppError> {
    let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM experimenters")
        .fetch_one(pool)
        .await?;
    Ok(n)
}

/// A one-time set-up token (printed at first start); only its hash is stored.
pub async fn new_setup_token(pool: &SqlitePool) -> Result<String, AppError> {
    let token = random_token();
    sqlx::query("INSERT INTO setup_tokens (token_hash, created_at) VALUES (?, ?)")
        .bind(token_hash(&token))
        .bind(now_ms())
        .execute(pool)
        .await?;
    Ok(token)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Credentials {
    pub username: String,
    pub password: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SetupRequest {
    pub token: String,
    pub username: String,
    pub password: String,
}

fn session_cookie(token: &str, max_age_s: i64) -> HeaderValue {
    HeaderValue::from_str(&format!(
        "{SESSION_COOKIE}={token}; HttpOnly; SameSite=Strict; Path=/; Max-Age={max_age_s}"
    ))
    .expect("ascii cookie")
}

async fn new_session(
    pool: &SqlitePool,
    experimenter_id: i64,
    username: &str,
) -> Result<Response, AppError> {
    let (token, csrf) = (random_token(), random_token());
    let now = now_ms();
    sqlx::query("INSERT INTO sessions (token_hash, experimenter_id, csrf, created_at, expires_at) VALUES (?, ?, ?, ?, ?)")
        .bind(token_hash(&token))
        .bind(experimenter_id)
        .bind(&csrf)
        .bind(now)
        .bind(now + SESSION_HOURS * 3_600_000)
        .execute(pool)
        .await?;
    let body = AppJson(serde_json::json!({ "username": username, "csrf": csrf }));
    Ok((
        [(
            header::SET_COOKIE,
            session_cookie(&token, SESSION_HOURS * 3600),
        )],
        body,
    )
        .into_response())
}

/// POST /api/login
pub async fn login(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    AppJson(c): AppJson<Credentials>,
) -> Result<Response, AppError> {
    let key = format!("{}|{}", c.username, peer.ip());
    {
        let mut failures = state
            .inner
            .login_failures
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        let recent = failures.entry(key.clone()).or_default();
        recent.retain(|t| t.elapsed() < Duration::from_secs(60));
        if recent.len() >= LOGIN_ATTEMPTS {
            return Err(AppError::TooManyRequests);
        }
    }
    let row: Option<(i64, String)> =
        sqlx::query_as("SELECT id, password_hash FROM experimenters WHERE username = ?")
            .bind(&c.username)
            .fetch_optional(&state.pool)
            .await?;
    let pw = c.password.clone();
    // Verify against a dummy hash for unknown users too, so timing does not reveal names.
    let phc = row.as_ref().map(|r| r.1.clone());
    let ok =
        tokio::task::spawn_blocking(move || verify_password(&pw, &phc.unwrap_or_else(dummy_hash)))
            .await
            .map_err(anyhow::Error::from)?;
    match (row, ok) {
        (Some((id, _)), true) => {
            state
                .inner
                .login_failures
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .remove(&key);
            crate::store::audit(
                &state.pool,
                &c.username,
                "login",
                None,
                serde_json::json!({ "from": peer.ip().to_string() }),
            )
            .await?;
            new_session(&state.pool, id, &c.username).await
        }
        _ => {
            state
                .inner
                .login_failures
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .entry(key)
                .or_default()
                .push(Instant::now());
            Err(AppError::Forbidden("wrong username or password".into()))
        }
    }
}

/// POST /api/logout
pub async fn logout(
    State(state): State<AppState>,
    who: Experimenter,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    if let Some(token) = cookie(&headers, SESSION_COOKIE) {
        sqlx::query("DELETE FROM sessions WHERE token_hash = ?")
            .bind(token_hash(&token))
            .execute(&state.pool)
            .await?;
    }
    crate::store::audit(
        &state.pool,
        &who.username,
        "logout",
        None,
        serde_json::json!({}),
    )
    .await?;
    Ok((
        [(header::SET_COOKIE, session_cookie("", 0))],
        AppJson(serde_json::json!({ "ok": true })),
    )
        .into_response())
}

/// POST /api/setup: creates the first experimenter with the one-time token.
pub async fn setup(
    State(state): State<AppState>,
    AppJson(req): AppJson<SetupRequest>,
) -> Result<Response, AppError> {
    if experimenter_count(&state.pool).await? > 0 {
        return Err(AppError::Conflict(
            "set-up is done: an experimenter account exists".into(),
        ));
    }
    check_new_credentials(&req.username, &req.password)?;
    let used =
        sqlx::query("UPDATE setup_tokens SET used_at = ? WHERE token_hash = ? AND used_at IS NULL")
            .bind(now_ms())
            .bind(token_hash(&req.token))
            .execute(&state.pool)
            .await?;
    if used.rows_affected() == 0 {
        return Err(AppError::Forbidden(
            "the set-up link is not valid (already used, or mistyped)".into(),
        ));
    }
    let id = create_experimenter(&state.pool, &req.username, &req.password).await?;
    crate::store::audit(
        &state.pool,
        &req.username,
        "setup.first_account",
        None,
        serde_json::json!({}),
    )
    .await?;
    new_session(&state.pool, id, &req.username).await
}

/// GET /api/setup: whether the first account still has to be made.
pub async fn setup_status(
    State(state): State<AppState>,
) -> Result<AppJson<serde_json::Value>, AppError> {
    Ok(AppJson(
        serde_json::json!({ "needs_setup": experimenter_count(&state.pool).await? == 0 }),
    ))
}

/// GET /api/me
pub async fn me(who: Experimenter) -> AppJson<Experimenter> {
    AppJson(who)
}
