//! How a trial's end is filed: the outcome decides the status; the result, the record and
//! the audit row are committed together.

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::records::TrialStatus;
use bdft_protocol::trial::{FaultKind, Outcome};
use serde_json::json;
use sqlx::SqlitePool;

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
    if !store::records::file_result(change.db(), result, status, reason.as_deref(), record).await? {
        return Ok(false);
    }
    change
        .commit(
            "trial.finish",
            Some(format!("trial:{}", result.trial_id)),
            json!({ "status": status, "reason": reason, "metrics": result.metrics }),
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
        change
            .commit(
                "trial.interrupt",
                None,
                json!({ "trials": ids, "reason": reason }),
            )
            .await?;
    }
    Ok(ids)
}
