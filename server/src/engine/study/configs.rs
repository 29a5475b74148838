//! Versioned controller configurations: a new version for every edit of a design (validated
//! and built as the controller builds it), and a study's pick of versions, resolved into the
//! design its parameters hold — so the protocol hash and the controller's messages are those
//! of a study that names the designs itself.

use bdft_protocol::params::{CompensatorKind, CompensatorSpec};
use serde::Serialize;
use sqlx::AnyPool;

use super::schedule::default_params;
use crate::engine::check_name;
use crate::error::{AppError, Result};
use crate::store::configs::ConfigVersion;
use crate::store::studies::Edit;
use crate::store::{self, Change};

/// Most versions a study picks at once: one per compensator kind.
const MAX_PICKS: usize = bdft_protocol::params::CompensatorKind::ALL.len();

/// What `config.create` records: the version made and its design.
#[derive(Debug, Serialize)]
struct Created<'a> {
    name: &'a str,
    version: i64,
    spec: &'a CompensatorSpec,
}

/// Adds the next version of `name` with design `spec`.
pub async fn create(
    pool: &AnyPool,
    actor: &str,
    name: &str,
    spec: &CompensatorSpec,
) -> Result<ConfigVersion> {
    check_name(name)?;
    spec.validate()?;
    // Built on the published plant as the controller builds it: an unsolvable design is
    // refused now, not when a study or a bench run first uses it.
    let (params, to_build) = (default_params(), spec.clone());
    tokio::task::spawn_blocking(move || super::runnable::check_design(&params, &to_build))
        .await
        .map_err(|e| AppError::Internal(anyhow::anyhow!("building the design failed: {e}")))??;
    let mut change = Change::begin(pool, actor).await?;
    let (id, version) = store::configs::insert(change.db(), name, spec).await?;
    change
        .commit(
            "config.create",
            Some(format!("config:{id}")),
            Created {
                name,
                version,
                spec,
            },
        )
        .await?;
    store::configs::get(pool, id).await
}

/// What `study.configs` records: the versions picked, and the study version they make.
#[derive(Debug, Serialize)]
struct Picked<'a> {
    picked: Vec<PickedVersion<'a>>,
    version: i64,
}

/// One version picked, by its id, name, number and kind.
#[derive(Debug, Serialize)]
struct PickedVersion<'a> {
    config_id: i64,
    name: &'a str,
    version: i64,
    kind: CompensatorKind,
}

/// Puts each of `config_ids` in place of the study's design of the same kind (a new study
/// version, audited as `study.configs`); refused for a locked study.
pub async fn pick(pool: &AnyPool, actor: &str, study_id: i64, config_ids: &[i64]) -> Result<()> {
    if config_ids.is_empty() || config_ids.len() > MAX_PICKS {
        return Err(AppError::BadRequest(format!(
            "config_ids: 1 to {MAX_PICKS} configuration versions"
        )));
    }
    let study = store::studies::get(pool, study_id).await?;
    if study.locked_at.is_some() {
        return Err(AppError::Conflict(
            "the study's protocol is locked: a subject has been enrolled, so its configuration versions cannot change".into(),
        ));
    }
    let mut params = study.params.clone();
    let mut versions = Vec::with_capacity(config_ids.len());
    for &id in config_ids {
        let v = store::configs::get(pool, id).await?;
        if versions.iter().any(|p: &ConfigVersion| p.kind == v.kind) {
            return Err(AppError::BadRequest(format!(
                "config_ids: two versions for the {} design; pick one",
                v.kind
            )));
        }
        let Some(slot) = params.compensators.iter_mut().find(|c| c.kind() == v.kind) else {
            return Err(AppError::BadRequest(format!(
                "config_ids: the study compares no {} design, so version {} of {:?} has no place in it",
                v.kind, v.version, v.name
            )));
        };
        *slot = v.spec.clone();
        versions.push(v);
    }
    params.validate()?;
    super::studies::check_runnable(&params).await?;
    let mut change = Change::begin(pool, actor).await?;
    let edit =
        store::studies::update(change.db(), study_id, study.version, &study.name, &params).await?;
    if let Edit::Stale(_) = edit {
        return Err(AppError::Conflict(
            "someone else changed the study at the same moment; reload and try again".into(),
        ));
    }
    for v in &versions {
        store::configs::pick(change.db(), study_id, v.kind, v.id).await?;
    }
    let picked = versions
        .iter()
        .map(|v| PickedVersion {
            config_id: v.id,
            name: &v.name,
            version: v.version,
            kind: v.kind,
        })
        .collect();
    change
        .commit(
            "study.configs",
            Some(format!("study:{study_id}")),
            Picked {
                picked,
                version: study.version + 1,
            },
        )
        .await
}
