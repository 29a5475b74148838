//! How a trial's end is filed: the outcome decides the status (a trial found invalid while
//! it ran stays invalid); the result, the record, the re-queue of a failed test and the
//! audit row are committed together. Trials nobody will finish (the server restarted, the
//! controller or a pilot process was lost) are filed incomplete with the reason.

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::records::TrialStatus;
use bdft_protocol::trial::{FaultKind, Metrics, Outcome};
use serde::Serialize;
use sqlx::SqlitePool;

use super::queue::requeue_failed;
use crate::engine::machine::controller_link::{BoxFuture, Filing};
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

/// What `trial.finish` records: how the trial was filed, its metrics, and the attempt that
/// re-queued it (if it failed).
#[derive(Debug, Serialize)]
struct Finished<'a> {
    status: TrialStatus,
    reason: Option<String>,
    metrics: &'a Metrics,
    requeued: Option<i64>,
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
            Finished {
                status,
                reason,
                metrics: &result.metrics,
                requeued,
            },
        )
        .await?;
    Ok(true)
}

/// The controller link's filing (`controller_link::Filing`): results as the controller's,
/// lost trials marked incomplete.
#[derive(Debug)]
pub struct LinkFiling(pub SqlitePool);

impl Filing for LinkFiling {
    fn result<'a>(
        &'a self,
        result: &'a TrialResult,
        record: &'a Record,
    ) -> BoxFuture<'a, Result<bool>> {
        Box::pin(file_result(&self.0, "system:controller", result, record))
    }

    fn interrupted<'a>(&'a self, reason: &'a str) -> BoxFuture<'a, Result<Vec<i64>>> {
        Box::pin(interrupt_running(&self.0, reason))
    }
}

/// What `trial.interrupt` records: the trials marked incomplete, why, and their re-queued
/// attempts.
#[derive(Debug, Serialize)]
struct Interrupted<'a> {
    trials: &'a [i64],
    reason: &'a str,
    requeued: Vec<i64>,
}

/// Marks every running trial of this server's controller incomplete with `reason` (server
/// restart, controller lost); returns their ids. A pilot process's trials run on its own
/// controller: they end with its heartbeat (`end_lost_pilots`), not with this server's.
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
                Interrupted {
                    trials: &ids,
                    reason,
                    requeued,
                },
            )
            .await?;
    }
    Ok(ids)
}

/// A pilot process that has not beaten for this long was killed (it beats every second,
/// `pilot::BEAT`; the margin covers a loaded machine's stalls).
pub const PILOT_SILENCE: std::time::Duration = std::time::Duration::from_secs(10);

/// What `pilot.end` records: the trials the run left running, marked incomplete, and why.
#[derive(Debug, Serialize)]
struct PilotEnded<'a> {
    interrupted_trials: &'a [i64],
    reason: &'a str,
}

/// Ends the pilot run `run_id`: the trials it left running are marked incomplete with
/// `reason`, audited with the run; returns their ids.
pub async fn end_pilot_run(pool: &SqlitePool, run_id: i64, reason: &str) -> Result<Vec<i64>> {
    let mut change = Change::begin(pool, "system:pilot-watch").await?;
    let ids = store::pilot_runs::end(change.db(), run_id, reason).await?;
    change
        .commit(
            "pilot.end",
            Some(format!("pilot_run:{run_id}")),
            PilotEnded {
                interrupted_trials: &ids,
                reason,
            },
        )
        .await?;
    Ok(ids)
}

/// Ends every pilot run that has been silent for `PILOT_SILENCE` (its process was killed)
/// and files its running trials incomplete; returns those trials' ids.
pub async fn end_lost_pilots(pool: &SqlitePool) -> Result<Vec<i64>> {
    let before = store::db::now_ms() - PILOT_SILENCE.as_millis() as i64;
    let mut ids = Vec::new();
    for (run_id, pid) in store::pilot_runs::silent_since(pool, before).await? {
        let reason = format!(
            "pilot process {pid} stopped (no heartbeat for {} s)",
            PILOT_SILENCE.as_secs()
        );
        ids.extend(end_pilot_run(pool, run_id, &reason).await?);
    }
    Ok(ids)
}

/// The server's watch over pilot processes: every second, a killed pilot's trials are
/// filed (so none stays "running" until a restart).
pub async fn watch_pilots(pool: SqlitePool) {
    let mut tick = tokio::time::interval(std::time::Duration::from_secs(1));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        match end_lost_pilots(&pool).await {
            Ok(ids) if !ids.is_empty() => {
                tracing::warn!(trials = ?ids, "a pilot process stopped: its running trials are marked incomplete");
            }
            Ok(_) => {}
            Err(e) => tracing::warn!("checking for stopped pilot processes: {e}"),
        }
    }
}
