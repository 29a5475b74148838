//! Bench runs: compensators (named designs or configuration versions) driven by one
//! reference signal with no operator (`InputSource::Reference`), one run at a time with
//! progress. On the simulated rig in-process, faster than real time
//! (`runtime::local::run`, the real-time loop's slot code, off the async threads); on a
//! real-rig study through the controller link in real time, with the study's interlock
//! limit, the E-stop ending it. Each result is stored with the metrics of its 1 kHz record
//! and the record decimated. The table's reductions compare each compensated design with
//! its uncompensated twin.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use bdft_controller::compensator::variants;
use bdft_controller::rng::Rng;
use bdft_controller::signals::{StepParams, StepTarget, SweptSine, Trapezoid};
use bdft_protocol::params::{CompensatorKind, CompensatorSpec, Seat};
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::study::RigKind;
use bdft_protocol::trial::{InputSource, MAX_SAMPLES, Outcome, TargetSpec, record_channel};
use serde::{Deserialize, Serialize};
use serde_json::json;
use sqlx::SqlitePool;
use utoipa::ToSchema;

use super::controller_link::ControllerLink;
use super::schedule::default_params;
use crate::error::{AppError, Result};
use crate::store::bench::{BenchResult, BenchRun, NewResult, NewRun};
use crate::store::{self, Change};

/// Loop sample period of a simulated run (the controller's).
const DT: f64 = 1e-3;
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

/// The uncompensated design a compensated one is measured against: PID for the notch and the
/// shaper, LQR for the cab-velocity and cab-acceleration feedback; none for PID and LQR.
pub fn twin(kind: CompensatorKind) -> Option<CompensatorKind> {
    match kind {
        CompensatorKind::Pid | CompensatorKind::Lqr => None,
        CompensatorKind::PidNotch | CompensatorKind::PidShaper => Some(CompensatorKind::Pid),
        CompensatorKind::LqrCabvel | CompensatorKind::LqrCabacc => Some(CompensatorKind::Lqr),
    }
}

/// One compensator of a run: a design name (`pid`, `pid-shaper:zvd`, … as `robustness`
/// takes them) or a configuration version.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BenchChoice {
    pub design: Option<String>,
    pub config_id: Option<i64>,
}

/// The reference signal: the rig's bench signals as `simulate` runs them (swept sine
/// 0.01→8 Hz at 5 mm, trapezoid ±25 mm over 6 s), the protocol's random steps (seeded), or
/// an uploaded CSV: one column of mm, one line per sample at `sample_rate_hz` (a first line
/// starting with a letter is a header).
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum BenchSignal {
    SweptSine,
    Trapezoid,
    Steps,
    Csv { sample_rate_hz: f64, csv: String },
}

/// What to run.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BenchRequest {
    /// The study whose rig (simulated or real), plant and body the run uses (default: the
    /// published parameters on the simulated rig).
    pub study_id: Option<i64>,
    /// 1 to 8.
    pub compensators: Vec<BenchChoice>,
    pub signal: BenchSignal,
    /// Seconds, 1 to 300 [default: 30, 140 for steps, the upload's length for a CSV].
    pub duration_s: Option<f64>,
    /// Seed of the accelerometer noise (and of the steps) [default 1, as `simulate`].
    pub seed: Option<u64>,
}

/// Parses an uploaded reference; a 422 names the line and the problem.
pub fn parse_csv(text: &str) -> Result<Vec<f64>> {
    let mut samples = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let cell = line.trim();
        if cell.is_empty() {
            continue;
        }
        if n == 1 && cell.starts_with(|c: char| c.is_ascii_alphabetic()) {
            continue;
        }
        let bad = |what: String| AppError::BadRequest(format!("signal.csv line {n}: {what}"));
        if cell.contains([',', ';', '\t']) {
            return Err(bad(format!(
                "{cell:?} has more than one column; one column of mm is allowed"
            )));
        }
        let x: f64 = cell
            .parse()
            .map_err(|_| bad(format!("{cell:?} is not a number (mm)")))?;
        if !x.is_finite() || x.abs() > 1000.0 {
            return Err(bad(format!(
                "{cell} mm is outside the allowed −1000 to 1000 mm"
            )));
        }
        if samples.len() == MAX_SAMPLES {
            return Err(bad(format!("more than {MAX_SAMPLES} samples")));
        }
        samples.push(x);
    }
    if samples.len() < 2 {
        return Err(AppError::BadRequest(format!(
            "signal.csv: {} samples; at least 2 are needed",
            samples.len()
        )));
    }
    Ok(samples)
}

/// The run's target and its length.
fn target(req: &BenchRequest, seed: u64) -> Result<(TargetSpec, f64)> {
    let duration = |default: f64| {
        let d = req.duration_s.unwrap_or(default);
        if !(1.0..=MAX_DURATION_S).contains(&d) {
            return Err(AppError::BadRequest(format!(
                "duration_s: 1 to {MAX_DURATION_S} s"
            )));
        }
        Ok(d)
    };
    Ok(match &req.signal {
        BenchSignal::SweptSine => {
            let s = SweptSine::bench(0.0);
            let spec = TargetSpec::SweptSine {
                amplitude_mm: s.amplitude_mm,
                f0_hz: s.f0_hz,
                f1_hz: s.f1_hz,
            };
            (spec, duration(30.0)?)
        }
        BenchSignal::Trapezoid => {
            let s = Trapezoid::bench();
            let spec = TargetSpec::Trapezoid {
                amplitude_mm: s.amplitude_mm,
                period_s: s.period_s,
            };
            (spec, duration(30.0)?)
        }
        BenchSignal::Steps => {
            let d = duration(140.0)?;
            let t = StepTarget::generate(&StepParams::default(), d, seed)?;
            let spec = TargetSpec::Steps {
                interval_s: t.interval_s,
                levels_mm: t.levels_mm,
            };
            (spec, d)
        }
        BenchSignal::Csv {
            sample_rate_hz,
            csv,
        } => {
            if !(1.0..=10_000.0).contains(sample_rate_hz) {
                return Err(AppError::BadRequest(
                    "signal.sample_rate_hz: 1 to 10000 Hz".into(),
                ));
            }
            let samples_mm = parse_csv(csv)?;
            let length = (samples_mm.len() - 1) as f64 / sample_rate_hz;
            let spec = TargetSpec::Sampled {
                sample_rate_hz: *sample_rate_hz,
                samples_mm,
            };
            (spec, duration(length.clamp(1.0, MAX_DURATION_S))?)
        }
    })
}

/// A compensator resolved: what the table calls it and the design that runs.
#[derive(Debug, Clone)]
struct Resolved {
    label: String,
    config_id: Option<i64>,
    spec: CompensatorSpec,
}

async fn resolve(
    pool: &SqlitePool,
    choices: &[BenchChoice],
    plant: &bdft_protocol::params::PlantParams,
) -> Result<Vec<Resolved>> {
    if choices.is_empty() || choices.len() > MAX_COMPENSATORS {
        return Err(AppError::BadRequest(format!(
            "compensators: 1 to {MAX_COMPENSATORS}"
        )));
    }
    let mut out = Vec::with_capacity(choices.len());
    for (i, c) in choices.iter().enumerate() {
        out.push(match (&c.design, c.config_id) {
            (Some(name), None) => Resolved {
                label: name.clone(),
                config_id: None,
                spec: variants::variant(name, plant, DT)
                    .map_err(|e| AppError::BadRequest(format!("compensators[{i}].design: {e}")))?,
            },
            (None, Some(id)) => {
                let v = store::configs::get(pool, id).await.map_err(|e| match e {
                    AppError::NotFound(_) => AppError::BadRequest(format!(
                        "compensators[{i}].config_id: no configuration version {id}"
                    )),
                    e => e,
                })?;
                Resolved {
                    label: format!("{} v{}", v.name, v.version),
                    config_id: Some(v.id),
                    spec: v.spec,
                }
            }
            _ => {
                return Err(AppError::BadRequest(format!(
                    "compensators[{i}]: give either design or config_id"
                )));
            }
        });
    }
    Ok(out)
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
        pool: &SqlitePool,
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
        let compensators = resolve(pool, &req.compensators, &params.plant).await?;
        let starts: Vec<StartTrial> = compensators
            .iter()
            .enumerate()
            .map(|(i, c)| StartTrial {
                trial_id: BENCH_TRIAL_IDS + i as u64,
                compensator: c.spec.clone(),
                // The reference drives the cylinder directly: no operator, no feedthrough.
                station: Seat::Off,
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
            })
            .collect();
        for s in &starts {
            s.validate()?;
        }
        let rig = match params.rig {
            RigKind::Simulated => Rig::Sim,
            RigKind::Real => {
                check_real_rig(pool, link).await?;
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
            },
        )
        .await?;
        let labels: Vec<&str> = compensators.iter().map(|c| c.label.as_str()).collect();
        change
            .commit(
                "bench.start",
                Some(format!("bench_run:{run_id}")),
                json!({ "compensators": labels, "signal": signal_kind(&target), "duration_s": duration_s, "seed": seed, "study_id": req.study_id }),
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
                        json!({ "error": error }),
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

/// Runs the server left running when it stopped are failed (audited), so none shows as
/// running forever.
pub async fn fail_interrupted(pool: &SqlitePool) -> Result<()> {
    let mut change = Change::begin(pool, "system:startup").await?;
    let n = store::bench::fail_unfinished(change.db(), "server restart").await?;
    if n > 0 {
        change
            .commit(
                "bench.fail",
                None,
                json!({ "runs": n, "error": "server restart" }),
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
}

/// A bench trial's id on the controller link: far above any row of `trials`, so its result
/// comes back to the bench and is never filed as a study's trial.
const BENCH_TRIAL_IDS: u64 = 1 << 50;

/// A bench run on the real rig needs the E-stop reset and a controller with a real rig.
async fn check_real_rig(pool: &SqlitePool, link: &ControllerLink) -> Result<()> {
    if store::latch::latched(pool).await? || link.estop_latched() {
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

fn signal_kind(t: &TargetSpec) -> &'static str {
    match t {
        TargetSpec::Steps { .. } => "steps",
        TargetSpec::SweptSine { .. } => "swept-sine",
        TargetSpec::Trapezoid { .. } => "trapezoid",
        TargetSpec::Sampled { .. } => "csv",
    }
}

/// Runs each compensator in turn off the async threads and stores its result.
async fn run_all(
    pool: &SqlitePool,
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
                if store::latch::latched(pool).await? || link.estop_latched() {
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
        let trace = trace_json(&channels, result.dt);
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
                json!({ "run_id": run_id, "label": c.label, "outcome": outcome, "metrics": m }),
            )
            .await?;
        job.done.fetch_add(1, Ordering::SeqCst);
    }
    Ok(())
}

/// The stored trace: `TRACE_CHANNELS` at every `DECIMATION`-th tick.
fn trace_json(channels: &[Vec<f32>], dt: f64) -> String {
    let mut trace = serde_json::Map::new();
    trace.insert("dt_s".into(), json!(dt * DECIMATION as f64));
    for name in TRACE_CHANNELS {
        let k = record_channel(name).expect("trace channels are record channels");
        let kept: Vec<f32> = channels
            .get(k)
            .map(|c| c.iter().step_by(DECIMATION).copied().collect())
            .unwrap_or_default();
        trace.insert(name.into(), json!(kept));
    }
    serde_json::Value::Object(trace).to_string()
}

/// A run's result with its reductions against its twin in the same run (none when the
/// design has no twin or the run has none).
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ResultView {
    #[serde(flatten)]
    pub result: BenchResult,
    /// The label of the twin it is compared with.
    pub twin: Option<String>,
    /// 100 · (1 − mine / twin's), in %: positive is better than the twin.
    pub tracking_reduction_pct: Option<f64>,
    pub cab_accel_reduction_pct: Option<f64>,
}

/// A run with its results, their reductions and their traces.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RunView {
    pub run: BenchRun,
    pub results: Vec<ResultView>,
    /// Per result (same order): {"dt_s", "target_mm", "cyl_pos_mm", "cab_accel_mm_s2"}.
    #[schema(value_type = Vec<Object>)]
    pub traces: Vec<serde_json::Value>,
}

/// Each result with its reductions against the first result of its twin's kind.
pub fn with_reductions(results: Vec<BenchResult>) -> Vec<ResultView> {
    let pct = |mine: f64, theirs: f64| (theirs > 0.0).then(|| 100.0 * (1.0 - mine / theirs));
    results
        .iter()
        .map(|r| {
            let twin = twin(r.kind).and_then(|k| results.iter().find(|t| t.kind == k));
            ResultView {
                result: r.clone(),
                twin: twin.map(|t| t.label.clone()),
                tracking_reduction_pct: twin
                    .and_then(|t| pct(r.mse_tracking_mm2, t.mse_tracking_mm2)),
                cab_accel_reduction_pct: twin.and_then(|t| pct(r.ms_cab_accel, t.ms_cab_accel)),
            }
        })
        .collect()
}

pub async fn view(pool: &SqlitePool, run_id: i64) -> Result<RunView> {
    let run = store::bench::run(pool, run_id).await?;
    let results = store::bench::results(pool, run_id).await?;
    let traces = results
        .iter()
        .map(|r| {
            serde_json::from_str(&r.trace_json).map_err(|e| {
                AppError::Internal(anyhow::anyhow!(
                    "stored trace of bench result {}: {e}",
                    r.id
                ))
            })
        })
        .collect::<Result<_>>()?;
    Ok(RunView {
        run,
        results: with_reductions(results),
        traces,
    })
}

/// The run as CSV: one line per result and kept tick (`t_s`, the trace channels), with the
/// result's metrics and reductions repeated, so one file holds everything.
pub fn csv(v: &RunView) -> String {
    use super::export::text_cell;
    let mut out = format!(
        "run_id,position,label,controller,config_id,outcome,mse_tracking_mm2,ms_cab_accel,tracking_reduction_pct,cab_accel_reduction_pct,t_s,{}\n",
        TRACE_CHANNELS.join(",")
    );
    let num = |x: Option<f64>| x.map(|x| x.to_string()).unwrap_or_default();
    for (r, trace) in v.results.iter().zip(&v.traces) {
        let b = &r.result;
        let prefix = format!(
            "{},{},{},{},{},{},{},{},{},{}",
            b.run_id,
            b.position,
            text_cell(&b.label),
            b.kind.name(),
            b.config_id.map(|x| x.to_string()).unwrap_or_default(),
            text_cell(&b.outcome),
            b.mse_tracking_mm2,
            b.ms_cab_accel,
            num(r.tracking_reduction_pct),
            num(r.cab_accel_reduction_pct),
        );
        let dt = trace["dt_s"].as_f64().unwrap_or(DT * DECIMATION as f64);
        let cols: Vec<&Vec<serde_json::Value>> = TRACE_CHANNELS
            .iter()
            .filter_map(|c| trace[*c].as_array())
            .collect();
        for k in 0..cols.first().map_or(0, |c| c.len()) {
            out.push_str(&prefix);
            out.push_str(&format!(",{:.3}", k as f64 * dt));
            for c in &cols {
                out.push(',');
                out.push_str(&c[k].to_string());
            }
            out.push('\n');
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_compensated_design_has_its_uncompensated_twin() {
        use CompensatorKind::*;
        assert_eq!(twin(PidNotch), Some(Pid));
        assert_eq!(twin(PidShaper), Some(Pid));
        assert_eq!(twin(LqrCabvel), Some(Lqr));
        assert_eq!(twin(LqrCabacc), Some(Lqr));
        assert_eq!(twin(Pid), None);
        assert_eq!(twin(Lqr), None);
    }

    #[test]
    fn csv_errors_name_the_line_and_the_problem() {
        let err = |t: &str| parse_csv(t).unwrap_err().to_string();
        assert_eq!(parse_csv("mm\n1\n-2.5\n\n").unwrap(), vec![1.0, -2.5]);
        assert!(err("1\n2\nabc\n").contains("line 3: \"abc\" is not a number"));
        assert!(err("1\n2,3\n").contains("line 2") && err("1\n2,3\n").contains("one column"));
        assert!(err("1\n1e9\n").contains("line 2: 1e9 mm is outside"));
        assert!(err("1\nNaN\n").contains("line 2"));
        assert!(err("mm\n1\n").contains("at least 2"));
        let long = "0\n".repeat(MAX_SAMPLES + 1);
        assert!(err(&long).contains(&format!("line {}", MAX_SAMPLES + 1)));
    }
}
