//! The E-stop latch the server keeps (one row): what every new controller connection is
//! told, and what keeps tests from starting until an experimenter resets it.

use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use crate::error::Result;

pub async fn latched<'c>(db: impl AnyExecutor<'c>) -> Result<bool> {
    let (latched,): (super::db::Flag,) =
        sqlx::query_as("SELECT latched FROM estop_latch WHERE id = 1")
            .fetch_one(db)
            .await?;
    Ok(latched.0)
}

pub async fn set(db: &mut AnyConnection, latched: bool) -> Result<()> {
    sqlx::query("UPDATE estop_latch SET latched = $1, changed_at = $2 WHERE id = 1")
        .bind(i64::from(latched))
        .bind(now_ms())
        .execute(db)
        .await?;
    Ok(())
}
