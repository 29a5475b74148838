//! `bdft-server pilot`: the whole protocol for N synthetic subjects, faster than real time,
//! through the same enrolment, scheduling, trial and commit code as a live study. Lets a lab
//! dry-run its protocol and plan the sample size before the first person sits down.

use std::sync::Arc;

use anyhow::Context;
use sqlx::SqlitePool;

use crate::orchestrator::{Operator, start_message};
use crate::store::{self, Record};
use crate::study::default_params;

#[derive(Debug, Clone, serde::Serialize)]
pub struct PilotReport {
    pub study_id: i64,
    pub subjects: Vec<String>,
    pub trials: usize,
    pub complete: usize,
}

/// Loop sample period of the simulated trials.
const DT: f64 = 1e-3;

/// Runs the pilot into `study_id` (default: the newest study, or a new default study if
/// there is none). `seed` seeds a newly created study.
/// How far a running pilot is (trials run so far, of how many).
#[derive(Debug, Default)]
pub struct Progress {
    pub done: std::sync::atomic::AtomicUsize,
    pub total: std::sync::atomic::AtomicUsize,
}

pub async fn run(
    pool: &SqlitePool,
    study_id: Option<i64>,
    subjects: u32,
    seed: Option<u64>,
) -> anyhow::Result<PilotReport> {
    run_with_progress(
        pool,
        study_id,
        subjects,
        seed,
        Arc::new(Progress::default()),
    )
    .await
}

/// `run`, counting finished trials in `progress` (the dashboard's progress bar).
pub async fn run_with_progress(
    pool: &SqlitePool,
    study_id: Option<i64>,
    subjects: u32,
    seed: Option<u64>,
    progress: Arc<Progress>,
) -> anyhow::Result<PilotReport> {
    let study_id = match study_id {
        Some(id) => {
            store::study(pool, id)
                .await
                .with_context(|| format!("study {id}"))?
                .id
        }
        None => match store::studies(pool).await?.last() {
            Some(s) => s.id,
            None => {
                store::create_study(
                    pool,
                    "Pilot (default protocol)",
                    &default_params(),
                    seed.unwrap_or_else(crate::db::random_seed),
                )
                .await?
            }
        },
    };
    let study = Arc::new(store::study(pool, study_id).await?);
    store::audit(
        pool,
        "pilot",
        "pilot.start",
        Some(format!("study:{study_id}")),
        serde_json::json!({ "subjects": subjects }),
    )
    .await?;
    let mut report = PilotReport {
        study_id,
        subjects: Vec::new(),
        trials: 0,
        complete: 0,
    };
    let mut work = Vec::new();
    for _ in 0..subjects {
        let (subject, _) = store::enrol(pool, study_id, true).await?;
        sqlx::query("UPDATE subjects SET consent_version = ?, consent_decision = 'agreed', consent_at = ? WHERE id = ?")
            .bind(format!("{} (synthetic)", study.params.consent.version))
            .bind(crate::db::now_ms())
            .bind(subject.id)
            .execute(pool)
            .await?;
        report.subjects.push(subject.code.clone());
        work.push(subject.id);
    }
    let per_subject = crate::study::schedule(&study.params, study.seed, 0).len();
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
        let (pool, study, queue, progress) = (
            pool.clone(),
            Arc::clone(&study),
            Arc::clone(&queue),
            Arc::clone(&progress),
        );
        tasks.spawn(async move {
            let mut done = (0, 0);
            loop {
                let Some(subject_id) = queue.lock().await.pop() else {
                    return anyhow::Ok(done);
                };
                while let Some(trial) = store::next_trial(&pool, subject_id).await? {
                    store::mark_running(&pool, trial.id).await?;
                    let start = start_message(&study, &trial, Operator::Synthetic)?;
                    let (result, channels) = tokio::task::spawn_blocking(move || {
                        bdft_controller::runtime::local::run(&start, DT)
                    })
                    .await?
                    .map_err(anyhow::Error::msg)?;
                    store::commit_result(&pool, &result, &Record { dt: DT, channels }).await?;
                    done.0 += 1;
                    progress
                        .done
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
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
    store::audit(
        pool,
        "pilot",
        "pilot.finish",
        Some(format!("study:{study_id}")),
        serde_json::to_value(&report)?,
    )
    .await?;
    Ok(report)
}
