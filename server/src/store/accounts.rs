//! Experimenter accounts (argon2id hashes), their sessions, and the one-time set-up tokens.

use sqlx::{SqliteConnection, SqliteExecutor};

use super::db::now_ms;
use super::tokens::token_hash;
use crate::error::{AppError, Result};

/// Who a valid session cookie belongs to: (experimenter id, username, CSRF token).
pub async fn session<'c>(
    db: impl SqliteExecutor<'c>,
    token: &str,
) -> Result<Option<(i64, String, String)>> {
    Ok(sqlx::query_as(
        "SELECT e.id, e.username, s.csrf FROM sessions s JOIN experimenters e ON e.id = s.experimenter_id WHERE s.token_hash = ? AND s.expires_at > ?",
    )
    .bind(token_hash(token))
    .bind(now_ms())
    .fetch_optional(db)
    .await?)
}

pub async fn insert_session(
    db: &mut SqliteConnection,
    token: &str,
    experimenter_id: i64,
    csrf: &str,
    lifetime_ms: i64,
) -> Result<()> {
    let now = now_ms();
    sqlx::query("INSERT INTO sessions (token_hash, experimenter_id, csrf, created_at, expires_at) VALUES (?, ?, ?, ?, ?)")
        .bind(token_hash(token))
        .bind(experimenter_id)
        .bind(csrf)
        .bind(now)
        .bind(now + lifetime_ms)
        .execute(db)
        .await?;
    Ok(())
}

pub async fn delete_session(db: &mut SqliteConnection, token: &str) -> Result<()> {
    sqlx::query("DELETE FROM sessions WHERE token_hash = ?")
        .bind(token_hash(token))
        .execute(db)
        .await?;
    Ok(())
}

/// The id and password hash of a username.
pub async fn credentials<'c>(
    db: impl SqliteExecutor<'c>,
    username: &str,
) -> Result<Option<(i64, String)>> {
    Ok(
        sqlx::query_as("SELECT id, password_hash FROM experimenters WHERE username = ?")
            .bind(username)
            .fetch_optional(db)
            .await?,
    )
}

pub async fn insert_experimenter(
    db: &mut SqliteConnection,
    username: &str,
    password_hash: &str,
) -> Result<i64> {
    let r = sqlx::query(
        "INSERT INTO experimenters (username, password_hash, created_at) VALUES (?, ?, ?)",
    )
    .bind(username)
    .bind(password_hash)
    .bind(now_ms())
    .execute(db)
    .await;
    match r {
        Ok(r) => Ok(r.last_insert_rowid()),
        Err(sqlx::Error::Database(e)) if e.is_unique_violation() => Err(AppError::Conflict(
            format!("the username {username} is taken"),
        )),
        Err(e) => Err(e.into()),
    }
}

pub async fn experimenter_count<'c>(db: impl SqliteExecutor<'c>) -> Result<i64> {
    let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM experimenters")
        .fetch_one(db)
        .await?;
    Ok(n)
}

/// Stores a new set-up token and deletes every unused earlier one (at most one set-up link
/// is valid); returns how many were deleted.
pub async fn replace_setup_token(db: &mut SqliteConnection, token: &str) -> Result<u64> {
    let replaced = sqlx::query("DELETE FROM setup_tokens WHERE used_at IS NULL")
        .execute(&mut *db)
        .await?
        .rows_affected();
    sqlx::query("INSERT INTO setup_tokens (token_hash, created_at) VALUES (?, ?)")
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

pub async fn setup_token<'c>(
    db: impl SqliteExecutor<'c>,
    token: &str,
) -> Result<Option<SetupToken>> {
    Ok(
        sqlx::query_as("SELECT created_at, used_at FROM setup_tokens WHERE token_hash = ?")
            .bind(token_hash(token))
            .fetch_optional(db)
            .await?,
    )
}

/// Marks a set-up token used (the caller checked it is unused, inside its transaction).
pub async fn use_setup_token(db: &mut SqliteConnection, token: &str) -> Result<()> {
    sqlx::query("UPDATE setup_tokens SET used_at = ? WHERE token_hash = ? AND used_at IS NULL")
        .bind(now_ms())
        .bind(token_hash(token))
        .execute(db)
        .await?;
    Ok(())
}
