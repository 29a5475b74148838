//! Which studies are dry runs (synthetic subjects only), and which study each copies.

use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use crate::error::Result;

/// `None`: a study for people. `Some(of)`: a dry run, copying study `of` if it is a copy.
pub async fn dry_run<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<Option<Option<i64>>> {
    let row: Option<(Option<i64>,)> =
        sqlx::query_as("SELECT of_study FROM dry_runs WHERE study_id = $1")
            .bind(study_id)
            .fetch_optional(db)
            .await?;
    Ok(row.map(|(of,)| of))
}

/// The dry-run copy of `study_id`, if it has one.
pub async fn copy_of<'c>(db: impl AnyExecutor<'c>, study_id: i64) -> Result<Option<i64>> {
    let row: Option<(i64,)> = sqlx::query_as("SELECT study_id FROM dry_runs WHERE of_study = $1")
        .bind(study_id)
        .fetch_optional(db)
        .await?;
    Ok(row.map(|(id,)| id))
}

pub async fn insert(db: &mut AnyConnection, study_id: i64, of_study: Option<i64>) -> Result<()> {
    sqlx::query("INSERT INTO dry_runs (study_id, of_study, created_at) VALUES ($1, $2, $3)")
        .bind(study_id)
        .bind(of_study)
        .bind(now_ms())
        .execute(db)
        .await?;
    Ok(())
}
