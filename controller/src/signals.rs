//! Reference signals: the rig's bench signals and the protocol's random-step target.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

use crate::error::ParamError;
use crate::identification::{IdentificationError, Multisine};
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
    /// Realized mean-squared step change (`ms_step`, mm²).
    pub ms_step_mm2: f64,
}

/// The mean-squared step change a difficulty-matched target has, as a multiple of its
/// variance: 2, that of independent levels (E[(a − b)²] = 2σ²), whatever the number of steps,
/// so the practice and the tests of a study share one value.
pub const MATCHED_MS_STEP_PER_VARIANCE: f64 = 2.0;

impl StepTarget {
    /// Draws levels for `duration_s`: uniform on ±range, then shifted and scaled so that the
    /// mean is zero and the standard deviation is exactly `std_mm`; a draw that no longer fits
    /// the range after scaling is rejected and drawn again. Same seed, same target.
    pub fn generate(params: &StepParams, duration_s: f64, seed: u64) -> Result<Self, ParamError> {
        Self::draw(params, duration_s, seed, None)
    }

    /// As `generate`, and besides the mean-squared step change (`ms_step`) is exactly
    /// `MATCHED_MS_STEP_PER_VARIANCE`·std_mm², so every such target is equally hard to follow
    /// by that measure. Mean, standard deviation and step change are all invariant under
    /// reordering and scale alike, so the match is made on the zero-mean draw before scaling:
    /// the ratio (Σ steps²)/(Σ levels²) of a draw `u` and of a further draw `w` on the other
    /// side of the wanted ratio bracket it, and the mixture (1 − t)·u + t·w hitting it exactly
    /// is found by bisection on t (both draws are random, so the mixture has no trend a
    /// subject could learn).
    pub fn generate_matched(
        params: &StepParams,
        duration_s: f64,
        seed: u64,
    ) -> Result<Self, ParamError> {
        Self::draw(params, duration_s, seed, Some(MATCHED_MS_STEP_PER_VARIANCE))
    }

    fn draw(
        params: &StepParams,
        duration_s: f64,
        seed: u64,
        ms_step_ratio: Option<f64>,
    ) -> Result<Self, ParamError> {
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
            let raw = match ms_step_ratio {
                None => raw,
                Some(ratio) => match matched_mixture(raw, ratio, &mut rng) {
                    Some(x) => x,
                    None => continue,
                },
            };
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
                    ms_step_mm2: ms_step(&levels),
                    levels_mm: levels,
                    seed,
                    mean_mm,
                    std_mm,
                });
            }
        }
        let matched = if ms_step_ratio.is_some() {
            " and a matched step change"
        } else {
            ""
        };
        Err(ParamError::Invalid {
            name: "steps",
            message: format!(
                "no target with standard deviation {} mm{matched} fits in ±{} mm over {n} steps; lower std_mm or widen range_mm",
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

/// Mean-squared step change of a target's levels: Σ(l[i] − l[i−1])²/n over all n levels,
/// with l[−1] = 0 (the first step is the move from rest, which the subject tracks too), in
/// mm² for levels in mm. A measure of how hard a target is to follow.
pub fn ms_step(levels: &[f64]) -> f64 {
    let mut prev = 0.0;
    let mut sum = 0.0;
    for &l in levels {
        sum += (l - prev) * (l - prev);
        prev = l;
    }
    sum / levels.len() as f64
}

/// Σ steps² − ratio·Σ levels² of a zero-mean draw: zero when its step change is `ratio`
/// times its variance, whatever its scale.
fn ms_step_excess(xs: &[f64], ratio: f64) -> f64 {
    ms_step(xs) - ratio * xs.iter().map(|x| x * x).sum::<f64>() / xs.len() as f64
}

/// Draws beyond `u` that may be tried for the other side of the ratio (each side about half
/// of all draws, so 64 misses in a row are a sign the ratio is out of reach at this length).
const MATCH_TRIES: usize = 64;

/// The zero-mean mixture of the draw `raw` and further draws from `rng` whose step change is
/// exactly `ratio` times its variance, or None when none is found (too few steps).
fn matched_mixture(raw: Vec<f64>, ratio: f64, rng: &mut Rng) -> Option<Vec<f64>> {
    let centred = |xs: Vec<f64>| {
        let (mean, _) = mean_std(&xs);
        xs.into_iter().map(|x| x - mean).collect::<Vec<f64>>()
    };
    let u = centred(raw);
    let fu = ms_step_excess(&u, ratio);
    if fu == 0.0 {
        return Some(u);
    }
    let w = (0..MATCH_TRIES)
        .map(|_| centred((0..u.len()).map(|_| rng.uniform(-1.0, 1.0)).collect()))
        .find(|w| ms_step_excess(w, ratio).signum() != fu.signum())?;
    let mix = |t: f64| -> Vec<f64> { u.iter().zip(&w).map(|(a, b)| a + t * (b - a)).collect() };
    let (mut lo, mut hi) = (0.0, 1.0);
    // Bisection to the last bit of t: the excess changes sign between lo and hi.
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if ms_step_excess(&mix(mid), ratio).signum() == fu.signum() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(mix(lo))
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
    /// The identification test's excitation: the cylinder reference itself.
    Multisine(Multisine),
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
            Self::Multisine(m) => m.at(t),
        }
    }

    /// The signal a trial message describes for a loop ticking every `dt` s; bench sweeps
    /// span the trial's duration. Only a multisine can be refused (its period must be a
    /// whole number of ticks).
    pub fn from_spec(
        spec: &TargetSpec,
        duration_s: f64,
        dt: f64,
    ) -> Result<Self, IdentificationError> {
        Ok(match spec {
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
            TargetSpec::Identification { excitation, .. } => {
                Self::Multisine(Multisine::new(excitation, dt)?)
            }
        })
    }

    /// Whether the signal is the identification test's excitation, which drives the
    /// cylinder reference directly whatever the operator does.
    pub fn excites(&self) -> bool {
        matches!(self, Self::Multisine(_))
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

    /// FNV-1a over the levels' bits: a fingerprint of a whole target.
    fn fingerprint(levels: &[f64]) -> u64 {
        levels.iter().fold(0xcbf2_9ce4_8422_2325, |h, l| {
            (h ^ l.to_bits()).wrapping_mul(0x0000_0100_0000_01b3)
        })
    }

    #[test]
    fn unmatched_targets_are_bit_identical_to_those_drawn_before_matching_existed() {
        // Printed by `generate` at commit 548fbae (before difficulty matching): existing
        // studies keep their targets.
        let p = StepParams::default();
        for (seed, print, first) in [
            (1, 0x90eb_9ca1_5a6a_a947, -11.420913813237657),
            (7, 0xc56c_9cd5_01cd_8448, -26.282657691607486),
            (42, 0xf979_35a2_7228_de07, -13.276803448441502),
            (1234567, 0x9af7_c71a_7367_a1df, 27.789106477590657),
        ] {
            let t = StepTarget::generate(&p, 140.0, seed).unwrap();
            assert_eq!(t.levels_mm[0], first, "seed {seed}");
            assert_eq!(fingerprint(&t.levels_mm), print, "seed {seed}");
        }
    }

    #[test]
    fn the_ms_step_change_counts_the_first_step_from_rest() {
        // (1 − 0)² + (3 − 1)² + (2 − 3)² = 6 over 3 levels.
        assert_eq!(ms_step(&[1.0, 3.0, 2.0]), 2.0);
        assert_eq!(ms_step(&[-4.0]), 16.0);
    }

    #[test]
    fn matched_targets_share_one_step_change_with_exact_mean_std_and_range() {
        let p = StepParams::default();
        let wanted = MATCHED_MS_STEP_PER_VARIANCE * p.std_mm * p.std_mm;
        let mut free = vec![];
        // The study's tests (70 steps), its practice (60) and a short pilot's (4 and 8).
        for duration in [140.0, 120.0, 8.0, 16.0] {
            for seed in 0..50 {
                let t = StepTarget::generate_matched(&p, duration, seed).unwrap();
                assert_eq!(t, StepTarget::generate_matched(&p, duration, seed).unwrap());
                let ms = ms_step(&t.levels_mm);
                assert!(
                    (ms / wanted - 1.0).abs() < 1e-9,
                    "{duration} s, seed {seed}: {ms} mm² against {wanted}"
                );
                assert_eq!(t.ms_step_mm2, ms);
                let (mean, std) = mean_std(&t.levels_mm);
                assert!(mean.abs() < 1e-9, "mean {mean}");
                assert!((std / p.std_mm - 1.0).abs() < 1e-12, "std {std}");
                assert!(t.levels_mm.iter().all(|v| v.abs() <= p.range_mm));
                let unmatched = StepTarget::generate(&p, duration, seed).unwrap();
                assert_eq!(unmatched.ms_step_mm2, ms_step(&unmatched.levels_mm));
                free.push(unmatched.ms_step_mm2 / wanted);
            }
        }
        // Without matching the step change varies from target to target: the match matters.
        let (lo, hi) = free
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &r| (l.min(r), h.max(r)));
        assert!(lo < 0.9 && hi > 1.1, "unmatched ratios {lo}..{hi}");
    }

    #[test]
    fn a_matched_target_of_two_steps_is_refused() {
        // Two zero-mean levels are ±a: their step change is always 2.5 a², never 2 a².
        let err = StepTarget::generate_matched(&StepParams::default(), 4.0, 1)
            .unwrap_err()
            .to_string();
        assert!(err.contains("matched step change"), "{err}");
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
