//! Pilots apart from people. A study either holds people or is a *dry run* holding only
//! synthetic subjects; never both, so a pilot can never pool synthetic data with a real
//! subject's (averages, plots, exports). A pilot of a study runs in its dry-run copy (same
//! parameters and seed, linked to it), made on the first pilot.

use serde::Serialize;
use sqlx::{AnyConnection, AnyPool};

use crate::error::{AppError, Result};
use crate::store::{self, Change};

/// Where a dry run stands, for the dashboard.
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct DryRunInfo {
    pub study_id: i64,
    /// Whether this study is a dry run (synthetic subjects only).
    pub dry_run: bool,
    /// The study a dry-run copy copies.
    pub copy_of: Option<i64>,
    /// A study's dry-run copy, once a pilot made one.
    pub dry_run_copy: Option<i64>,
}

pub async fn info(pool: &AnyPool, study_id: i64) -> Result<DryRunInfo> {
    store::studies::get(pool, study_id).await?;
    let of = store::dry_runs::dry_run(pool, study_id).await?;
    Ok(DryRunInfo {
        study_id,
        dry_run: of.is_some(),
        copy_of: of.flatten(),
        dry_run_copy: store::dry_runs::copy_of(pool, study_id).await?,
    })
}

/// Refuses a subject the study must not hold (checked inside the enrolment transaction).
pub async fn check_enrolment(db: &mut AnyConnection, study_id: i64, synthetic: bool) -> Result<()> {
    match (
        synthetic,
        store::dry_runs::dry_run(&mut *db, study_id).await?,
    ) {
        (true, None) => Err(AppError::Conflict(format!(
            "study {study_id} is for people: synthetic subjects go into its dry-run copy (POST /api/studies/{study_id}/dry-run makes it; a pilot uses it)"
        ))),
        (false, Some(_)) => Err(AppError::Conflict(format!(
            "study {study_id} is a dry run: it holds synthetic subjects only; enrol people in the study it copies"
        ))),
        _ => Ok(()),
    }
}

/// What `study.dry_run` records: the study copied, and the copy's name and seed.
#[derive(Debug, Serialize)]
struct Copied<'a> {
    copy_of: i64,
    name: &'a str,
    seed: u64,
}

/// The dry run a pilot of `study_id` writes into: the study itself if it is one, else its
/// dry-run copy (made now, in one transaction with its audit row, if there is none).
pub async fn for_pilot(pool: &AnyPool, actor: &str, study_id: i64) -> Result<i64> {
    let study = store::studies::get(pool, study_id).await?;
    if store::dry_runs::dry_run(pool, study_id).await?.is_some() {
        return Ok(study_id);
    }
    let mut change = Change::begin(pool, actor).await?;
    if let Some(copy) = store::dry_runs::copy_of(change.db(), study_id).await? {
        return Ok(copy);
    }
    let name = format!("{} (dry run)", study.name);
    let copy = store::studies::insert(change.db(), &name, &study.params, study.seed).await?;
    store::dry_runs::insert(change.db(), copy, Some(study_id)).await?;
    change
        .commit(
            "study.dry_run",
            Some(format!("study:{copy}")),
            Copied {
                copy_of: study_id,
                name: &name,
                seed: study.seed,
            },
        )
        .await?;
    Ok(copy)
}

/// A new stand-alone dry run of `params` (a pilot with no study to copy), in one
/// transaction with its audit row.
pub async fn create(
    pool: &AnyPool,
    actor: &str,
    params: &bdft_protocol::study::StudyParams,
    seed: Option<u64>,
) -> Result<i64> {
    params.validate()?;
    let seed = seed.unwrap_or_else(store::tokens::random_seed);
    super::studies::insert(pool, actor, "Pilot (default protocol)", params, seed, true).await
}
