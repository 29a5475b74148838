//! Creating and editing a study: the parameters are validated and checked to run
//! (`runnable`), and a study whose protocol is locked (a subject enrolled) cannot change.

use bdft_protocol::study::StudyParams;
use serde_json::json;
use sqlx::SqlitePool;

use super::stability::{StabilityCache, StabilityReport};
use crate::engine::check_name;
use crate::error::{AppError, Result};
use crate::store::studies::Edit;
use crate::store::{self, Change};

/// Seeds are kept below 2^53 so they survive JSON and JavaScript unchanged.
const SEED_LIMIT: u64 = 1 << 53;

/// Creates a study (default seed: a random one); returns its id.
pub async fn create(
    pool: &SqlitePool,
    actor: &str,
    name: &str,
    params: &StudyParams,
    seed: Option<u64>,
) -> Result<i64> {
    check_name(name)?;
    if seed.is_some_and(|s| s >= SEED_LIMIT) {
        return Err(AppError::BadRequest(
            "seed: a whole number below 2^53".into(),
        ));
    }
    params.validate()?;
    check_runnable(params).await?;
    let seed = seed.unwrap_or_else(store::tokens::random_seed);
    let mut change = Change::begin(pool, actor).await?;
    let id = store::studies::insert(change.db(), name, params, seed).await?;
    change
        .commit(
            "study.create",
            Some(format!("study:{id}")),
            json!({ "name": name, "seed": seed }),
        )
        .await?;
    Ok(id)
}

/// `runnable::check` off the async threads (it designs every compensator and draws targets).
pub(super) async fn check_runnable(params: &StudyParams) -> Result<()> {
    let params = params.clone();
    tokio::task::spawn_blocking(move || super::runnable::check(&params))
        .await
        .map_err(|e| AppError::Internal(anyhow::anyhow!("the runnable check failed: {e}")))?
}

/// Replaces the name and parameters of a study that has not started, if nobody changed it
/// since `version` (the version the edit was based on).
pub async fn update(
    pool: &SqlitePool,
    actor: &str,
    id: i64,
    version: i64,
    name: &str,
    params: &StudyParams,
) -> Result<Edit> {
    check_name(name)?;
    params.validate()?;
    check_runnable(params).await?;
    let mut change = Change::begin(pool, actor).await?;
    let edit = store::studies::update(change.db(), id, version, name, params).await?;
    if let Edit::Stale(_) = edit {
        return Ok(edit);
    }
    change
        .commit(
            "study.update",
            Some(format!("study:{id}")),
            json!({ "name": name, "params": params, "version": version + 1 }),
        )
        .await?;
    Ok(edit)
}

/// Records that `actor` knows the study's design is unstable on the machine and wants it run
/// in simulation all the same (a real-machine study cannot be acknowledged).
pub async fn acknowledge_instability(
    pool: &SqlitePool,
    stability: &StabilityCache,
    actor: &str,
    id: i64,
    reason: &str,
) -> Result<StabilityReport> {
    crate::engine::check_reason(reason)?;
    let study = store::studies::get(pool, id).await?;
    let report = stability.report(&study.params).await?;
    if report.unstable().is_empty() {
        return Err(AppError::Conflict(
            "every design is stable on and off the machine: there is nothing to acknowledge".into(),
        ));
    }
    if study.params.rig == bdft_protocol::study::RigKind::Real {
        return Err(AppError::Conflict(
            "the study runs on the real machine: an unstable design cannot be acknowledged, only changed".into(),
        ));
    }
    let ack = json!({ "by": actor, "at": store::db::now_ms(), "reason": reason });
    let mut change = Change::begin(pool, actor).await?;
    store::studies::acknowledge_instability(change.db(), id, &ack).await?;
    change
        .commit(
            "study.acknowledge_instability",
            Some(format!("study:{id}")),
            json!({ "reason": reason, "unstable": report.unstable() }),
        )
        .await?;
    Ok(report)
}
