//! Reference signals: the rig's bench signals and the protocol's random-step target.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

use crate::error::ParamError;
use crate::params::check;
use crate::rng::Rng;
pub use bdft_protocol::params::StepParams;
use bdft_protocol::trial::TargetSpec;

/// Linear swept sine from f0 to f1 over `duration` seconds:
/// r(t) = A·sin(2π(f0·t + (f1 − f0)·t²/(2T))).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SweptSine {
    pub amplitude_mm: f64,
    pub f0_hz: f64,
    pub f1_hz: f64,
    pub duration_s: f64,
}

impl SweptSine {
    pub fn bench(duration_s: f64) -> Self {
        Self {
            amplitude_mm: 5.0,
            f0_hz: 0.01,
            f1_hz: 8.0,
            duration_s,
        }
    }

    pub fn at(&self, t: f64) -> f64 {
        let t = t.min(self.duration_s);
        let phase = self.f0_hz * t + (self.f1_hz - self.f0_hz) * t * t / (2.0 * self.duration_s);
        self.amplitude_mm * (2.0 * PI * phase).sin()
    }
}

/// Smoothed trapezoid: the integral of a trapezoidal velocity profile, moving between −A and
/// +A and back once per period. Each half period: a move over 2/3 of it (a quarter of the
/// move accelerating, half cruising, a quarter braking), then a dwell. Time 0 is mid-move
/// (r = 0), so a loop starting at rest starts on the signal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Trapezoid {
    pub amplitude_mm: f64,
    pub period_s: f64,
}

impl Trapezoid {
    pub fn bench() -> Self {
        Self {
            amplitude_mm: 25.0,
            period_s: 6.0,
        }
    }

    fn move_time(&self) -> f64 {
        self.period_s / 3.0
    }

    /// Distance covered τ seconds into a move of length 2A.
    fn travelled(&self, tau: f64) -> f64 {
        let tm = self.move_time();
        let ta = tm / 4.0;
        let d = 2.0 * self.amplitude_mm;
        let v = d / (tm - ta);
        if tau <= 0.0 {
            0.0
        } else if tau < ta {
            0.5 * v / ta * tau * tau
        } else if tau < tm - ta {
            0.5 * v * ta + v * (tau - ta)
        } else if tau < tm {
            d - 0.5 * v / ta * (tm - tau).powi(2)
        } else {
            d
        }
    }

    pub fn at(&self, t: f64) -> f64 {
        let half = self.period_s / 2.0;
        let phase = (t + self.move_time() / 2.0).rem_euclid(self.period_s);
        if phase < half {
            -self.amplitude_mm + self.travelled(phase)
        } else {
            self.amplitude_mm - self.travelled(phase - half)
        }
    }
}

/// A random-step target: one level per interval.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepTarget {
    pub interval_s: f64,
    pub levels_mm: Vec<f64>,
    pub seed: u64,
    /// Realized mean and standard deviation of the levels (equal intervals, so also of the
    /// signal over time).
    pub mean_mm: f64,
    pub std_mm: f64,
}

impl StepTarget {
    /// Draws levels for `duration_s`: uniform on ±range, then shifted and scaled so that the
    /// mean is zero and the standard deviation is exactly `std_mm`; a draw that no longer fits
    /// the range after scaling is rejected and drawn again. Same seed, same target.
    pub fn generate(params: &StepParams, duration_s: f64, seed: u64) -> Result<Self, ParamError> {
        params.validate()?;
        check("duration_s", duration_s, params.interval_s, 3600.0)?;
        let n = (duration_s / params.interval_s).ceil() as usize;
        if n < 2 {
            return Err(ParamError::Invalid {
                name: "duration_s",
                message: "a step target needs at least two steps".into(),
            });
        }
        let mut rng = Rng::derive(seed, Rng::TARGET);
        for _ in 0..10_000 {
            let raw: Vec<f64> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
            let (mean, std) = mean_std(&raw);
            if std < 1e-9 {
                continue;
            }
            let levels: Vec<f64> = raw
                .iter()
                .map(|x| (x - mean) / std * params.std_mm)
                .collect();
            if levels.iter().all(|v| v.abs() <= params.range_mm) {
                let (mean_mm, std_mm) = mean_std(&levels);
                return Ok(Self {
                    interval_s: params.interval_s,
                    levels_mm: levels,
                    seed,
                    mean_mm,
                    std_mm,
                });
            }
        }
        Err(ParamError::Invalid {
            name: "steps",
            message: format!(
                "no target with standard deviation {} mm fits in ±{} mm over {n} steps; lower std_mm or widen range_mm",
                params.std_mm, params.range_mm
            ),
        })
    }

    /// The target as a signal.
    pub fn signal(&self) -> Signal {
        Signal::Steps {
            interval_s: self.interval_s,
            levels_mm: self.levels_mm.clone(),
        }
    }
}

/// An uploaded reference: samples at a fixed rate, linearly interpolated, the last held.
#[derive(Debug, Clone, PartialEq)]
pub struct SampledReference {
    pub sample_rate_hz: f64,
    pub samples_mm: Vec<f64>,
}

impl SampledReference {
    pub fn at(&self, t: f64) -> f64 {
        let x = (t * self.sample_rate_hz).max(0.0);
        let last = self.samples_mm.len() - 1;
        let i = x.floor() as usize;
        if i >= last {
            return self.samples_mm[last];
        }
        let f = x - i as f64;
        self.samples_mm[i] + f * (self.samples_mm[i + 1] - self.samples_mm[i])
    }
}

/// Population mean and standard deviation.
pub fn mean_std(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// Any reference signal by name.
#[derive(Debug, Clone, PartialEq)]
pub enum Signal {
    SweptSine(SweptSine),
    Trapezoid(Trapezoid),
    /// `levels_mm[i]` from `i·interval_s` on; the last level holds after the end.
    Steps {
        interval_s: f64,
        levels_mm: Vec<f64>,
    },
    Sampled(SampledReference),
}

impl Signal {
    pub fn at(&self, t: f64) -> f64 {
        match self {
            Self::SweptSine(s) => s.at(t),
            Self::Trapezoid(s) => s.at(t),
            Self::Steps {
                interval_s,
                levels_mm,
            } => {
                let i = ((t / interval_s).max(0.0) as usize).min(levels_mm.len() - 1);
                levels_mm[i]
            }
            Self::Sampled(s) => s.at(t),
        }
    }

    /// The signal a trial message describes; bench sweeps span the trial's duration.
    pub fn from_spec(spec: &TargetSpec, duration_s: f64) -> Self {
        match spec {
            TargetSpec::Steps {
                interval_s,
                levels_mm,
            } => Self::Steps {
                interval_s: *interval_s,
                levels_mm: levels_mm.clone(),
            },
            TargetSpec::SweptSine {
                amplitude_mm,
                f0_hz,
                f1_hz,
            } => Self::SweptSine(SweptSine {
                amplitude_mm: *amplitude_mm,
                f0_hz: *f0_hz,
                f1_hz: *f1_hz,
                duration_s,
            }),
            TargetSpec::Trapezoid {
                amplitude_mm,
                period_s,
            } => Self::Trapezoid(Trapezoid {
                amplitude_mm: *amplitude_mm,
                period_s: *period_s,
            }),
            TargetSpec::Sampled {
                sample_rate_hz,
                samples_mm,
            } => Self::Sampled(SampledReference {
                sample_rate_hz: *sample_rate_hz,
                samples_mm: samples_mm.clone(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_targets_are_reproducible_bounded_and_normalized() {
        let p = StepParams::default();
        let a = StepTarget::generate(&p, 140.0, 11).unwrap();
        let b = StepTarget::generate(&p, 140.0, 11).unwrap();
        let c = StepTarget::generate(&p, 140.0, 12).unwrap();
        assert_eq!(a, b);
        assert_ne!(a.levels_mm, c.levels_mm);
        assert_eq!(a.levels_mm.len(), 70);
        for t in [&a, &c] {
            assert!(t.levels_mm.iter().all(|v| v.abs() <= p.range_mm));
            assert!(t.mean_mm.abs() < 1e-9, "mean {}", t.mean_mm);
            assert!((t.std_mm - p.std_mm).abs() < 1e-9, "std {}", t.std_mm);
        }
        // One level per 2 s.
        let s = a.signal();
        assert_eq!(s.at(0.0), a.levels_mm[0]);
        assert_eq!(s.at(1.999), a.levels_mm[0]);
        assert_eq!(s.at(2.0), a.levels_mm[1]);
        assert_eq!(s.at(500.0), a.levels_mm[69]);
    }

    #[test]
    fn infeasible_step_statistics_are_rejected_with_the_allowed_range() {
        let p = StepParams {
            std_mm: 39.0,
            ..StepParams::default()
        };
        let err = StepTarget::generate(&p, 140.0, 1).unwrap_err().to_string();
        assert!(err.contains("steps.std_mm") && err.contains("32"), "{err}");
    }

    #[test]
    fn swept_sine_instantaneous_frequency_sweeps_linearly() {
        let s = SweptSine::bench(30.0);
        // Zero crossings near t: spacing 1/(2 f(t)), f(t) = f0 + (f1 − f0) t/T.
        let dt = 1e-5;
        let mut crossings = vec![];
        let mut prev = s.at(20.0);
        let mut t = 20.0;
        while t < 20.5 {
            t += dt;
            let v = s.at(t);
            if prev.signum() != v.signum() {
                crossings.push(t);
            }
            prev = v;
        }
        let spacing = (crossings.last().unwrap() - crossings[0]) / (crossings.len() - 1) as f64;
        let f_mid = 0.01 + (8.0 - 0.01) * 20.25 / 30.0;
        assert!(
            (1.0 / (2.0 * spacing) - f_mid).abs() < 0.02,
            "{}",
            1.0 / (2.0 * spacing)
        );
        assert!((0..3000).all(|k| s.at(k as f64 * 0.01).abs() <= 5.0));
    }

    #[test]
    fn a_sampled_reference_interpolates_between_samples_and_holds_the_last() {
        let s = SampledReference {
            sample_rate_hz: 10.0,
            samples_mm: vec![0.0, 2.0, -4.0],
        };
        assert_eq!(s.at(0.0), 0.0);
        assert!((s.at(0.05) - 1.0).abs() < 1e-12);
        assert!((s.at(0.15) + 1.0).abs() < 1e-12);
        assert_eq!(s.at(0.2), -4.0);
        assert_eq!(s.at(99.0), -4.0);
        assert_eq!(s.at(-1.0), 0.0);
    }

    #[test]
    fn trapezoid_is_continuous_bounded_and_periodic() {
        let s = Trapezoid::bench();
        assert!(s.at(0.0).abs() < 1e-12);
        let dt = 1e-3;
        let mut max_v: f64 = 0.0;
        for k in 0..12_000 {
            let t = k as f64 * dt;
            let v = (s.at(t + dt) - s.at(t)) / dt;
            max_v = max_v.max(v.abs());
            assert!(s.at(t).abs() <= 25.0 + 1e-12);
            assert!((s.at(t) - s.at(t + 6.0)).abs() < 1e-9);
        }
        // Cruise speed: 50 mm over a 2 s move with 0.5 s ramps → 50/1.5 mm/s.
        assert!((max_v - 50.0 / 1.5).abs() < 0.1, "{max_v}");
        assert!((s.at(-1.0 + 6.0 * 3.0) - s.at(-1.0)).abs() < 1e-9);
    }
}
