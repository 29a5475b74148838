//! The E-stop latches as the store records them, beside each press's and reset's audit row:
//! the server's own latch (`engine::machine::estop_latch`, in memory and in a file outside
//! the store) is what starts and controllers obey, and it starts as the union of its file
//! and these rows. The one row of `estop_latch` latches every site at once;
//! `site_estop_latch` holds each site's own (a site without a row was never stopped on its
//! own).

use sqlx::{AnyConnection, AnyPool};

use super::db::{Flag, now_ms};
use crate::error::Result;

/// The stored latches: whether every site is latched, and the sites latched on their own.
pub async fn stored(db: &AnyPool) -> Result<(bool, Vec<String>)> {
    let (all,): (Flag,) = sqlx::query_as("SELECT latched FROM estop_latch WHERE id = 1")
        .fetch_one(db)
        .await?;
    let sites: Vec<(String,)> =
        sqlx::query_as("SELECT site FROM site_estop_latch WHERE latched = 1 ORDER BY site")
            .fetch_all(db)
            .await?;
    Ok((all.0, sites.into_iter().map(|(s,)| s).collect()))
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
