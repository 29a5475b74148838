//! The synthetic subject pool: each synthetic subject draws its own operator, body and
//! survey habits from the study's `PopulationParams` (`draw`), becomes a slightly different
//! operator from test to test as they learn and tire (`operator`), and answers the survey
//! after each test from what they perceived of it (`perceive`, `answers`).
//!
//! Everything is a function of the draw's seed: the same study seed and enrolment index give
//! the same subject forever (`Rng::derive` keeps the streams apart).

use bdft_protocol::params::{
    BodyModel, BodySource, PopulationParams, Seat, Spread, SubjectDraw, bounds,
};

use crate::operator::OperatorParams;
use crate::rng::Rng;

/// Draws one subject. `seed` is the subject's own (the server derives it from the study
/// seed and the enrolment index).
pub fn draw(pop: &PopulationParams, seed: u64) -> SubjectDraw {
    let mut rng = Rng::derive(seed, Rng::POPULATION);
    // Every spread takes one normal deviate in a fixed order, drawn or not, so changing
    // one spread (or the body source) never moves another parameter's value.
    let at = |rng: &mut Rng, s: &Spread, (lo, hi): (f64, f64)| s.at(rng.normal(), lo, hi);
    let reaction_delay_s = at(&mut rng, &pop.reaction_delay_s, bounds::REACTION_DELAY_S);
    let neuromuscular_w_rad_s = at(&mut rng, &pop.neuromuscular_w, bounds::NEUROMUSCULAR_W);
    let neuromuscular_zeta = at(
        &mut rng,
        &pop.neuromuscular_zeta,
        bounds::NEUROMUSCULAR_ZETA,
    );
    let error_gain = at(&mut rng, &pop.error_gain, bounds::ERROR_GAIN);
    let error_integral_gain_1_s = at(
        &mut rng,
        &pop.error_integral_gain,
        bounds::ERROR_INTEGRAL_GAIN,
    );
    let remnant_std_mm = at(&mut rng, &pop.remnant_std_mm, bounds::REMNANT_STD_MM);
    let shake_aversion_per_mm = at(
        &mut rng,
        &pop.shake_aversion_per_mm,
        bounds::SHAKE_AVERSION_PER_MM,
    );
    let learning_excess = at(&mut rng, &pop.learning_excess, bounds::LEARNING_EXCESS);
    let learning_tests = at(&mut rng, &pop.learning_tests, bounds::LEARNING_TESTS);
    let fatigue_per_hour = at(&mut rng, &pop.fatigue_per_hour, bounds::FATIGUE_PER_HOUR);
    let body_k_h = at(&mut rng, &pop.body_k_h, bounds::BODY_K_H);
    let torso_f_hz = at(&mut rng, &pop.torso_f_hz, bounds::TORSO_F_HZ);
    let torso_zeta = at(&mut rng, &pop.torso_zeta, bounds::TORSO_ZETA);
    let arm_f_hz = at(&mut rng, &pop.arm_f_hz, bounds::ARM_F_HZ);
    let arm_zeta = at(&mut rng, &pop.arm_zeta, bounds::ARM_ZETA);
    let grip_stiffening_per_m_s2 = at(
        &mut rng,
        &pop.grip_stiffening_per_m_s2,
        bounds::GRIP_STIFFENING_PER_M_S2,
    );
    let vibration_remnant_per_m_s2 = at(
        &mut rng,
        &pop.vibration_remnant_per_m_s2,
        bounds::VIBRATION_REMNANT_PER_M_S2,
    );
    let survey_bias_points = pop.survey_bias_sd * rng.normal();
    // Drawn last: a parameter added later leaves the earlier ones of a seed as they were.
    let vibration_slowing_per_m_s2 = at(
        &mut rng,
        &pop.vibration_slowing_per_m_s2,
        bounds::VIBRATION_SLOWING_PER_M_S2,
    );
    let vibration_regression_per_m_s2 = at(
        &mut rng,
        &pop.vibration_regression_per_m_s2,
        bounds::VIBRATION_REGRESSION_PER_M_S2,
    );
    let motor_noise_mm = at(&mut rng, &pop.motor_noise_mm, bounds::MOTOR_NOISE_MM);
    let drawn_body = pop.body == BodySource::Drawn;
    let body_or_zero = |v: f64| if drawn_body { v } else { 0.0 };
    SubjectDraw {
        reaction_delay_s,
        neuromuscular_w_rad_s,
        neuromuscular_zeta,
        error_gain,
        error_integral_gain_1_s,
        remnant_std_mm,
        shake_aversion_per_mm,
        learning_excess,
        learning_tests,
        fatigue_per_hour,
        body_k_h: body_or_zero(body_k_h),
        torso_f_hz: body_or_zero(torso_f_hz),
        torso_zeta: body_or_zero(torso_zeta),
        arm_f_hz: body_or_zero(arm_f_hz),
        arm_zeta: body_or_zero(arm_zeta),
        grip_stiffening_per_m_s2: body_or_zero(grip_stiffening_per_m_s2),
        vibration_remnant_per_m_s2,
        vibration_slowing_per_m_s2,
        vibration_regression_per_m_s2,
        motor_noise_mm,
        survey_bias_points,
        survey_noise_points: pop.survey_noise_sd,
    }
}

/// The body this subject rides with: their own seated body, or the study's `preset` when
/// the population does not draw bodies (`body_k_h` = 0).
pub fn body(d: &SubjectDraw, preset: BodyModel) -> BodyModel {
    if d.body_k_h == 0.0 {
        return preset;
    }
    BodyModel::Seated {
        k_h: d.body_k_h,
        torso_f_hz: d.torso_f_hz,
        torso_zeta: d.torso_zeta,
        arm_f_hz: d.arm_f_hz,
        arm_zeta: d.arm_zeta,
    }
}

/// How much of the task the subject has yet to learn before the test at `position` (0 for
/// the practice, 1 for the first scored test, …): the fraction of remnant in excess of the
/// learned level, decaying by e every `learning_tests` tests.
pub fn unlearned(d: &SubjectDraw, position: u32) -> f64 {
    d.learning_excess * (-f64::from(position) / d.learning_tests).exp()
}

/// The operator this subject is in the test at `position` after `hours_on_task` of tracking.
/// Learning: the unlearned excess u raises the remnant by (1 + u), lowers the error gain by
/// 1/(1 + u) and lengthens the delay by a quarter of u (people first track hesitantly).
/// Fatigue f = fatigue_per_hour·hours raises the remnant by f and the delay by f/2.
pub fn operator(d: &SubjectDraw, position: u32, hours_on_task: f64) -> OperatorParams {
    let u = unlearned(d, position);
    let f = d.fatigue_per_hour * hours_on_task.max(0.0);
    OperatorParams {
        reaction_delay_s: (d.reaction_delay_s * (1.0 + 0.25 * u + 0.5 * f))
            .min(bounds::REACTION_DELAY_S.1),
        neuromuscular_w: d.neuromuscular_w_rad_s,
        neuromuscular_zeta: d.neuromuscular_zeta,
        error_gain: d.error_gain / (1.0 + u),
        error_integral_gain: d.error_integral_gain_1_s,
        remnant_std_mm: (d.remnant_std_mm * (1.0 + u + f)).min(bounds::REMNANT_STD_MM.1),
        shake_aversion_per_mm: d.shake_aversion_per_mm,
        grip_stiffening_per_m_s2: d.grip_stiffening_per_m_s2,
        vibration_remnant_per_m_s2: d.vibration_remnant_per_m_s2,
        vibration_slowing_per_m_s2: d.vibration_slowing_per_m_s2,
        vibration_regression_per_m_s2: d.vibration_regression_per_m_s2,
        motor_noise_mm: (d.motor_noise_mm * (1.0 + u + f)).min(bounds::MOTOR_NOISE_MM.1),
    }
}

/// What a subject takes away from a test: how far off the target they were, how much the
/// seat shook, how quickly the machine answered their hand, and how much the cylinder shook
/// on the display.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Perception {
    /// RMS of target − cylinder position (mm).
    pub rms_error_mm: f64,
    /// RMS cab acceleration felt (m/s²): 0 at the desk.
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
        Seat::On => rms(&mut cab_accel[..n].iter().map(|&a| f64::from(a))) * 1e-3,
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
    felt_rms_m_s2: 0.19,
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
    use crate::closed_loop::LoopSetup;
    use crate::compensator::study_spec;
    use crate::params::{LoopParams, PlantParams};
    use crate::simulate::{SignalKind, SimConfig, simulate};
    use bdft_protocol::params::{CompensatorKind, StepParams};

    /// Every spread of a draw with its configured distribution and bounds.
    fn spreads(pop: &PopulationParams, d: &SubjectDraw) -> Vec<(&'static str, Spread, f64)> {
        vec![
            ("reaction_delay_s", pop.reaction_delay_s, d.reaction_delay_s),
            (
                "neuromuscular_w",
                pop.neuromuscular_w,
                d.neuromuscular_w_rad_s,
            ),
            (
                "neuromuscular_zeta",
                pop.neuromuscular_zeta,
                d.neuromuscular_zeta,
            ),
            ("error_gain", pop.error_gain, d.error_gain),
            (
                "error_integral_gain",
                pop.error_integral_gain,
                d.error_integral_gain_1_s,
            ),
            ("remnant_std_mm", pop.remnant_std_mm, d.remnant_std_mm),
            (
                "shake_aversion",
                pop.shake_aversion_per_mm,
                d.shake_aversion_per_mm,
            ),
            ("learning_excess", pop.learning_excess, d.learning_excess),
            ("learning_tests", pop.learning_tests, d.learning_tests),
            ("fatigue_per_hour", pop.fatigue_per_hour, d.fatigue_per_hour),
            ("body_k_h", pop.body_k_h, d.body_k_h),
            ("torso_f_hz", pop.torso_f_hz, d.torso_f_hz),
            ("torso_zeta", pop.torso_zeta, d.torso_zeta),
            ("arm_f_hz", pop.arm_f_hz, d.arm_f_hz),
            ("arm_zeta", pop.arm_zeta, d.arm_zeta),
            (
                "grip_stiffening",
                pop.grip_stiffening_per_m_s2,
                d.grip_stiffening_per_m_s2,
            ),
            (
                "vibration_remnant",
                pop.vibration_remnant_per_m_s2,
                d.vibration_remnant_per_m_s2,
            ),
            (
                "vibration_slowing",
                pop.vibration_slowing_per_m_s2,
                d.vibration_slowing_per_m_s2,
            ),
            (
                "vibration_regression",
                pop.vibration_regression_per_m_s2,
                d.vibration_regression_per_m_s2,
            ),
        ]
    }

    fn median(mut v: Vec<f64>) -> f64 {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        0.5 * (v[(n - 1) / 2] + v[n / 2])
    }

    #[test]
    fn a_drawn_population_reproduces_its_configured_distributions() {
        // The default spreads are narrow enough that no bound clips more than a few draws,
        // so each parameter's logarithm is normal with the configured median and log-sd.
        let pop = PopulationParams::default();
        let n = 4000;
        let draws: Vec<SubjectDraw> = (0..n).map(|s| draw(&pop, s)).collect();
        let names = spreads(&pop, &draws[0]);
        for (i, (name, spread, _)) in names.iter().enumerate() {
            let logs: Vec<f64> = draws.iter().map(|d| spreads(&pop, d)[i].2.ln()).collect();
            let sigma = spread.log_sd();
            // Sample median of a normal: standard error 1.2533·σ/√n; allow 4 of them.
            let m = median(logs.clone());
            let tol = 4.0 * 1.2533 * sigma / (n as f64).sqrt() + 1e-12;
            assert!(
                (m - spread.median.ln()).abs() < tol,
                "{name}: median {} vs {}",
                m.exp(),
                spread.median
            );
            let mean = logs.iter().sum::<f64>() / n as f64;
            let sd = (logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
            // The sample sd's standard error is σ/√(2(n − 1)); allow 5 of them (a few
            // draws are clipped to the bounds, which narrows it a little).
            assert!(
                (sd - sigma).abs() < 5.0 * sigma / (2.0 * (n - 1) as f64).sqrt(),
                "{name}: log-sd {sd} vs {sigma}"
            );
        }
        let bias: Vec<f64> = draws.iter().map(|d| d.survey_bias_points).collect();
        let sd = (bias.iter().map(|b| b * b).sum::<f64>() / n as f64).sqrt();
        assert!(
            (sd - pop.survey_bias_sd).abs() < 0.05 * pop.survey_bias_sd,
            "{sd}"
        );
        // Seeded: the same seed is the same subject; another seed another one.
        assert_eq!(draw(&pop, 7), draw(&pop, 7));
        assert_ne!(draw(&pop, 7), draw(&pop, 8));
    }

    #[test]
    fn one_spread_changed_moves_no_other_parameter_and_a_preset_body_keeps_the_studys() {
        let pop = PopulationParams::default();
        let wider = PopulationParams {
            error_gain: Spread {
                median: 0.6,
                cv: 0.1,
            },
            body: BodySource::Preset,
            ..pop
        };
        let (a, b) = (draw(&pop, 3), draw(&wider, 3));
        assert_ne!(a.error_gain, b.error_gain);
        assert_eq!(a.reaction_delay_s, b.reaction_delay_s);
        assert_eq!(a.remnant_std_mm, b.remnant_std_mm);
        assert_eq!(a.survey_bias_points, b.survey_bias_points);
        assert_eq!(b.body_k_h, 0.0);
        let preset = BodyModel::RigidMass { k_h: 0.56 };
        assert_eq!(body(&b, preset), preset);
        assert!(matches!(body(&a, preset), BodyModel::Seated { k_h, .. } if k_h == a.body_k_h));
        // Everyone the median: cv = 0.
        let same = PopulationParams {
            reaction_delay_s: Spread {
                median: 0.3,
                cv: 0.0,
            },
            ..pop
        };
        assert_eq!(draw(&same, 1).reaction_delay_s, 0.3);
        assert_eq!(draw(&same, 2).reaction_delay_s, 0.3);
    }

    /// Everyone the population's median person.
    fn median_subject() -> SubjectDraw {
        let mut pop = PopulationParams::default();
        for s in [
            &mut pop.reaction_delay_s,
            &mut pop.neuromuscular_w,
            &mut pop.neuromuscular_zeta,
            &mut pop.error_gain,
            &mut pop.error_integral_gain,
            &mut pop.remnant_std_mm,
            &mut pop.shake_aversion_per_mm,
            &mut pop.learning_excess,
            &mut pop.learning_tests,
            &mut pop.fatigue_per_hour,
            &mut pop.body_k_h,
            &mut pop.torso_f_hz,
            &mut pop.torso_zeta,
            &mut pop.arm_f_hz,
            &mut pop.arm_zeta,
            &mut pop.grip_stiffening_per_m_s2,
            &mut pop.vibration_remnant_per_m_s2,
            &mut pop.vibration_slowing_per_m_s2,
            &mut pop.vibration_regression_per_m_s2,
        ] {
            s.cv = 0.0;
        }
        pop.survey_bias_sd = 0.0;
        draw(&pop, 1)
    }

    /// Mean-squared tracking error of `d` in the test at `position` with `kind` at `seat`,
    /// over the same `seeds` of target and noise.
    fn mse(
        d: &SubjectDraw,
        kind: CompensatorKind,
        seat: Seat,
        position: u32,
        seeds: &[u64],
    ) -> f64 {
        let plant = PlantParams::default();
        let mut total = 0.0;
        for &seed in seeds {
            let cfg = SimConfig {
                setup: LoopSetup {
                    plant,
                    body: body(d, BodyModel::default()),
                    loop_params: LoopParams {
                        k_bf: 0.78,
                        ..LoopParams::default()
                    },
                    station: seat,
                    compensator: study_spec(kind, &plant),
                },
                signal: SignalKind::Steps,
                duration_s: 140.0,
                seed,
                operator: operator(d, position, 0.0),
                steps: StepParams::default(),
                max_cab_rms_mm_s2: None,
            };
            total += simulate(&cfg, |_| {}).unwrap().mse_tracking_mm2;
        }
        total / seeds.len() as f64
    }

    #[test]
    fn feedthrough_degrades_tracking_on_the_machine_over_the_pool() {
        // Eight drawn subjects, each with the same targets and noise on the machine and at
        // the desk. On the machine the body feeds cab motion back into the device; the slow
        // part of it the operator sees and corrects, the part near the cab modes passes
        // uncorrected, and the felt vibration slows the operator. Over the pool the error is
        // larger on the machine with every compensator.
        let pooled = |body: BodySource| {
            let pop = PopulationParams {
                body,
                ..PopulationParams::default()
            };
            let subjects: Vec<SubjectDraw> = (0..8).map(|s| draw(&pop, 1000 + s)).collect();
            let mut log_ratio = [0.0; 5];
            for (k, kind) in CompensatorKind::STUDY.iter().copied().enumerate() {
                for (i, d) in subjects.iter().enumerate() {
                    let seeds = [100 + i as u64];
                    let on = mse(d, kind, Seat::On, 5, &seeds);
                    let off = mse(d, kind, Seat::Off, 5, &seeds);
                    log_ratio[k] += (on / off).ln() / 8.0;
                }
            }
            log_ratio
        };
        let seated = pooled(BodySource::Drawn);
        assert!(seated.iter().all(|&r| r > 0.0), "log on/off: {seated:?}");
        // The thesis's rigid mass passes static cab motion on, a brake on the delayed
        // correction: the same subjects lose less on the machine with it.
        let rigid = pooled(BodySource::Preset);
        assert!(
            rigid.iter().zip(&seated).all(|(r, s)| r < s),
            "log on/off: rigid {rigid:?}, seated {seated:?}"
        );
    }

    #[test]
    fn learning_lowers_the_error_over_the_tests_and_fatigue_raises_it() {
        let d = SubjectDraw {
            learning_excess: 1.0,
            learning_tests: 3.0,
            ..median_subject()
        };
        // The unlearned excess decays by e every `learning_tests` tests.
        assert!((unlearned(&d, 0) - 1.0).abs() < 1e-12);
        assert!((unlearned(&d, 3) - (-1.0f64).exp()).abs() < 1e-12);
        let seeds = [21, 22];
        let first = mse(&d, CompensatorKind::Pid, Seat::Off, 1, &seeds);
        let tenth = mse(&d, CompensatorKind::Pid, Seat::Off, 10, &seeds);
        assert!(
            tenth < first,
            "position 10: {tenth:.2} vs position 1: {first:.2}"
        );
        let rested = operator(&d, 10, 0.0);
        let tired = operator(&d, 10, 1.0);
        assert!(tired.remnant_std_mm > rested.remnant_std_mm);
        assert!(tired.reaction_delay_s > rested.reaction_delay_s);
    }

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
        assert!((p.felt_rms_m_s2 - 2.0).abs() < 0.01, "{}", p.felt_rms_m_s2);
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
