//! The E-stop latches the server keeps: what every new controller connection is told, and
//! what keeps tests from starting until an experimenter resets them. The one row of
//! `estop_latch` latches every site at once; `site_estop_latch` holds each site's own (a
//! site without a row was never stopped on its own).

use sqlx::{AnyConnection, AnyExecutor};

use super::db::{Flag, now_ms};
use crate::error::Result;

/// Whether `site` is latched: by its own latch or by the latch of every site.
pub async fn latched<'c>(db: impl AnyExecutor<'c>, site: &str) -> Result<bool> {
    let (latched,): (Flag,) = sqlx::query_as(
        "SELECT CASE WHEN latched = 1 OR EXISTS (SELECT 1 FROM site_estop_latch WHERE site = $1 AND latched = 1) THEN 1 ELSE 0 END FROM estop_latch WHERE id = 1",
    )
    .bind(site)
    .fetch_one(db)
    .await?;
    Ok(latched.0)
}

/// Whether every site is latched at once (the E-stop of all sites).
pub async fn all_latched<'c>(db: impl AnyExecutor<'c>) -> Result<bool> {
    let (latched,): (Flag,) = sqlx::query_as("SELECT latched FROM estop_latch WHERE id = 1")
        .fetch_one(db)
        .await?;
    Ok(latched.0)
}

/// Sets or clears the latch of every site; clearing it clears each site's own too.
pub async fn set_all(db: &mut AnyConnection, latched: bool) -> Result<()> {
    sqlx::query("UPDATE estop_latch SET latched = $1, changed_at = $2 WHERE id = 1")
        .bind(i64::from(latched))
        .bind(now_ms())
        .execute(&mut *db)
        .await?;
    if !latched {
        sqlx::query("UPDATE site_estop_latch SET latched = 0, changed_at = $1")
            .bind(now_ms())
            .execute(db)
            .await?;
    }
    Ok(())
}

/// Sets or clears the latch of `site` alone.
pub async fn set_site(db: &mut AnyConnection, site: &str, latched: bool) -> Result<()> {
    sqlx::query(
        "INSERT INTO site_estop_latch (site, latched, changed_at) VALUES ($1, $2, $3) ON CONFLICT (site) DO UPDATE SET latched = excluded.latched, changed_at = excluded.changed_at",
    )
    .bind(site)
    .bind(i64::from(latched))
    .bind(now_ms())
    .execute(db)
    .await?;
    Ok(())
}
