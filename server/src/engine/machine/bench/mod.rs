//! Bench runs: compensators (named designs or configuration versions) driven by one
//! reference signal with no operator (`InputSource::Reference`), one run at a time with
//! progress. On the simulated rig in-process, faster than real time
//! (`runtime::local::run`, the real-time loop's slot code, off the async threads); on a
//! real-rig study through the controller link in real time, with the study's interlock
//! limit, the E-stop ending it. Each result is stored with the metrics of its 1 kHz record
//! and the record decimated. The table's reductions compare each compensated design with
//! its uncompensated twin.
//!
//! `request`: what a run asks for and its checks; `view`: a run's results read back with
//! their reductions. The run's CSV is an export (`results::export::bench`).

mod request;
mod view;

pub use request::{BenchChoice, BenchRequest, BenchSignal, parse_csv};
use request::{Resolved, resolve, target};
pub use view::{ResultView, RunView, Trace, twin, view, with_reductions};

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use bdft_controller::rng::Rng;
use bdft_protocol::params::Seat;
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::study::RigKind;
use bdft_protocol::trial::{InputSource, Metrics, Outcome, TargetSpec};
use serde::Serialize;
use sqlx::AnyPool;
use utoipa::ToSchema;

use super::controller_link::ControllerLink;
use crate::engine::study::schedule::default_params;
use crate::error::{AppError, Result};
use crate::store::bench::{NewResult, NewRun};
use crate::store::{self, Change};

/// Loop sample period of a simulated run (the controller's).
pub const DT: f64 = 1e-3;
/// The stored trace keeps every 10th tick: 100 Hz, enough to draw up to the 8 Hz top of the
/// swept sine; the metrics come from the full 1 kHz record.
pub const DECIMATION: usize = 10;
/// Most compensators in one run.
pub const MAX_COMPENSATORS: usize = 8;
/// Longest bench run (s): bounds the record a run holds (8 × 300 s × 9 channels × 4 B ≈ 86 MB
/// at most, one compensator at a time: 11 MB).
pub const MAX_DURATION_S: f64 = 300.0;
/// The channels a stored trace keeps, from `RECORD_CHANNELS`.
pub const TRACE_CHANNELS: [&str; 3] = ["target_mm", "cyl_pos_mm", "cab_accel_mm_s2"];
/// The simulated bench has nobody in the cab, so its interlock limit is the highest a trial
/// may carry (as `simulate` runs bench signals without one).
const NO_PERSON_CAB_RMS: f64 = 1e6;

/// What `bench.start` records: the run's compensators (labels), signal and study.
#[derive(Debug, Serialize)]
struct Started<'a> {
    compensators: Vec<&'a str>,
    signal: &'static str,
    duration_s: f64,
    seed: u64,
    study_id: Option<i64>,
    /// The site whose machine runs it (on the real rig).
    site: Option<&'a str>,
    /// The machine's condition.
    condition: &'a str,
}

/// What `bench.finish` and `bench.fail` record: why the run failed (null: it did not).
#[derive(Debug, Serialize)]
struct Ended<'a> {
    error: Option<&'a str>,
}

/// What `bench.fail` records when a restart ended the runs that were going.
#[derive(Debug, Serialize)]
struct Abandoned {
    runs: u64,
    error: &'static str,
}

/// What `bench.result` records: a compensator's outcome and metrics in its run.
#[derive(Debug, Serialize)]
struct Measured<'a> {
    run_id: i64,
    label: &'a str,
    outcome: &'a str,
    metrics: Metrics,
}

/// The one bench run the server may have going, and how far it is.
#[derive(Debug, Default)]
pub struct BenchJob {
    running: AtomicBool,
    run_id: std::sync::atomic::AtomicI64,
    done: AtomicUsize,
    total: AtomicUsize,
}

/// Where the bench stands.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct BenchStatus {
    pub running: bool,
    /// The run going now, or the last one started.
    pub run_id: Option<i64>,
    /// Compensators run so far, of `total`.
    pub done: usize,
    pub total: usize,
}

/// Releases the one-run guard however the run ends.
struct Running(Arc<BenchJob>);

impl Drop for Running {
    fn drop(&mut self) {
        self.0.running.store(false, Ordering::SeqCst);
    }
}

impl BenchJob {
    pub fn status(&self) -> BenchStatus {
        let run_id = self.run_id.load(Ordering::SeqCst);
        BenchStatus {
            running: self.running.load(Ordering::SeqCst),
            run_id: (run_id > 0).then_some(run_id),
            done: self.done.load(Ordering::SeqCst),
            total: self.total.load(Ordering::SeqCst),
        }
    }

    /// Checks `req` and starts the run in the background; returns its id. Refused while
    /// another runs; on a study with the real rig, refused unless the rig can take it.
    pub async fn start(
        self: &Arc<Self>,
        pool: &AnyPool,
        link: &ControllerLink,
        actor: &str,
        req: &BenchRequest,
    ) -> Result<i64> {
        let study = match req.study_id {
            Some(id) => Some(store::studies::get(pool, id).await?),
            None => None,
        };
        let params = study
            .as_ref()
            .map_or_else(default_params, |s| s.params.clone());
        let seed = req.seed.unwrap_or(1);
        if seed >= 1 << 53 {
            return Err(AppError::BadRequest(
                "seed: a whole number below 2^53".into(),
            ));
        }
        let (target, duration_s) = target(req, seed)?;
        let condition = req.condition.unwrap_or(params.condition);
        let signal = signal_kind(&target)?;
        let compensators = resolve(pool, &req.compensators, &params.plant).await?;
        let starts: Vec<StartTrial> = compensators
            .iter()
            .enumerate()
            .map(|(i, c)| StartTrial {
                trial_id: BENCH_TRIAL_IDS + i as u64,
                compensator: c.spec.clone(),
                // The reference drives the cylinder directly: no operator, no feedthrough.
                seat: Seat::Off,
                k_bf: params.k_bf,
                target: target.clone(),
                duration_s,
                input: InputSource::Reference,
                plant: params.plant,
                body: params.body,
                noise_seed: Rng::derive(seed, Rng::ACCEL_NOISE).next_u64(),
                live_rate_hz: 100.0,
                stale_input_ms: params.stale_input_ms,
                max_cab_rms_mm_s2: match params.rig {
                    RigKind::Simulated => NO_PERSON_CAB_RMS,
                    // The machine's own interlock limit, as for the study's trials.
                    RigKind::Real => params.max_cab_rms_mm_s2,
                },
                // No person rides a bench run.
                exposure_allowance: None,
                cancellation: None,
                condition,
            })
            .collect();
        for s in &starts {
            s.validate()?;
        }
        let rig = match params.rig {
            RigKind::Simulated => Rig::Sim,
            RigKind::Real => {
                check_real_rig(link)?;
                Rig::Real(link.clone())
            }
        };
        if self.running.swap(true, Ordering::SeqCst) {
            return Err(AppError::Conflict(
                "a bench run is already in progress; wait for it to finish".into(),
            ));
        }
        let guard = Running(Arc::clone(self));
        let signal_json = serde_json::to_string(&target).expect("targets serialize");
        let condition = condition.to_string();
        let mut change = Change::begin(pool, actor).await?;
        let run_id = store::bench::insert_run(
            change.db(),
            &NewRun {
                study_id: req.study_id,
                rig: rig.name(),
                signal_json: &signal_json,
                duration_s,
                seed,
                created_by: actor,
                site: rig.site(),
                condition: &condition,
            },
        )
        .await?;
        change
            .commit(
                "bench.start",
                Some(format!("bench_run:{run_id}")),
                Started {
                    compensators: compensators.iter().map(|c| c.label.as_str()).collect(),
                    signal,
                    duration_s,
                    seed,
                    study_id: req.study_id,
                    site: rig.site(),
                    condition: &condition,
                },
            )
            .await?;
        self.run_id.store(run_id, Ordering::SeqCst);
        self.done.store(0, Ordering::SeqCst);
        self.total.store(starts.len(), Ordering::SeqCst);
        let (pool, actor) = (pool.clone(), actor.to_string());
        tokio::spawn(async move {
            let outcome =
                run_all(&pool, &actor, run_id, &rig, &compensators, starts, &guard.0).await;
            let error = outcome.as_ref().err().map(|e| format!("{e:#}"));
            let ended = async {
                let mut change = Change::begin(&pool, actor.as_str()).await?;
                store::bench::finish(change.db(), run_id, error.as_deref()).await?;
                change
                    .commit(
                        if error.is_some() {
                            "bench.fail"
                        } else {
                            "bench.finish"
                        },
                        Some(format!("bench_run:{run_id}")),
                        Ended {
                            error: error.as_deref(),
                        },
                    )
                    .await
            };
            if let Err(e) = ended.await {
                tracing::error!("bench run {run_id} could not be filed: {e}");
            }
            drop(guard);
        });
        Ok(run_id)
    }
}

/// Why the runs a restart found going failed.
const RESTART: &str = "server restart";

/// Runs the server left running when it stopped are failed (audited), so none shows as
/// running forever.
pub async fn fail_interrupted(pool: &AnyPool) -> Result<()> {
    let mut change = Change::begin(pool, "system:startup").await?;
    let n = store::bench::fail_unfinished(change.db(), RESTART).await?;
    if n > 0 {
        change
            .commit(
                "bench.fail",
                None,
                Abandoned {
                    runs: n,
                    error: RESTART,
                },
            )
            .await?;
    }
    Ok(())
}

/// Where a run's compensators run.
#[derive(Debug)]
enum Rig {
    /// In this process, faster than real time.
    Sim,
    /// On the machine through the controller link, in real time, with its interlocks.
    Real(ControllerLink),
}

impl Rig {
    fn name(&self) -> &'static str {
        match self {
            Self::Sim => "sim",
            Self::Real(_) => "real",
        }
    }

    /// The site whose machine a run on the real rig uses.
    fn site(&self) -> Option<&str> {
        match self {
            Self::Sim => None,
            Self::Real(link) => Some(link.site()),
        }
    }
}

/// A bench trial's id on the controller link: far above any row of `trials`, so its result
/// comes back to the bench and is never filed as a study's trial.
const BENCH_TRIAL_IDS: u64 = 1 << 50;

/// A bench run on the real rig needs the E-stop reset and a controller with a real rig.
fn check_real_rig(link: &ControllerLink) -> Result<()> {
    if link.stopped() {
        return Err(AppError::Conflict(
            "the E-stop is latched: reset it before a bench run on the real rig".into(),
        ));
    }
    if !link.is_connected() {
        return Err(AppError::Unavailable(
            "the controller is not connected: a bench run on the real rig needs it".into(),
        ));
    }
    if link.rig().as_deref() != Some("udp") {
        return Err(AppError::Conflict(format!(
            "the study runs on the real rig but the controller's rig is {}: no real rig is connected",
            link.rig().unwrap_or_else(|| "unknown".into())
        )));
    }
    Ok(())
}

/// The bench signal a target is; an identification test is no bench signal (it needs a
/// person on the seat and runs from a study's schedule), so a bench run refuses it.
fn signal_kind(t: &TargetSpec) -> Result<&'static str> {
    Ok(match t {
        TargetSpec::Steps { .. } => "steps",
        TargetSpec::SweptSine { .. } => "swept-sine",
        TargetSpec::Trapezoid { .. } => "trapezoid",
        TargetSpec::Sampled { .. } => "csv",
        TargetSpec::Identification { .. } => {
            return Err(AppError::BadRequest(
                "target.kind: identification is not a bench signal; allowed: steps, \
                 swept-sine, trapezoid, csv"
                    .into(),
            ));
        }
    })
}

/// Runs each compensator in turn off the async threads and stores its result.
async fn run_all(
    pool: &AnyPool,
    actor: &str,
    run_id: i64,
    rig: &Rig,
    compensators: &[Resolved],
    starts: Vec<StartTrial>,
    job: &BenchJob,
) -> anyhow::Result<()> {
    for (i, (c, mut start)) in compensators.iter().zip(starts).enumerate() {
        let (result, channels) = match rig {
            Rig::Sim => tokio::task::spawn_blocking(move || {
                bdft_controller::runtime::local::run(&start, DT)
            })
            .await?
            .map_err(anyhow::Error::msg)?,
            Rig::Real(link) => {
                // After an E-stop nothing more starts (the controller would refuse it too).
                if link.stopped() {
                    anyhow::bail!("stopped: the E-stop is latched");
                }
                start.trial_id += run_id as u64 * MAX_COMPENSATORS as u64;
                let (r, record) = link
                    .run_bench_trial(&start)
                    .await
                    .map_err(anyhow::Error::msg)?;
                (r, record.channels)
            }
        };
        let trace = store::json_text(&Trace::decimated(&channels, result.dt))?;
        let outcome = match &result.outcome {
            Outcome::Complete => "complete".to_string(),
            Outcome::Aborted { reason } => format!("aborted: {reason}"),
            Outcome::Faulted { message, .. } => format!("faulted: {message}"),
        };
        let spec_json = store::configs::spec_text(&c.spec);
        let m = result.metrics;
        let mut change = Change::begin(pool, actor).await?;
        let result_id = store::bench::insert_result(
            change.db(),
            run_id,
            &NewResult {
                position: i as i64,
                label: &c.label,
                kind: c.spec.kind(),
                config_id: c.config_id,
                spec_json: &spec_json,
                outcome: &outcome,
                ticks: m.ticks,
                mse_tracking_mm2: m.mse_tracking_mm2,
                ms_cab_accel: m.ms_cab_accel,
                decimation: DECIMATION as u32,
                trace_json: &trace,
            },
        )
        .await?;
        change
            .commit(
                "bench.result",
                Some(format!("bench_result:{result_id}")),
                Measured {
                    run_id,
                    label: &c.label,
                    outcome: &outcome,
                    metrics: m,
                },
            )
            .await?;
        job.done.fetch_add(1, Ordering::SeqCst);
    }
    Ok(())
}
