//! `bdft-server pilot`: the whole protocol for N synthetic subjects, faster than real time,
//! through the same enrolment, scheduling, trial and commit code as a live study. Lets a lab
//! dry-run its protocol and plan the sample size before the first person sits down.

use std::sync::Arc;

use anyhow::Context;
use sqlx::AnyPool;

use bdft_protocol::records::ConsentDecision;
use serde::Serialize;

use super::job::{Job, JobStatus, Progress};
use crate::engine::procedure::enrolment::enrol;
use crate::engine::procedure::filing::file_result;
use crate::engine::procedure::orchestrator::{Operator, start_now};
use crate::engine::procedure::stations::consent_form;
use crate::engine::study::schedule::default_params;
use crate::store::audit::NoDetail;
use crate::store::records::Record;
use crate::store::{self, Change};

/// Who the audit log names for starting a pilot from the command line.
pub const COMMAND_LINE: &str = "system:pilot-command";

/// What `pilot.process` records: the process that runs the pilot.
#[derive(Debug, Serialize)]
struct Process {
    pid: u32,
}

/// What `pilot.start` records: how many synthetic subjects.
#[derive(Debug, Serialize)]
struct Started {
    subjects: u32,
}

/// What a synthetic subject's `consent` records: always agreed, and synthetic.
#[derive(Debug, Serialize)]
struct SyntheticConsent {
    decision: ConsentDecision,
    synthetic: bool,
}

#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct PilotReport {
    /// The dry run the pilot ran in (never a study with people).
    pub study_id: i64,
    pub subjects: Vec<String>,
    pub trials: usize,
    pub complete: usize,
}

/// Loop sample period of the simulated trials.
const DT: f64 = 1e-3;

/// How often a pilot process tells the database it is alive.
pub const BEAT: std::time::Duration = std::time::Duration::from_secs(1);

/// A stand-alone dry run of `params` for a pilot from the command line (e.g. a population
/// other than the default, whose pilot makes data to calibrate against); only into a
/// database with no study yet, so the pilot's "newest study" stays unambiguous.
pub async fn new_study(
    pool: &AnyPool,
    params: &bdft_protocol::study::StudyParams,
    seed: Option<u64>,
) -> anyhow::Result<i64> {
    if let Some(s) = store::studies::all(pool).await?.first() {
        anyhow::bail!(
            "--params: the database already has study {}; a pilot with its own parameters needs a database without studies",
            s.id
        );
    }
    Ok(crate::engine::study::dry_run::create(pool, COMMAND_LINE, params, seed).await?)
}

/// Runs the pilot into `study_id` (default: the newest study, or a new default study if
/// there is none) as a process of its own (`bdft-server pilot`). `seed` seeds a newly
/// created study. The run beats while it works, so a server can tell when this process was
/// killed and file the trials it left running; if it fails, it files them itself.
pub async fn run(
    pool: &AnyPool,
    study_id: Option<i64>,
    subjects: u32,
    seed: Option<u64>,
) -> anyhow::Result<PilotReport> {
    // An earlier pilot process that was killed: its trials are filed before this one starts.
    crate::engine::procedure::filing::end_lost_pilots(pool).await?;
    let mut change = Change::begin(pool, COMMAND_LINE).await?;
    let run_id = store::pilot_runs::start(change.db(), std::process::id()).await?;
    change
        .commit(
            "pilot.process",
            Some(format!("pilot_run:{run_id}")),
            Process {
                pid: std::process::id(),
            },
        )
        .await?;
    let beating = {
        let pool = pool.clone();
        crate::engine::beat_every(BEAT, "pilot", move || {
            let pool = pool.clone();
            async move { store::pilot_runs::beat(&pool, run_id).await }
        })
    };
    let outcome = run_with_progress(
        pool,
        COMMAND_LINE,
        study_id,
        subjects,
        seed,
        Arc::new(Progress::default()),
        Some(run_id),
    )
    .await;
    beating.abort();
    let reason = match &outcome {
        Ok(_) => "pilot finished".to_string(),
        Err(e) => format!("pilot failed: {e:#}"),
    };
    crate::engine::procedure::filing::end_pilot_run(pool, run_id, &reason).await?;
    outcome
}

/// `run` on behalf of `requested_by` (who the audit log names for starting it), counting
/// finished trials in `progress` (the dashboard's progress bar). A pilot process passes its
/// `run_id` (`pilot_runs`), so each trial it starts is known to be its own.
pub async fn run_with_progress(
    pool: &AnyPool,
    requested_by: &str,
    study_id: Option<i64>,
    subjects: u32,
    seed: Option<u64>,
    progress: Arc<Progress>,
    run_id: Option<i64>,
) -> anyhow::Result<PilotReport> {
    // The audit log names the pilot's own actions with who started it.
    let actor = format!("pilot (by {requested_by})");
    // A pilot never writes into a study with people: it runs in the study's dry-run copy.
    let study_id = match study_id {
        Some(id) => crate::engine::study::dry_run::for_pilot(pool, requested_by, id)
            .await
            .with_context(|| format!("study {id}"))?,
        None => match store::studies::all(pool).await?.last() {
            Some(s) => crate::engine::study::dry_run::for_pilot(pool, requested_by, s.id).await?,
            None => {
                crate::engine::study::dry_run::create(pool, &actor, &default_params(), seed).await?
            }
        },
    };
    let study = Arc::new(store::studies::get(pool, study_id).await?);
    let stability = crate::engine::study::stability::StabilityCache::default();
    Change::begin(pool, requested_by)
        .await?
        .commit(
            "pilot.start",
            Some(format!("study:{study_id}")),
            Started { subjects },
        )
        .await?;
    let mut report = PilotReport {
        study_id,
        subjects: Vec::new(),
        trials: 0,
        complete: 0,
    };
    // The form the lock renders from these parameters: what a person would agree to.
    let consent_sha256 = bdft_protocol::hex::sha256(consent_form(&study).text.as_bytes());
    let mut work = Vec::new();
    for _ in 0..subjects {
        let (subject, _) = enrol(pool, &stability, &actor, study_id, true).await?;
        let mut change = Change::begin(pool, actor.as_str()).await?;
        store::subjects::record_consent(
            change.db(),
            subject.id,
            &format!("{} (synthetic)", study.params.consent.version),
            &consent_sha256,
            ConsentDecision::Agreed,
        )
        .await?;
        change
            .commit(
                "consent",
                Some(format!("subject:{}", subject.id)),
                SyntheticConsent {
                    decision: ConsentDecision::Agreed,
                    synthetic: true,
                },
            )
            .await?;
        report.subjects.push(subject.code.clone());
        work.push(subject.id);
    }
    let per_subject = crate::engine::study::schedule::schedule(&study.params, study.seed, 0).len();
    progress.total.store(
        per_subject * work.len(),
        std::sync::atomic::Ordering::Relaxed,
    );
    // One worker per core; each takes a subject and runs its tests in schedule order.
    let queue = Arc::new(tokio::sync::Mutex::new(work));
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .max(1);
    let mut tasks = tokio::task::JoinSet::new();
    for _ in 0..workers {
        let (pool, study, queue, progress, actor) = (
            pool.clone(),
            Arc::clone(&study),
            Arc::clone(&queue),
            Arc::clone(&progress),
            actor.clone(),
        );
        tasks.spawn(async move {
            let mut done = (0, 0);
            loop {
                let Some(subject_id) = queue.lock().await.pop() else {
                    return anyhow::Ok(done);
                };
                let subject = store::subjects::get(&pool, subject_id).await?;
                while let Some(trial) = store::trials::next(&pool, subject_id).await? {
                    let mut change = Change::begin(&pool, actor.as_str()).await?;
                    // The same budget as a person's: a pilot shows whether the tests fit it.
                    let start = start_now(
                        change.db(),
                        &study,
                        &trial,
                        &subject,
                        Operator::Synthetic(subject.drawn),
                    )
                    .await?;
                    // A dry run's own simulated controller is no site's machine.
                    store::trials::mark_running(change.db(), trial.id, None).await?;
                    if let Some(run_id) = run_id {
                        store::pilot_runs::claim(change.db(), run_id, trial.id).await?;
                    }
                    change
                        .commit(
                            "trial.start",
                            Some(format!("trial:{}", trial.id)),
                            NoDetail {},
                        )
                        .await?;
                    let (result, channels) = tokio::task::spawn_blocking(move || {
                        bdft_controller::runtime::local::run(&start, DT)
                    })
                    .await?
                    .map_err(anyhow::Error::msg)?;
                    let record = Record { dt: DT, channels };
                    file_result(&pool, &actor, &result, &record).await?;
                    // The subject answers the survey of each completed test, as a person
                    // would, from what it perceived.
                    crate::engine::study::synthetic::answer_survey(
                        &pool, &actor, &study, &subject, &trial, &record,
                    )
                    .await?;
                    done.0 += 1;
                    progress.add(1);
                    if result.outcome == bdft_protocol::trial::Outcome::Complete {
                        done.1 += 1;
                    }
                }
            }
        });
    }
    while let Some(r) = tasks.join_next().await {
        let (t, c) = r??;
        report.trials += t;
        report.complete += c;
    }
    Change::begin(pool, actor)
        .await?
        .commit("pilot.finish", Some(format!("study:{study_id}")), &report)
        .await?;
    Ok(report)
}

/// The one pilot run the dashboard may have going, with its progress and outcome.
#[derive(Debug, Default)]
pub struct PilotJob {
    job: Arc<Job<PilotReport>>,
}

/// Where the dashboard's pilot run stands.
pub type PilotStatus = JobStatus<PilotReport>;

impl PilotJob {
    /// Starts a pilot of `subjects` synthetic subjects into `study_id` in the background;
    /// refused while another runs.
    pub async fn start(
        &self,
        pool: &AnyPool,
        actor: &str,
        study_id: i64,
        subjects: u32,
    ) -> crate::error::Result<()> {
        use crate::error::AppError;
        if !(1..=50).contains(&subjects) {
            return Err(AppError::BadRequest("subjects: 1 to 50".into()));
        }
        // Resolved now, so the dashboard names the dry run the data goes to.
        let study_id = crate::engine::study::dry_run::for_pilot(pool, actor, study_id).await?;
        let (pool, actor) = (pool.clone(), actor.to_string());
        self.job
            .spawn(study_id, "a pilot run", move |progress| async move {
                // In the server's own process: it files the trials when it restarts.
                run_with_progress(
                    &pool,
                    &actor,
                    Some(study_id),
                    subjects,
                    None,
                    progress,
                    None,
                )
                .await
                .map_err(|e| format!("{e:#}"))
            })
    }

    pub fn status(&self) -> PilotStatus {
        self.job.status()
    }
}
