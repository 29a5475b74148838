//! Creating and editing a study: the parameters are validated and checked to run
//! (`runnable`), and a study whose protocol is locked (a subject enrolled) cannot change.

use bdft_protocol::study::StudyParams;
use serde::Serialize;
use sqlx::AnyPool;

use super::stability::{StabilityCache, StabilityReport, Verdict};
use crate::engine::check_name;
use crate::error::{AppError, Result};
use crate::store::studies::{Edit, InstabilityAck};
use crate::store::{self, Change};

/// Seeds are kept below 2^53 so they survive JSON and JavaScript unchanged.
const SEED_LIMIT: u64 = 1 << 53;

/// What `study.create` records: the name and seed, and `"dry_run": true` for a stand-alone
/// dry run (absent for a study of people).
#[derive(Debug, Serialize)]
struct Created<'a> {
    name: &'a str,
    seed: u64,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    dry_run: bool,
}

/// Creates a study (default seed: a random one); returns its id.
pub async fn create(
    pool: &AnyPool,
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
    insert(pool, actor, name, params, seed, false).await
}

/// Stores a new study (a stand-alone dry run if `dry_run`) with its `study.create` audit
/// row, in one transaction; returns its id.
pub(super) async fn insert(
    pool: &AnyPool,
    actor: &str,
    name: &str,
    params: &StudyParams,
    seed: u64,
    dry_run: bool,
) -> Result<i64> {
    let mut change = Change::begin(pool, actor).await?;
    let id = store::studies::insert(change.db(), name, params, seed).await?;
    if dry_run {
        store::dry_runs::insert(change.db(), id, None).await?;
    }
    change
        .commit(
            "study.create",
            Some(format!("study:{id}")),
            Created {
                name,
                seed,
                dry_run,
            },
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

/// What `study.update` records: the new name and parameters, and the version they make.
#[derive(Debug, Serialize)]
struct Updated<'a> {
    name: &'a str,
    params: &'a StudyParams,
    version: i64,
}

/// Replaces the name and parameters of a study that has not started, if nobody changed it
/// since `version` (the version the edit was based on).
pub async fn update(
    pool: &AnyPool,
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
            Updated {
                name,
                params,
                version: version + 1,
            },
        )
        .await?;
    Ok(edit)
}

/// What `study.acknowledge_instability` records: why, and the verdicts acknowledged.
#[derive(Debug, Serialize)]
struct Acknowledged<'a> {
    reason: &'a str,
    unstable: Vec<&'a Verdict>,
}

/// Records that `actor` knows the study's design is unstable on the machine and wants it run
/// in simulation all the same (a real-machine study cannot be acknowledged).
pub async fn acknowledge_instability(
    pool: &AnyPool,
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
    let ack = InstabilityAck {
        at: store::db::now_ms(),
        by: actor.to_string(),
        reason: reason.to_string(),
    };
    let mut change = Change::begin(pool, actor).await?;
    store::studies::acknowledge_instability(change.db(), id, &ack).await?;
    change
        .commit(
            "study.acknowledge_instability",
            Some(format!("study:{id}")),
            Acknowledged {
                reason,
                unstable: report.unstable(),
            },
        )
        .await?;
    Ok(report)
}
