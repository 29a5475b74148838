//! A background job of which one runs at a time (the dashboard's pilot, a power plan): its
//! progress while it runs and its outcome after, for the dashboard to poll.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use crate::error::{AppError, Result};

/// How far a job is (steps done so far, of how many).
#[derive(Debug, Default)]
pub struct Progress {
    pub done: AtomicUsize,
    pub total: AtomicUsize,
}

impl Progress {
    pub fn add(&self, steps: usize) {
        self.done.fetch_add(steps, Ordering::Relaxed);
    }
}

#[derive(Debug)]
pub struct Job<R> {
    run: Mutex<Option<Run<R>>>,
}

impl<R> Default for Job<R> {
    fn default() -> Self {
        Self {
            run: Mutex::new(None),
        }
    }
}

#[derive(Debug, Clone)]
struct Run<R> {
    study_id: i64,
    progress: Arc<Progress>,
    /// None while running; then Ok(report) or Err(message).
    outcome: Option<std::result::Result<R, String>>,
}

/// Where a job stands: running or not, for which study, how far (steps done of how many),
/// and how it ended (its report or the error).
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct JobStatus<R> {
    pub running: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub study_id: Option<i64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub done: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub total: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub report: Option<R>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl<R: Clone> Job<R> {
    fn run(&self) -> MutexGuard<'_, Option<Run<R>>> {
        self.run.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Claims the job for `study_id`; refused while one is running (`what` names it).
    pub fn begin(&self, study_id: i64, what: &str) -> Result<Arc<Progress>> {
        let mut run = self.run();
        if run.as_ref().is_some_and(|r| r.outcome.is_none()) {
            return Err(AppError::Conflict(format!("{what} is already in progress")));
        }
        let progress = Arc::new(Progress::default());
        *run = Some(Run {
            study_id,
            progress: progress.clone(),
            outcome: None,
        });
        Ok(progress)
    }

    /// Claims the job for `study_id` (refused while one is running) and runs `work` in the
    /// background; `work` is handed the progress to count its steps in.
    pub fn spawn<F, Fut>(self: &Arc<Self>, study_id: i64, what: &str, work: F) -> Result<()>
    where
        R: Send + 'static,
        F: FnOnce(Arc<Progress>) -> Fut,
        Fut: std::future::Future<Output = std::result::Result<R, String>> + Send + 'static,
    {
        let running = work(self.begin(study_id, what)?);
        let job = Arc::clone(self);
        tokio::spawn(async move {
            let outcome = running.await;
            job.finish(outcome);
        });
        Ok(())
    }

    fn finish(&self, outcome: std::result::Result<R, String>) {
        if let Some(run) = self.run().as_mut() {
            run.outcome = Some(outcome);
        }
    }

    pub fn status(&self) -> JobStatus<R> {
        match self.run().clone() {
            None => JobStatus {
                running: false,
                study_id: None,
                done: None,
                total: None,
                report: None,
                error: None,
            },
            Some(r) => JobStatus {
                running: r.outcome.is_none(),
                study_id: Some(r.study_id),
                done: Some(r.progress.done.load(Ordering::Relaxed)),
                total: Some(r.progress.total.load(Ordering::Relaxed)),
                report: r.outcome.as_ref().and_then(|o| o.as_ref().ok()).cloned(),
                error: r.outcome.as_ref().and_then(|o| o.as_ref().err()).cloned(),
            },
        }
    }
}
