//! What a synthetic subject takes away from a test and says of it: the error, the felt
//! vibration, the machine's response time and the seen shake read off the test's record
//! (`perceive`), and the survey's answers from them (`answers`).

use crate::rng::Rng;
use bdft_protocol::params::{Seat, SubjectDraw};
use bdft_protocol::trial::record_channel;

/// What a subject takes away from a test: how far off the target they were, how much the
/// seat shook, how quickly the machine answered their hand, and how much the cylinder shook
/// on the display.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Perception {
    /// RMS of target − cylinder position (mm).
    pub rms_error_mm: f64,
    /// RMS cab acceleration felt (m/s²), frequency-weighted as ISO 2631-1 weights fore-aft
    /// vibration at the seat (W_d: flat to 2 Hz, falling as 1/f above, so the engine's tone
    /// at 30 Hz counts a fifteenth of its size): 0 at the desk.
    pub felt_rms_m_s2: f64,
    /// How quickly the machine answered what the subject did — the survey's "how quickly
    /// did the machine respond" — from their intended hand position to the cylinder, their
    /// own reaction time left out (s): when the cylinder began to follow (`follow_lag`) plus
    /// how long it took to get there and stay (`settling_delay`). Onset and settling both,
    /// as handling-qualities ratings depend on a response's phase delay and on its
    /// bandwidth (ADS-33): a filter's lag is felt as a late start, a lightly damped
    /// feedthrough loop as a response that will not settle.
    pub response_time_s: f64,
    /// RMS of the cylinder's motion above 3 Hz (mm, `operator::shake_filter`): shake seen
    /// on the display.
    pub seen_shake_mm: f64,
}

/// The longest response looked at (s), and its sampling step.
const MAX_LAG_S: f64 = 1.5;
const LAG_STEP_S: f64 = 0.01;

/// The record channels a subject perceives a test through, at the loop rate.
#[derive(Debug, Clone, Copy)]
pub struct Seen<'a> {
    /// Pursuit target (mm).
    pub target: &'a [f32],
    /// The subject's intended hand position (mm of device travel).
    pub hand: &'a [f32],
    /// Cylinder position (mm).
    pub y: &'a [f32],
    /// Cab acceleration (mm/s²).
    pub cab_accel: &'a [f32],
}

/// What the subject perceived of a test from its record at the loop rate `dt`.
pub fn perceive(seen: &Seen<'_>, seat: Seat, dt: f64) -> Perception {
    let Seen {
        target,
        hand,
        y,
        cab_accel,
    } = *seen;
    let n = target
        .len()
        .min(hand.len())
        .min(y.len())
        .min(cab_accel.len());
    if n == 0 {
        return Perception {
            rms_error_mm: 0.0,
            felt_rms_m_s2: 0.0,
            response_time_s: 0.0,
            seen_shake_mm: 0.0,
        };
    }
    let rms = |it: &mut dyn Iterator<Item = f64>| {
        let (s, c) = it.fold((0.0, 0usize), |(s, c), v| (s + v * v, c + 1));
        (s / c.max(1) as f64).sqrt()
    };
    let rms_error_mm = rms(&mut (0..n).map(|i| f64::from(target[i]) - f64::from(y[i])));
    let felt_rms_m_s2 = match seat {
        Seat::On => {
            let mut wd = crate::exposure::WdWeighting::new(dt);
            rms(&mut cab_accel[..n].iter().map(|&a| wd.step(f64::from(a) * 1e-3)))
        }
        Seat::Off => 0.0,
    };
    let mut hp = crate::operator::shake_filter(dt);
    let seen_shake_mm = rms(&mut y[..n].iter().map(|&v| hp.step(f64::from(v))));
    Perception {
        rms_error_mm,
        felt_rms_m_s2,
        response_time_s: follow_lag(&hand[..n], &y[..n], dt)
            + settling_delay(&hand[..n], &y[..n], dt),
        seen_shake_mm,
    }
}

/// When `later` began to follow `lead` (s): the shift at the peak of their correlation
/// coefficient, which ignores the signals' levels and scales (the hand moves millimetres of
/// device travel, the cylinder K_BF times as many). 0 when either signal does not move.
fn follow_lag(lead: &[f32], later: &[f32], dt: f64) -> f64 {
    let n = lead.len().min(later.len());
    let step = ((LAG_STEP_S / dt).round() as usize).max(1);
    let max = ((MAX_LAG_S / dt).round() as usize).min(n.saturating_sub(2));
    let mut best = (0.0, 0usize);
    for lag in (0..=max).step_by(step) {
        let pairs = || {
            (0..n - lag)
                .step_by(step)
                .map(|i| (f64::from(lead[i]), f64::from(later[i + lag])))
        };
        let m = (n - lag).div_ceil(step) as f64;
        let (sa, sb) = pairs().fold((0.0, 0.0), |(sa, sb), (a, b)| (sa + a, sb + b));
        let (ma, mb) = (sa / m, sb / m);
        let (sab, saa, sbb) = pairs().fold((0.0, 0.0, 0.0), |(ab, aa, bb), (a, b)| {
            let (a, b) = (a - ma, b - mb);
            (ab + a * b, aa + a * a, bb + b * b)
        });
        let r = sab / (saa * sbb).sqrt();
        if r > best.0 {
            best = (r, lag);
        }
    }
    best.1 as f64 * dt
}

/// How long (s) `later` takes to get to a step of `lead` and stay there: the delay whose
/// step response has the same time-weighted absolute error (ITAE = τ²/2 for a delay τ) as
/// the step response identified from the two records (a least-squares impulse response of
/// their increments over `MAX_LAG_S`, sampled every `LAG_STEP_S`). Weighting the error by
/// time counts a response that rings as slow, even when it starts early. 0 when `lead`
/// does not move.
fn settling_delay(lead: &[f32], later: &[f32], dt: f64) -> f64 {
    let step = ((LAG_STEP_S / dt).round() as usize).max(1);
    let taps = (MAX_LAG_S / LAG_STEP_S).round() as usize;
    let sample = |x: &[f32]| -> Vec<f64> {
        let s: Vec<f64> = x.iter().step_by(step).map(|&v| f64::from(v)).collect();
        s.windows(2).map(|w| w[1] - w[0]).collect()
    };
    let (u, y) = (sample(lead), sample(later));
    let n = u.len().min(y.len());
    if n <= 2 * taps {
        return 0.0;
    }
    // Normal equations with the increments' correlations (Toeplitz): R g = b.
    let corr = |a: &[f64], b: &[f64], lag: usize| -> f64 {
        (lag..n).map(|k| a[k - lag] * b[k]).sum::<f64>() / n as f64
    };
    let r: Vec<f64> = (0..taps).map(|j| corr(&u, &u, j)).collect();
    if r[0] <= 0.0 {
        return 0.0;
    }
    let big = nalgebra::DMatrix::from_fn(taps, taps, |i, j| r[i.abs_diff(j)]);
    let rhs = nalgebra::DVector::from_fn(taps, |j, _| corr(&u, &y, j));
    let Some(g) = big.cholesky().map(|c| c.solve(&rhs)) else {
        return 0.0;
    };
    let mut s = 0.0;
    let response: Vec<f64> = g
        .iter()
        .map(|v| {
            s += v;
            s
        })
        .collect();
    let tail = taps / 8;
    let last = response[taps - tail..].iter().sum::<f64>() / tail as f64;
    if last.abs() < f64::EPSILON {
        return 0.0;
    }
    let itae: f64 = response
        .iter()
        .enumerate()
        .map(|(k, v)| k as f64 * LAG_STEP_S * (1.0 - v / last).abs())
        .sum::<f64>()
        * LAG_STEP_S;
    (2.0 * itae).sqrt()
}

/// The levels a typical subject calls "middling" for each perceived quantity: a rating sits
/// at the scale's middle when the test was like this, one standard unit higher for each
/// factor `SCALE_FACTOR` better. Calibrated on the default population tracking the
/// published protocol: the medians over the five compensators of an 8-subject pilot (felt
/// vibration on the machine, the cylinder's seen shake at the desk), rounded
/// (docs/synthetic-subjects.md; `bdft-server findings --subjects 8 --surveys 8 --seed 11`
/// prints them). Re-set with the population: levels left from an earlier one put every
/// rating of a quantity that has since shrunk against the scale's top.
pub const MIDDLING: Perception = Perception {
    rms_error_mm: 11.4,
    felt_rms_m_s2: 0.17,
    response_time_s: 0.51,
    seen_shake_mm: 0.6,
};
/// How many times better (smaller) a quantity must be to raise a rating by one standard
/// unit: (scale − 1)/4 points.
const SCALE_FACTOR: f64 = 1.5;

/// The four ratings (accuracy, speed of response, smoothness, overall controllability) a
/// subject gives a test they perceived as `p`, on a 1…`scale_points` scale (higher is
/// better), and a one-line comment. Each rating is the scale's middle plus
/// (scale − 1)/4 points per standard unit of how much better than `MIDDLING` the test felt
/// (log base `SCALE_FACTOR`), plus the subject's own bias and the answer's noise, rounded
/// and kept on the scale. Smoothness is what was felt on the machine, and the cylinder's
/// visible shake at the desk; controllability weighs the three.
/// What a subject perceives of a test from its record: `channels` in the record's order
/// (`record_channel`), sampled every `dt`.
pub fn perceive_record(channels: &[Vec<f32>], seat: Seat, dt: f64) -> Perception {
    let channel = |name: &str| {
        record_channel(name)
            .and_then(|i| channels.get(i))
            .map_or(&[][..], Vec::as_slice)
    };
    perceive(
        &Seen {
            target: channel("target_mm"),
            hand: channel("hand_mm"),
            y: channel("cyl_pos_mm"),
            cab_accel: channel("cab_accel_mm_s2"),
        },
        seat,
        dt,
    )
}

/// The answers to the test whose target was seeded `target_seed`: `answers` on the survey's
/// own stream of that seed, so the same test is always answered alike.
pub fn answer_test(
    d: &SubjectDraw,
    p: &Perception,
    seat: Seat,
    scale_points: u8,
    target_seed: u64,
) -> ([u8; 4], String) {
    answers(
        d,
        p,
        seat,
        scale_points,
        Rng::derive(target_seed, Rng::SURVEY).next_u64(),
    )
}

pub fn answers(
    d: &SubjectDraw,
    p: &Perception,
    seat: Seat,
    scale_points: u8,
    seed: u64,
) -> ([u8; 4], String) {
    let mut rng = Rng::derive(seed, Rng::SURVEY);
    let better = |middling: f64, got: f64| (middling / got.max(1e-9)).ln() / SCALE_FACTOR.ln();
    let accuracy = better(MIDDLING.rms_error_mm, p.rms_error_mm);
    let speed = better(MIDDLING.response_time_s, p.response_time_s.max(0.05));
    let smoothness = match seat {
        Seat::On => better(MIDDLING.felt_rms_m_s2, p.felt_rms_m_s2),
        Seat::Off => better(MIDDLING.seen_shake_mm, p.seen_shake_mm),
    };
    let overall = 0.5 * accuracy + 0.2 * speed + 0.3 * smoothness;
    let scale = f64::from(scale_points.max(2));
    let mid = (scale + 1.0) / 2.0;
    let points_per_unit = (scale - 1.0) / 4.0;
    let mut rate = |units: f64| {
        let noisy = mid
            + points_per_unit * units
            + d.survey_bias_points
            + d.survey_noise_points * rng.normal();
        noisy.round().clamp(1.0, scale) as u8
    };
    let ratings = [rate(accuracy), rate(speed), rate(smoothness), rate(overall)];
    let aspects = [
        ("following the target", accuracy),
        ("how quickly it responded", speed),
        ("how smooth it felt", smoothness),
    ];
    let best = aspects
        .iter()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .expect("three");
    let worst = aspects
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("three");
    let comment = format!("(synthetic) liked {}; disliked {}", best.0, worst.0);
    (ratings, comment)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::population::tests::median_subject;

    #[test]
    fn perception_reads_error_and_felt_vibration_off_the_record() {
        // The cylinder follows a 0.5 Hz target sine 0.3 s late: the RMS error
        // |1 − e^(−jωτ)|·A/√2 = 2·sin(ωτ/2)·A/√2.
        let dt = 1e-3;
        let (a, f, tau) = (10.0f64, 0.5f64, 0.3f64);
        let w = 2.0 * std::f64::consts::PI * f;
        let n = 20_000;
        let sine = |shift: f64| -> Vec<f32> {
            (0..n)
                .map(|k| (a * (w * (k as f64 * dt - shift)).sin()) as f32)
                .collect()
        };
        let (target, y) = (sine(0.0), sine(tau));
        // 2 m/s² RMS of cab acceleration at 4 Hz.
        let accel: Vec<f32> = (0..n)
            .map(|k| {
                (2000.0 * 2f64.sqrt() * (8.0 * std::f64::consts::PI * k as f64 * dt).sin()) as f32
            })
            .collect();
        let seen = Seen {
            target: &target,
            hand: &target,
            y: &y,
            cab_accel: &accel,
        };
        let p = perceive(&seen, Seat::On, dt);
        let want = 2.0 * (w * tau / 2.0).sin() * a / 2f64.sqrt();
        assert!(
            (p.rms_error_mm - want).abs() < 0.01 * want,
            "{} vs {want}",
            p.rms_error_mm
        );
        // Felt through W_d: |W_d(4 Hz)| of it (the weighting's start-up is 1 % of the test).
        let felt = 2.0 * crate::exposure::wd_analog(4.0);
        assert!(
            (p.felt_rms_m_s2 - felt).abs() < 0.02 * felt,
            "{} vs {felt}",
            p.felt_rms_m_s2
        );
        // A 0.5 Hz motion is tracking, not shake.
        assert!(p.seen_shake_mm < 0.05 * a, "{}", p.seen_shake_mm);
        assert_eq!(perceive(&seen, Seat::Off, dt).felt_rms_m_s2, 0.0);
        // A hand that never moved gives the machine nothing to answer.
        let still = vec![0.0f32; n];
        let idle = Seen {
            hand: &still,
            ..seen
        };
        assert_eq!(perceive(&idle, Seat::On, dt).response_time_s, 0.0);
    }

    /// 100 s of a hand that wanders (a random walk) at 1 kHz, and a cylinder answering it
    /// through the discrete filter `answer` (3 mm of cylinder per mm of hand).
    fn answered(answer: impl FnMut(f64) -> f64) -> (Vec<f32>, Vec<f32>) {
        let mut rng = Rng::derive(7, Rng::OPERATOR);
        let mut at = 0.0;
        let hand: Vec<f64> = (0..100_000)
            .map(|_| {
                at += 0.1 * rng.normal();
                at
            })
            .collect();
        let y: Vec<f32> = hand
            .iter()
            .map(|&h| 3.0 * h)
            .map(answer)
            .map(|v| v as f32)
            .collect();
        (hand.iter().map(|&v| v as f32).collect(), y)
    }

    /// The time-weighted absolute error of a unit step response sampled every `dt`, as the
    /// delay with the same ITAE (τ²/2): computed on the response itself, not identified.
    fn itae_delay(step_response: &[f64], dt: f64) -> f64 {
        let itae: f64 = step_response
            .iter()
            .enumerate()
            .map(|(k, v)| k as f64 * dt * (1.0 - v).abs() * dt)
            .sum();
        (2.0 * itae).sqrt()
    }

    #[test]
    fn a_machine_that_answers_late_or_rings_is_perceived_slow() {
        let dt = 1e-3;
        // A pure delay τ starts τ late and settles τ late: perceived τ + τ.
        let tau = 0.3;
        let (hand, y) = {
            let mut past = std::collections::VecDeque::from(vec![0.0; 300]);
            answered(move |v| {
                past.push_back(v);
                past.pop_front().expect("a delay line")
            })
        };
        let still = vec![0.0f32; hand.len()];
        let seen = Seen {
            target: &y,
            hand: &hand,
            y: &y,
            cab_accel: &still,
        };
        let lag = perceive(&seen, Seat::Off, dt).response_time_s;
        assert!((lag - 2.0 * tau).abs() < 0.011, "{lag}");
        // A first-order lag T: ITAE = T², so it settles like a delay of √2·T.
        let t = 0.1;
        let a = (-dt / t).exp();
        let mut state = 0.0;
        let (hand, y) = answered(move |v| {
            state = a * state + (1.0 - a) * v;
            state
        });
        let settled = settling_delay(&hand, &y, dt);
        assert!((settled - 2f64.sqrt() * t).abs() < 0.01, "{settled}");
        // Two 2 Hz second-order answers: the one that rings (ζ = 0.2, within 3 % of its
        // final value by the window's end) settles later than the damped one (ζ = 0.7), each
        // as its own step response says.
        let second_order = |zeta: f64| {
            let w = 2.0 * std::f64::consts::PI * 2.0;
            let (mut x, mut v) = (0.0f64, 0.0f64);
            move |u: f64| {
                // Semi-implicit Euler at 1 kHz: accurate to well under the tolerance.
                v += dt * (w * w * (u - x) - 2.0 * zeta * w * v);
                x += dt * v;
                x
            }
        };
        for zeta in [0.2, 0.7] {
            let mut direct = second_order(zeta);
            let step: Vec<f64> = (0..1500).map(|_| direct(1.0)).step_by(10).collect();
            let want = itae_delay(&step, 0.01);
            let (hand, y) = answered(second_order(zeta));
            let got = settling_delay(&hand, &y, dt);
            assert!((got - want).abs() < 0.02, "ζ {zeta}: {got} vs {want}");
        }
        let settles = |zeta| {
            let (hand, y) = answered(second_order(zeta));
            settling_delay(&hand, &y, dt)
        };
        let (ringing, damped) = (settles(0.2), settles(0.7));
        assert!(ringing > 1.5 * damped, "{ringing} vs {damped}");
    }

    #[test]
    fn ratings_sit_mid_scale_at_the_middling_test_and_rise_a_step_per_factor_better() {
        let d = SubjectDraw {
            survey_noise_points: 0.0,
            ..median_subject()
        };
        let (r, comment) = answers(&d, &MIDDLING, Seat::On, 7, 1);
        assert_eq!(r, [4, 4, 4, 4]);
        assert!(comment.starts_with("(synthetic)"));
        // An error SCALE_FACTOR² smaller: two standard units, (7 − 1)/4 = 1.5 points each.
        let better = Perception {
            rms_error_mm: MIDDLING.rms_error_mm / SCALE_FACTOR.powi(2),
            ..MIDDLING
        };
        let (r, _) = answers(&d, &better, Seat::On, 7, 1);
        assert_eq!(r[0], 7);
        // Overall weighs accuracy by half: one standard unit, 1.5 points → 5.5 → 6.
        assert_eq!(r[3], 6);
        // Anything stays on the scale, whatever the bias and the test.
        let biased = SubjectDraw {
            survey_bias_points: 9.0,
            survey_noise_points: 3.0,
            ..d
        };
        let awful = Perception {
            rms_error_mm: 1e3,
            felt_rms_m_s2: 50.0,
            response_time_s: 1.5,
            seen_shake_mm: 40.0,
        };
        for seed in 0..50 {
            for p in [&awful, &better] {
                for scale in [2, 5, 7, 11] {
                    let (r, _) = answers(&biased, p, Seat::Off, scale, seed);
                    assert!(
                        r.iter().all(|&x| (1..=scale).contains(&x)),
                        "{r:?} on 1..{scale}"
                    );
                }
            }
        }
    }
}
