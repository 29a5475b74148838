//! The rules of a test's life: when it may start (consent, order, surveys, the right rig),
//! when it may be redone (queued again by hand: `queue` re-queues failed tests by itself),
//! aborted or accepted as incomplete, and the E-stop. Every change is committed with its audit row.

use bdft_protocol::params::{CompensatorKind, Seat};
use bdft_protocol::records::{ConsentDecision, TestPhase, TrialStatus};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::study::RigKind;
use serde::Serialize;
use sqlx::AnyPool;

use super::lsl::{self, Marker};
use super::orchestrator::{Operator, start_now};
use super::queue;
use crate::engine::machine::controller_link::{ControllerEvent, ControllerLink};
use crate::engine::machine::estop_latch;
use crate::engine::machine::sites::Sites;
use crate::error::{AppError, Result};
use crate::store::audit::{NoDetail, Reason};
use crate::store::trials::Trial;
use crate::store::{self, Change};

/// The rig kind a controller must have to run a study on `rig`: "sim" or "udp".
fn rig_name(rig: RigKind) -> &'static str {
    match rig {
        RigKind::Simulated => "sim",
        RigKind::Real => "udp",
    }
}

/// What `trial.start` records: the compensator and the seat, by their wire names.
#[derive(Debug, Serialize)]
struct Started {
    #[serde(rename = "controller")]
    compensator: CompensatorKind,
    #[serde(rename = "station")]
    seat: Seat,
}

/// The site a subject's tests run at: its stations' (a subject's stations are at one
/// site), or the server's first site for a subject at no station.
async fn site_of_subject<'s>(
    pool: &AnyPool,
    sites: &'s Sites,
    subject: &store::subjects::Subject,
) -> Result<&'s ControllerLink> {
    let stored = super::stations::subject_site(pool, subject.id).await?;
    let stored = stored.as_deref();
    sites.stored(stored).ok_or_else(|| {
        AppError::Conflict(format!(
            "{}'s station is at site {:?}, which this server does not serve (its sites: {})",
            subject.code,
            sites.name_of(stored),
            sites.names().join(", ")
        ))
    })
}

/// The link of the site a running trial runs at (recorded when it started).
pub fn site_of_trial<'s>(sites: &'s Sites, trial: &Trial) -> Result<&'s ControllerLink> {
    sites.stored(trial.site.as_deref()).ok_or_else(|| {
        AppError::Unavailable(format!(
            "trial {} runs at site {:?}, which this server does not serve now",
            trial.id,
            sites.name_of(trial.site.as_deref())
        ))
    })
}

/// Checks that `trial` may start now and starts it on the controller of its subject's site.
pub async fn start(pool: &AnyPool, sites: &Sites, actor: &str, trial_id: i64) -> Result<Trial> {
    let trial = store::trials::get(pool, trial_id).await?;
    let subject = store::subjects::get(pool, trial.subject_id).await?;
    if subject.withdrawn_at.is_some() {
        return Err(AppError::Conflict(format!(
            "{} has withdrawn",
            subject.code
        )));
    }
    if subject.consent_decision != Some(ConsentDecision::Agreed) {
        return Err(AppError::Conflict(format!(
            "{} has not consented; nothing runs without consent",
            subject.code
        )));
    }
    let next = store::trials::next(pool, subject.id).await?;
    if next.is_none() {
        let attempts = store::trials::of_subject(pool, subject.id).await?;
        if let Some(held) = queue::held_test(&attempts) {
            return Err(AppError::Conflict(format!(
                "{}'s schedule is held: {} (trial {}) failed {} times; redo it or accept it as incomplete with a reason first",
                subject.code, held.label, held.trial_id, held.attempts
            )));
        }
    }
    if next.as_ref().map(|t| t.id) != Some(trial.id) {
        return Err(AppError::Conflict(format!(
            "trial {} is not {}'s next test",
            trial.id, subject.code
        )));
    }
    // A synthetic subject's surveys may be answered (to try the pages) but never hold up a
    // dry run; a person's must be answered before the next test.
    if !subject.synthetic {
        if let Some(pending) = store::trials::pending_survey(pool, subject.id).await? {
            return Err(AppError::Conflict(format!(
                "the survey of trial {} is still to be answered",
                pending.id
            )));
        }
    }
    let link = site_of_subject(pool, sites, &subject).await?;
    if sites.latch().latched(link.site()) {
        return Err(AppError::Conflict(format!(
            "the E-stop of site {:?} is latched: reset it (Reset e-stop, POST /api/estop/reset) before starting a test",
            link.site()
        )));
    }
    if !link.is_connected() {
        return Err(AppError::Unavailable(format!(
            "the controller of site {:?} is not connected",
            link.site()
        )));
    }
    let study = store::studies::get(pool, subject.study_id).await?;
    // A study run on the real machine must never go to a simulating controller, nor the
    // reverse: the data would silently mean something else.
    let want = rig_name(study.params.rig);
    if link.rig().as_deref() != Some(want) {
        return Err(AppError::Conflict(format!(
            "the study runs on the {} rig but the controller's rig is {}",
            if want == "sim" { "simulated" } else { "real" },
            link.rig().unwrap_or_else(|| "unknown".into())
        )));
    }
    let operator = if subject.synthetic {
        Operator::Synthetic(subject.drawn)
    } else {
        Operator::Person
    };
    let mut change = Change::begin(pool, actor).await?;
    let msg = start_now(change.db(), &study, &trial, &subject, operator).await?;
    store::trials::mark_running(change.db(), trial.id, Some(link.site())).await?;
    change
        .commit(
            "trial.start",
            Some(format!("trial:{}", trial.id)),
            Started {
                compensator: trial.compensator,
                seat: trial.seat,
            },
        )
        .await?;
    // Its station's LSL streams are up and route its ticks before it starts.
    lsl::trial_starting(pool, link, &trial).await;
    if let Err(reason) = link.start_trial(&msg).await {
        let mut change = Change::begin(pool, actor).await?;
        if !store::trials::unmark_running(change.db(), trial.id).await? {
            // The controller was lost while it started: the loss filed the trial first
            // (incomplete, to be repeated), and so it stays.
            return Err(AppError::Unavailable(format!(
                "the controller was lost as the trial started ({reason}); it is filed incomplete and will be repeated"
            )));
        }
        change
            .commit(
                "trial.start_failed",
                Some(format!("trial:{}", trial.id)),
                Reason { reason: &reason },
            )
            .await?;
        return Err(AppError::Unavailable(format!(
            "the controller did not start the trial: {reason}"
        )));
    }
    // The station's socket starts forwarding operator input at once.
    link.emit(ControllerEvent::TrialChanged { trial_id: trial.id });
    lsl::test_started(pool, &trial).await;
    store::trials::get(pool, trial.id).await
}

/// Stops a running trial early; its site's controller files it aborted with `reason`.
pub async fn abort(
    pool: &AnyPool,
    sites: &Sites,
    actor: &str,
    trial_id: i64,
    reason: &str,
) -> Result<()> {
    crate::engine::check_reason(reason)?;
    let trial = store::trials::get(pool, trial_id).await?;
    if trial.status != TrialStatus::Running {
        return Err(AppError::Conflict(format!(
            "trial {trial_id} is {}, not running",
            trial.status
        )));
    }
    site_of_trial(sites, &trial)?
        .send(&ServerToController::AbortTrial {
            trial_id: trial_id as u64,
            reason: reason.to_string(),
        })
        .map_err(AppError::Unavailable)?;
    Change::begin(pool, actor)
        .await?
        .commit(
            "trial.abort",
            Some(format!("trial:{trial_id}")),
            Reason { reason },
        )
        .await
}

/// What `trial.redo` records: the new attempt and why.
#[derive(Debug, Serialize)]
struct Redone<'a> {
    new_trial: i64,
    reason: &'a str,
}

/// Adds the next attempt of a finished test (the latest attempt only), queued at the end of
/// its block like a failed test's; returns it. The experimenter may repeat a test that
/// failed more often than the server repeats it by itself.
pub async fn redo(pool: &AnyPool, actor: &str, trial_id: i64, reason: &str) -> Result<Trial> {
    if reason.chars().count() > 500 {
        return Err(AppError::BadRequest(
            "reason: at most 500 characters".into(),
        ));
    }
    // Read and insert in one immediate transaction: two redos racing see each other.
    let mut change = Change::begin(pool, actor).await?;
    let t = store::trials::get(change.db(), trial_id).await?;
    let latest = store::trials::latest_attempt(change.db(), &t).await?;
    if latest != t.attempt || !t.finished() {
        return Err(AppError::Conflict(
            "only the latest attempt of a finished test can be redone".into(),
        ));
    }
    let new_id = store::trials::insert_next_attempt(change.db(), trial_id).await?;
    let new = store::trials::get(change.db(), new_id).await?;
    change
        .commit(
            "trial.redo",
            Some(format!("trial:{trial_id}")),
            Redone {
                new_trial: new_id,
                reason,
            },
        )
        .await?;
    lsl::mark_trial(
        pool,
        trial_id,
        Marker::Redo {
            trial_id,
            new_trial_id: new_id,
        },
    )
    .await;
    Ok(new)
}

/// The experimenter accepts a test as incomplete with a reason: it is not run (again) and
/// counts as missing with the reason. `trial_id` may be any attempt of the test; the latest
/// is the one accepted (a failed attempt, its re-queued successor, or a complete one).
pub async fn accept_incomplete(
    pool: &AnyPool,
    actor: &str,
    trial_id: i64,
    reason: &str,
) -> Result<Trial> {
    crate::engine::check_reason(reason)?;
    let mut change = Change::begin(pool, actor).await?;
    let given = store::trials::get(change.db(), trial_id).await?;
    let trial_id = store::trials::of_subject(change.db(), given.subject_id)
        .await?
        .into_iter()
        .filter(|t| t.slot == given.slot)
        .max_by_key(|t| t.attempt)
        .map_or(trial_id, |t| t.id);
    store::trials::accept_incomplete(change.db(), trial_id, reason).await?;
    let t = store::trials::get(change.db(), trial_id).await?;
    if t.phase == TestPhase::Identification {
        // No body will be measured: the cancelling tests that needed it are not run, said
        // now rather than refused one by one at their start.
        let subject = store::subjects::get(change.db(), t.subject_id).await?;
        let params = store::studies::get(change.db(), subject.study_id)
            .await?
            .params;
        let why = "the identification test was accepted as incomplete";
        let planned = super::cancellation::plan(&params, Err(why), None);
        super::cancellation::store(&mut change, &t, &planned).await?;
    }
    change
        .commit(
            "trial.accept_incomplete",
            Some(format!("trial:{trial_id}")),
            Reason { reason },
        )
        .await?;
    Ok(t)
}

/// What `trial.note` records: the note's id and its text.
#[derive(Debug, Serialize)]
struct Noted<'a> {
    note: i64,
    text: &'a str,
}

/// A note about a test, by its author; returns the note's id.
pub async fn add_note(pool: &AnyPool, author: &str, trial_id: i64, text: &str) -> Result<i64> {
    if text.trim().is_empty() || text.chars().count() > 2000 {
        return Err(AppError::BadRequest("text: 1 to 2000 characters".into()));
    }
    let mut change = Change::begin(pool, author).await?;
    let t = store::trials::get(change.db(), trial_id).await?;
    let note = store::subjects::add_note(change.db(), t.subject_id, trial_id, text, author).await?;
    change
        .commit(
            "trial.note",
            Some(format!("trial:{trial_id}")),
            Noted { note, text },
        )
        .await?;
    Ok(note)
}

/// What `estop` records: whether every controller confirmed the stop and the slowest
/// confirmation, and the same for each site stopped.
#[derive(Debug, Serialize)]
struct EStopped<'a> {
    delivered: bool,
    confirmed_ms: Option<f64>,
    sites: Vec<SiteStopped<'a>>,
}

#[derive(Debug, Serialize)]
struct SiteStopped<'a> {
    site: &'a str,
    delivered: bool,
    confirmed_ms: Option<f64>,
}

/// A confirmed E-stop: the sites stopped and the slowest confirmation.
#[derive(Debug)]
pub struct Stopped {
    pub sites: Vec<String>,
    pub slowest: std::time::Duration,
    /// Why the latch is held in memory only (its file could not be written), if it is.
    pub latch_not_kept: Option<String>,
}

/// The E-stop of one site (`site`) or of every site (none, or a site this server does not
/// serve: a stop is never refused for a wrong name). Sent first, to each controller at
/// once, while the server's latch is set (in memory at once, then in its file: never behind
/// the store's lock); answered when the controllers confirm. The audit row follows when the
/// store allows (`estop_latch::record_pending`); an error naming each site whose controller
/// did not confirm.
///
/// Runs to its end on a task of its own: a client that goes away cannot cut a stop short.
pub async fn estop(sites: &Sites, actor: &str, site: Option<&str>) -> Result<Stopped> {
    let (sites, actor, site) = (sites.clone(), actor.to_string(), site.map(str::to_string));
    tokio::spawn(async move { press(&sites, &actor, site.as_deref()).await })
        .await
        .map_err(|e| AppError::Internal(anyhow::anyhow!("the E-stop's task: {e}")))?
}

async fn press(sites: &Sites, actor: &str, site: Option<&str>) -> Result<Stopped> {
    let one = site.and_then(|name| sites.named(name).ok());
    let links: Vec<&ControllerLink> = match one {
        Some(link) => vec![link],
        None => sites.all().iter().collect(),
    };
    let site = one.map(ControllerLink::site);
    let latch = sites.latch();
    let ((number, kept), sent) = futures_util::future::join(
        latch.press(actor, site),
        futures_util::future::join_all(links.iter().map(|l| l.estop(ESTOP_CONFIRMATION))),
    )
    .await;
    lsl::estop();
    if let Err(e) = &kept {
        tracing::error!(
            "the E-stop latch file could not be written (the latch holds in memory): {e}"
        );
    }
    let ms = |r: &std::result::Result<std::time::Duration, String>| {
        r.as_ref().ok().map(|d| d.as_secs_f64() * 1e3)
    };
    let sites_stopped: Vec<SiteStopped> = links
        .iter()
        .zip(&sent)
        .map(|(l, r)| SiteStopped {
            site: l.site(),
            delivered: r.is_ok(),
            confirmed_ms: ms(r),
        })
        .collect();
    let delivered = sent.iter().all(|r| r.is_ok());
    let stopped = EStopped {
        delivered,
        confirmed_ms: delivered.then(|| sent.iter().filter_map(ms).fold(0.0, f64::max)),
        sites: sites_stopped,
    };
    latch.answered(number, serde_json::to_value(&stopped).unwrap_or_default());
    let failed: Vec<String> = links
        .iter()
        .zip(&sent)
        .filter_map(|(l, r)| {
            r.as_ref()
                .err()
                .map(|why| format!("site {:?}: {why}", l.site()))
        })
        .collect();
    if !failed.is_empty() {
        return Err(AppError::Unavailable(format!(
            "the E-stop was NOT confirmed by the controller ({}); stop the machine by hand",
            failed.join("; ")
        )));
    }
    Ok(Stopped {
        sites: links.iter().map(|l| l.site().to_string()).collect(),
        slowest: sent
            .into_iter()
            .filter_map(|r| r.ok())
            .max()
            .unwrap_or_default(),
        latch_not_kept: kept.err().map(|e| e.to_string()),
    })
}

/// How long the API waits for the controller to confirm an E-stop before saying it was not
/// delivered.
const ESTOP_CONFIRMATION: std::time::Duration = std::time::Duration::from_millis(500);

/// How long a reset waits for the presses before it to reach the audit log.
const RESET_WAITS_FOR_PRESSES: std::time::Duration = std::time::Duration::from_secs(10);

/// Clears the E-stop latch of one site, or of every site (and each site's own): once every
/// press before it is in the audit log, the store's rows and the reset's audit row first,
/// then the server's latch (so a controller that connects meanwhile is told latched), then
/// the controllers'. A site stays stopped while the E-stop of every site is latched: that one
/// is reset for every site at once.
pub async fn reset_estop(
    pool: &AnyPool,
    sites: &Sites,
    actor: &str,
    site: Option<&str>,
) -> Result<()> {
    let links: Vec<&ControllerLink> = match site {
        Some(name) => vec![sites.named(name)?],
        None => sites.all().iter().collect(),
    };
    let latch = sites.latch();
    if let Some(name) = site
        && latch.all_latched()
    {
        return Err(AppError::Conflict(format!(
            "the E-stop of every site is latched: reset it for every site (POST /api/estop/reset without a site), not for site {name:?} alone"
        )));
    }
    latch.recorded(RESET_WAITS_FOR_PRESSES).await?;
    let mut change = Change::begin(pool, actor).await?;
    match site {
        Some(name) => store::latch::set_site(change.db(), name, false).await?,
        None => store::latch::set_all(change.db(), false).await?,
    }
    change
        .commit("estop.reset", Some(estop_latch::target(site)), NoDetail {})
        .await?;
    latch.clear(site).await.map_err(|e| {
        AppError::Internal(anyhow::anyhow!(
            "the reset is recorded but the E-stop latch file could not be written ({e}): the latch holds after a restart"
        ))
    })?;
    let mut unreached = Vec::new();
    for link in links {
        match link.send(&ServerToController::ResetEStop {}) {
            // The controller's status confirms the cleared latch.
            Ok(()) => drop(link.send(&ServerToController::Status {})),
            Err(why) => unreached.push(format!("site {:?}: {why}", link.site())),
        }
    }
    if unreached.is_empty() {
        Ok(())
    } else {
        Err(AppError::Unavailable(unreached.join("; ")))
    }
}
