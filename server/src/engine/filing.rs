//! How a trial's end is filed: the outcome decides the status (a trial found invalid while
//! it ran stays invalid); the result, the record, the re-queue of a failed test and the
//! audit row are committed together.

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::records::TrialStatus;
use bdft_protocol::trial::{FaultKind, Outcome};
use serde_json::json;
use sqlx::SqlitePool;

use super::queue::requeue_failed;
use crate::error::Result;
use crate::store::records::Record;
use crate::store::{self, Change};

/// How an outcome is filed: the experimenter's abort and the E-stop are "aborted"; any other
/// fault leaves the test "incomplete".
pub fn filing(outcome: &Outcome) -> (TrialStatus, Option<String>) {
    match outcome {
        Outcome::Complete => (TrialStatus::Complete, None),
        Outcome::Aborted { reason } => (TrialStatus::Aborted, Some(reason.clone())),
        Outcome::Faulted {
            fault: FaultKind::EStop,
            message,
        } => (TrialStatus::Aborted, Some(format!("e-stop: {message}"))),
        Outcome::Faulted { message, .. } => (TrialStatus::Incomplete, Some(message.clone())),
    }
}

/// Files a finished trial's result and record with its audit row. `false` when the trial
/// was no longer running (then nothing is stored).
pub async fn file_result(
    pool: &SqlitePool,
    actor: &str,
    result: &TrialResult,
    record: &Record,
) -> Result<bool> {
    let (status, reason) = filing(&result.outcome);
    let mut change = Change::begin(pool, actor).await?;
    let Some((status, reason)) =
        store::records::file_result(change.db(), result, status, reason.as_deref(), record).await?
    else {
        return Ok(false);
    };
    let requeued = requeue_failed(change.db(), result.trial_id as i64).await?;
    change
        .commit(
            "trial.finish",
            Some(format!("trial:{}", result.trial_id)),
            json!({ "status": status, "reason": reason, "metrics": result.metrics, "requeued": requeued }),
        )
        .await?;
    Ok(true)
}

/// Marks every running trial incomplete with `reason` (server restart, controller lost);
/// returns their ids.
pub async fn interrupt_running(pool: &SqlitePool, reason: &str) -> Result<Vec<i64>> {
    let mut change = Change::begin(pool, "system:trial-filing").await?;
    let ids = store::trials::interrupt_running(change.db(), reason).await?;
    if !ids.is_empty() {
        let mut requeued = Vec::new();
        for &id in &ids {
            requeued.extend(requeue_failed(change.db(), id).await?);
        }
        change
            .commit(
                "trial.interrupt",
                None,
                json!({ "trials": ids, "reason": reason, "requeued": requeued }),
            )
            .await?;
    }
    Ok(ids)
}
