//! Experimenter accounts: credentials rules, argon2id hashing, rate-limited login, the
//! one-time set-up token and sessions. No HTTP here: `http::session` carries cookies.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use argon2::Argon2;
use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString};
use serde_json::json;
use sqlx::SqlitePool;

use crate::error::{AppError, Result};
use crate::store::tokens::random_token;
use crate::store::{self, Change};

const MIN_PASSWORD: usize = 10;
/// Failed logins allowed per user and address per minute.
const LOGIN_ATTEMPTS: usize = 5;
/// How long a session lasts.
pub const SESSION_HOURS: i64 = 12;

fn hash_password(password: &str) -> anyhow::Result<String> {
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

fn check_new_credentials(username: &str, password: &str) -> Result<()> {
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

async fn hashed(password: &str) -> Result<String> {
    let pw = password.to_string();
    Ok(tokio::task::spawn_blocking(move || hash_password(&pw))
        .await
        .map_err(anyhow::Error::from)??)
}

/// Creates an experimenter account on behalf of `actor`; returns its id.
pub async fn create_experimenter(
    pool: &SqlitePool,
    actor: &str,
    username: &str,
    password: &str,
) -> Result<i64> {
    check_new_credentials(username, password)?;
    let hash = hashed(password).await?;
    let mut change = Change::begin(pool, actor).await?;
    let id = store::accounts::insert_experimenter(change.db(), username, &hash).await?;
    change
        .commit(
            "experimenter.create",
            Some(format!("experimenter:{id}")),
            json!({ "username": username }),
        )
        .await?;
    Ok(id)
}

/// A one-time set-up token (printed at first start); only its hash is stored.
pub async fn new_setup_token(pool: &SqlitePool) -> Result<String> {
    let token = random_token();
    let mut change = Change::begin(pool, "system").await?;
    store::accounts::insert_setup_token(change.db(), &token).await?;
    change.commit("setup.link", None, json!({})).await?;
    Ok(token)
}

/// Creates the first experimenter with the one-time set-up token: the token is used and the
/// account made in one transaction.
pub async fn first_account(
    pool: &SqlitePool,
    token: &str,
    username: &str,
    password: &str,
) -> Result<i64> {
    let taken = || AppError::Conflict("set-up is done: an experimenter account exists".into());
    if store::accounts::experimenter_count(pool).await? > 0 {
        return Err(taken());
    }
    check_new_credentials(username, password)?;
    let hash = hashed(password).await?;
    let mut change = Change::begin(pool, username).await?;
    if store::accounts::experimenter_count(change.db()).await? > 0 {
        return Err(taken());
    }
    if !store::accounts::use_setup_token(change.db(), token).await? {
        return Err(AppError::Forbidden(
            "the set-up link is not valid (already used, or mistyped)".into(),
        ));
    }
    let id = store::accounts::insert_experimenter(change.db(), username, &hash).await?;
    change
        .commit(
            "setup.first_account",
            Some(format!("experimenter:{id}")),
            json!({ "username": username }),
        )
        .await?;
    Ok(id)
}

/// A new session: (cookie token, CSRF token).
pub async fn new_session(
    pool: &SqlitePool,
    experimenter_id: i64,
    username: &str,
    action: &str,
    detail: serde_json::Value,
) -> Result<(String, String)> {
    let (token, csrf) = (random_token(), random_token());
    let mut change = Change::begin(pool, username).await?;
    store::accounts::insert_session(
        change.db(),
        &token,
        experimenter_id,
        &csrf,
        SESSION_HOURS * 3_600_000,
    )
    .await?;
    change.commit(action, None, detail).await?;
    Ok((token, csrf))
}

pub async fn end_session(pool: &SqlitePool, username: &str, token: Option<&str>) -> Result<()> {
    let mut change = Change::begin(pool, username).await?;
    if let Some(token) = token {
        store::accounts::delete_session(change.db(), token).await?;
    }
    change.commit("logout", None, json!({})).await
}

/// Failed logins per (username, client address), for rate limiting.
#[derive(Debug, Default)]
pub struct LoginLimiter {
    failures: Mutex<HashMap<String, Vec<Instant>>>,
}

impl LoginLimiter {
    fn failures(&self) -> std::sync::MutexGuard<'_, HashMap<String, Vec<Instant>>> {
        self.failures.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Checks a password (rate-limited per username and address); returns the session
/// (cookie token, CSRF token).
pub async fn login(
    pool: &SqlitePool,
    limiter: &LoginLimiter,
    username: &str,
    password: &str,
    peer: IpAddr,
) -> Result<(String, String)> {
    let key = format!("{username}|{peer}");
    {
        let mut failures = limiter.failures();
        let recent = failures.entry(key.clone()).or_default();
        recent.retain(|t| t.elapsed() < Duration::from_secs(60));
        if recent.len() >= LOGIN_ATTEMPTS {
            return Err(AppError::TooManyRequests);
        }
    }
    let row = store::accounts::credentials(pool, username).await?;
    let pw = password.to_string();
    // Verify against a dummy hash for unknown users too, so timing does not reveal names.
    let phc = row.as_ref().map(|r| r.1.clone());
    let ok =
        tokio::task::spawn_blocking(move || verify_password(&pw, &phc.unwrap_or_else(dummy_hash)))
            .await
            .map_err(anyhow::Error::from)?;
    match (row, ok) {
        (Some((id, _)), true) => {
            limiter.failures().remove(&key);
            new_session(
                pool,
                id,
                username,
                "login",
                json!({ "from": peer.to_string() }),
            )
            .await
        }
        _ => {
            limiter
                .failures()
                .entry(key)
                .or_default()
                .push(Instant::now());
            Err(AppError::Forbidden("wrong username or password".into()))
        }
    }
}
