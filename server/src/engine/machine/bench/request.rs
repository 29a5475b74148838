//! What a bench run asks for: its compensators (design names or configuration versions,
//! resolved to the designs that run), its reference signal (generated, or an uploaded CSV
//! checked line by line) and their limits.

use bdft_controller::compensator::variants;
use bdft_controller::signals::{StepParams, StepTarget, SweptSine, Trapezoid};
use bdft_protocol::params::{CompensatorSpec, MachineCondition};
use bdft_protocol::trial::{MAX_SAMPLES, TargetSpec};
use serde::Deserialize;
use sqlx::AnyPool;
use utoipa::ToSchema;

use super::{DT, MAX_COMPENSATORS, MAX_DURATION_S};
use crate::error::{AppError, Result};
use crate::store;

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
    /// The machine's condition the simulated rig runs under (`tires`, `outriggers+loaded`,
    /// …; the designs stay made for the study's rig) [default: the study's, `stilts`].
    #[serde(default)]
    #[schema(value_type = Option<String>, example = "tires")]
    pub condition: Option<MachineCondition>,
    /// The site whose machine a run on the real rig uses (`serve --site`) [default: the
    /// server's first].
    #[serde(default)]
    pub site: Option<String>,
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
pub(super) fn target(req: &BenchRequest, seed: u64) -> Result<(TargetSpec, f64)> {
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
pub(super) struct Resolved {
    pub(super) label: String,
    pub(super) config_id: Option<i64>,
    pub(super) spec: CompensatorSpec,
}

pub(super) async fn resolve(
    pool: &AnyPool,
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

#[cfg(test)]
mod tests {
    use super::*;

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
