//! The queue of a subject's tests: nothing is skipped. A person's test that failed
//! (aborted, incomplete or invalid) comes back as a new attempt at the end of its block, at
//! most [`MAX_ATTEMPTS`] times; the experimenter can instead accept it as incomplete, or
//! repeat it again by hand. The subject is finished only when every test is complete or
//! accepted as incomplete. A person's practice that failed so holds the schedule
//! (`store::trials::next`): nothing scored runs before the experimenter decides.

use bdft_protocol::records::{TestPhase, TrialStatus};
use bdft_protocol::server_to_browser::{HeldTest, StopNotice};
use sqlx::AnyConnection;

use crate::error::Result;
use crate::store;
use crate::store::trials::{Trial, latest_attempts};

/// Attempts of one test the server makes by itself: a rig that keeps failing must not loop
/// a subject forever; past this the experimenter decides (repeat or accept).
pub const MAX_ATTEMPTS: i64 = 3;

/// Re-queues the failed trial `trial_id` (in the caller's transaction) when it is a
/// person's, its test's latest attempt, the subject is still taking part and the test has
/// had fewer than [`MAX_ATTEMPTS`]; returns the new attempt's id.
pub async fn requeue_failed(db: &mut AnyConnection, trial_id: i64) -> Result<Option<i64>> {
    let t = store::trials::get(&mut *db, trial_id).await?;
    if !t.status.failed() || t.accepted_reason.is_some() {
        return Ok(None);
    }
    let subject = store::subjects::get(&mut *db, t.subject_id).await?;
    // A dry run reports what happened to its synthetic subjects; repeating their tests
    // would only hide it.
    if subject.synthetic || subject.withdrawn_at.is_some() {
        return Ok(None);
    }
    let latest = store::trials::latest_attempt(&mut *db, &t).await?;
    if latest != t.attempt || latest >= MAX_ATTEMPTS {
        return Ok(None);
    }
    Ok(Some(
        store::trials::insert_next_attempt(db, trial_id).await?,
    ))
}

/// Whether some test of the subject is still owed: neither complete nor accepted as
/// incomplete (queued, running, or failed too often and waiting for the experimenter).
pub fn anything_missing(trials: &[Trial]) -> bool {
    latest_attempts(trials).any(|t| !t.settled())
}

/// The test a held schedule waits on: a failed practice first (it holds every scored test),
/// then the first failed test in queue order.
pub fn held_test(trials: &[Trial]) -> Option<HeldTest> {
    let waiting = latest_attempts(trials)
        .filter(|t| t.status.failed() && !t.settled())
        .min_by_key(|t| (t.phase != TestPhase::Practice, t.block, t.queue_order))?;
    Some(HeldTest {
        trial_id: waiting.id,
        label: waiting.blinded_label.clone(),
        phase: waiting.phase,
        attempts: waiting.attempt,
    })
}

/// What the subject is told about their last test when it was stopped: the most recently
/// started attempt, if it failed; whether its test is queued again, and as the next test.
pub fn stop_notice(trials: &[Trial]) -> Option<StopNotice> {
    let last = trials
        .iter()
        .filter(|t| t.started_at.is_some())
        .max_by_key(|t| (t.started_at, t.id))?;
    if !last.status.failed() {
        return None;
    }
    let repeat = trials.iter().find(|t| {
        t.slot == last.slot && t.attempt > last.attempt && t.status == TrialStatus::Scheduled
    });
    // The test the station offers next: the first still to run in the queue's order (a
    // slot's latest attempt, by block then queue order, as `store::trials::next` picks it).
    let next = latest_attempts(trials)
        .filter(|t| t.status == TrialStatus::Scheduled)
        .min_by_key(|t| (t.block, t.queue_order));
    Some(StopNotice {
        label: last.blinded_label.clone(),
        status: last.status,
        repeated: repeat.is_some(),
        repeated_next: repeat.is_some_and(|r| next.is_some_and(|n| n.id == r.id)),
    })
}
