//! How a trial's end is filed: the outcome decides the status (a trial found invalid while
//! it ran stays invalid); the result, the record, the re-queue of a failed test and the
//! audit row are committed together. Trials nobody will finish (the server restarted, the
//! controller or a pilot process was lost) are filed incomplete with the reason. What the
//! controller link hands over and cannot be written now (the disk full) is written again
//! every second until it is ([`LinkFiling`]).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::exposure::{ACTION_A8_M_S2, ACTION_VDV_M_S175, DoseSum};
use bdft_protocol::params::{AdaptationStatus, Seat};
use bdft_protocol::records::{TestPhase, TrialStatus};
use bdft_protocol::trial::{FaultKind, Metrics, Outcome};
use serde::Serialize;
use sqlx::AnyPool;
use tokio::sync::broadcast;

use super::identification::{self, Measured};
use super::lsl;
use super::queue::requeue_failed;
use crate::engine::machine::controller_link::{BoxFuture, ControllerEvent, Filing};
use crate::engine::study::exposure::{action_values_reached, last_24h};
use crate::error::{AppError, Result};
use crate::store::records::Record;
use crate::store::trials::Trial;
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

/// What `trial.finish` records: how the trial was filed, its metrics, the attempt that
/// re-queued it (if it failed), when cancellation's guard turned it off (if it did), and what an
/// adaptive design did (its fallbacks to the fixed design among it).
#[derive(Debug, Serialize)]
struct Finished<'a> {
    status: TrialStatus,
    reason: Option<String>,
    metrics: &'a Metrics,
    requeued: Option<i64>,
    /// When cancellation's guard turned it off for the rest of the test (s into it).
    #[serde(skip_serializing_if = "Option::is_none")]
    cancellation_off_at_s: Option<f64>,
    /// What an adaptive design did: its estimate, retunes and fallbacks to the fixed design.
    #[serde(skip_serializing_if = "Option::is_none")]
    adaptation: Option<AdaptationStatus>,
}

/// Files a finished trial's result and record with its audit row. `false` when the trial
/// was no longer running (then nothing is stored).
pub async fn file_result(
    pool: &AnyPool,
    actor: &str,
    result: &TrialResult,
    record: &Record,
) -> Result<bool> {
    let (status, reason) = filing(&result.outcome);
    let measured = match status {
        TrialStatus::Complete => measure_identification(pool, result, record).await?,
        _ => None,
    };
    let mut change = Change::begin(pool, actor).await?;
    let Some((status, reason)) =
        store::records::file_result(change.db(), result, status, reason.as_deref(), record).await?
    else {
        return Ok(false);
    };
    // Filed complete only now: a test found invalid while it ran stays invalid, and then
    // it measured nothing.
    if let (TrialStatus::Complete, Some((trial, m))) = (status, &measured) {
        identification::store(&mut change, trial, m).await?;
    }
    if let Some(t) = result.cancellation_off_at_s {
        tracing::warn!(
            trial_id = result.trial_id,
            at_s = t,
            "cancellation's guard turned it off; the test went on uncancelled"
        );
    }
    if let Some(a) = result.adaptation.filter(|a| a.fallbacks > 0) {
        tracing::info!(
            trial_id = result.trial_id,
            fallbacks = a.fallbacks,
            confident_since_s = a.confident_since_s,
            "the adaptive design fell back to its fixed design without a trusted estimate"
        );
    }
    let requeued = requeue_failed(change.db(), result.trial_id as i64).await?;
    audit_action_values(&mut change, result).await?;
    change
        .commit(
            "trial.finish",
            Some(format!("trial:{}", result.trial_id)),
            Finished {
                status,
                reason,
                metrics: &result.metrics,
                requeued,
                cancellation_off_at_s: result.cancellation_off_at_s,
                adaptation: result.adaptation,
            },
        )
        .await?;
    lsl::test_filed(pool, result, status.as_str()).await;
    Ok(true)
}

/// What the record of `result`'s trial measured, when it is an identification test.
async fn measure_identification(
    pool: &AnyPool,
    result: &TrialResult,
    record: &Record,
) -> Result<Option<(Trial, Measured)>> {
    let trial = match store::trials::get(pool, result.trial_id as i64).await {
        Ok(t) => t,
        // Not a trial of ours (the file_result below says so).
        Err(AppError::NotFound(_)) => return Ok(None),
        Err(e) => return Err(e),
    };
    if trial.phase != TestPhase::Identification {
        return Ok(None);
    }
    let subject = store::subjects::get(pool, trial.subject_id).await?;
    let study = store::studies::get(pool, subject.study_id).await?;
    Ok(identification::measure(&study.params, &trial, record)
        .await
        .map(|m| (trial, m)))
}

/// What `exposure.action_value` records: a test took its subject's daily exposure (the 24 h
/// before it) to an action value of 2002/44/EC.
#[derive(Debug, Serialize)]
struct ActionValueReached<'a> {
    subject: &'a str,
    trial_id: i64,
    /// `a8`, `vdv` or both.
    reached: Vec<&'static str>,
    a8_m_s2: f64,
    vdv_m_s175: f64,
    action_a8_m_s2: f64,
    action_vdv_m_s175: f64,
}

/// Audits the action values a filed test on the machine took its subject's day to.
async fn audit_action_values(change: &mut Change, result: &TrialResult) -> Result<()> {
    let Some(exposure) = result.exposure else {
        return Ok(());
    };
    let trial = store::trials::get(change.db(), result.trial_id as i64).await?;
    if trial.seat != Seat::On {
        return Ok(());
    }
    let subject = store::subjects::get(change.db(), trial.subject_id).await?;
    let study = store::studies::get(change.db(), subject.study_id).await?;
    let after = last_24h(change.db(), &study.params, subject.id, store::db::now_ms()).await?;
    let before = DoseSum {
        energy_m2_s3: after.energy_m2_s3 - exposure.energy(),
        vdv4_m4_s7: after.vdv4_m4_s7 - exposure.vdv4(),
    };
    let reached = action_values_reached(before, after);
    if reached.is_empty() {
        return Ok(());
    }
    change
        .audit_also(
            "exposure.action_value",
            Some(format!("subject:{}", subject.id)),
            ActionValueReached {
                subject: &subject.code,
                trial_id: trial.id,
                reached,
                a8_m_s2: after.a8(),
                vdv_m_s175: after.vdv(),
                action_a8_m_s2: ACTION_A8_M_S2,
                action_vdv_m_s175: ACTION_VDV_M_S175,
            },
        )
        .await
}

/// How often [`LinkFiling`] writes again what it could not.
const RETRY_EVERY: Duration = Duration::from_secs(1);

/// The controller link's filing (`controller_link::Filing`): results as the controller's,
/// lost trials marked incomplete. What cannot be written now (the disk full, the database
/// locked past its timeout) is kept and written again every second until it is, so that no
/// result is lost and no trial is left running while this server lives (a restart files
/// what it still held as it files every trial running then). A test whose result waits
/// shows as running meanwhile: nothing else can be stored either.
#[derive(Debug)]
pub struct LinkFiling {
    pool: AnyPool,
    unfiled: Mutex<Vec<Unfiled>>,
    /// Told about a trial filed late, so that its station and the dashboards show it.
    events: broadcast::Sender<ControllerEvent>,
}

/// What the link handed over and could not be written yet.
#[derive(Debug)]
enum Unfiled {
    Result(Box<TrialResult>, Record),
    /// Trials of a lost controller, to be filed incomplete with the reason.
    Lost {
        trials: Vec<i64>,
        reason: String,
    },
}

/// Who files what the controller link hands over (the audit log's actor).
const LINK_ACTOR: &str = "system:controller";

impl LinkFiling {
    /// A filing on `pool` that tells `events` what it filed late; what it could not write is
    /// written again every second.
    pub fn start(pool: AnyPool, events: broadcast::Sender<ControllerEvent>) -> Arc<Self> {
        let filing = Arc::new(Self {
            pool,
            unfiled: Mutex::new(Vec::new()),
            events,
        });
        let weak = Arc::downgrade(&filing);
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(RETRY_EVERY);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tick.tick().await;
                let Some(filing) = weak.upgrade() else { return };
                filing.retry().await;
            }
        });
        filing
    }

    fn unfiled(&self) -> std::sync::MutexGuard<'_, Vec<Unfiled>> {
        self.unfiled.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Writes what waits; keeps what still cannot be written.
    async fn retry(&self) {
        let waiting = std::mem::take(&mut *self.unfiled());
        for item in waiting {
            let filed = match &item {
                Unfiled::Result(result, record) => {
                    file_result(&self.pool, LINK_ACTOR, result, record)
                        .await
                        .map(|_| vec![result.trial_id as i64])
                }
                Unfiled::Lost { trials, reason } => interrupt(&self.pool, trials, reason).await,
            };
            match filed {
                Ok(ids) => {
                    tracing::warn!(trials = ?ids, "filed late: the database takes writes again");
                    for trial_id in ids {
                        let _ = self.events.send(ControllerEvent::TrialChanged { trial_id });
                    }
                }
                Err(_) => self.unfiled().push(item),
            }
        }
    }
}

impl Filing for LinkFiling {
    fn result<'a>(
        &'a self,
        result: &'a TrialResult,
        record: &'a Record,
    ) -> BoxFuture<'a, Result<bool>> {
        Box::pin(async move {
            let filed = file_result(&self.pool, LINK_ACTOR, result, record).await;
            if let Err(e) = &filed {
                tracing::error!(
                    trial = result.trial_id,
                    "the result is kept and written again every second: {e}"
                );
                self.unfiled()
                    .push(Unfiled::Result(Box::new(result.clone()), record.clone()));
            }
            filed
        })
    }

    fn interrupted<'a>(
        &'a self,
        site: &'a str,
        reason: &'a str,
    ) -> BoxFuture<'a, Result<Vec<i64>>> {
        Box::pin(async move {
            // A trial whose result waits to be written is not lost.
            let held: Vec<i64> = self
                .unfiled()
                .iter()
                .filter_map(|u| match u {
                    Unfiled::Result(r, _) => Some(r.trial_id as i64),
                    Unfiled::Lost { .. } => None,
                })
                .collect();
            let trials: Vec<i64> = store::trials::running_ids_at(&self.pool, site)
                .await?
                .into_iter()
                .filter(|id| !held.contains(id))
                .collect();
            if trials.is_empty() {
                return Ok(trials);
            }
            match interrupt(&self.pool, &trials, reason).await {
                Ok(marked) => Ok(marked),
                Err(e) => {
                    tracing::error!(
                        ?trials,
                        "filing the lost controller's trials is tried again every second: {e}"
                    );
                    self.unfiled().push(Unfiled::Lost {
                        trials: trials.clone(),
                        reason: reason.to_string(),
                    });
                    Ok(trials)
                }
            }
        })
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
pub async fn interrupt_running(pool: &AnyPool, reason: &str) -> Result<Vec<i64>> {
    let trials = store::trials::running_ids(pool).await?;
    interrupt(pool, &trials, reason).await
}

/// Marks those of `trials` that still run incomplete with `reason`, re-queues them and audits
/// it; returns the ids marked.
async fn interrupt(pool: &AnyPool, trials: &[i64], reason: &str) -> Result<Vec<i64>> {
    let mut change = Change::begin(pool, "system:trial-filing").await?;
    let ids = store::trials::interrupt(change.db(), trials, reason).await?;
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
pub async fn end_pilot_run(pool: &AnyPool, run_id: i64, reason: &str) -> Result<Vec<i64>> {
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
pub async fn end_lost_pilots(pool: &AnyPool) -> Result<Vec<i64>> {
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
pub async fn watch_pilots(pool: AnyPool) {
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
