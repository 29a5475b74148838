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
    let mut at = |s: &Spread, (lo, hi): (f64, f64)| s.at(rng.normal(), lo, hi);
    let reaction_delay_s = at(&pop.reaction_delay_s, bounds::REACTION_DELAY_S);
    let neuromuscular_w_rad_s = at(&pop.neuromuscular_w, bounds::NEUROMUSCULAR_W);
    let neuromuscular_zeta = at(&pop.neuromuscular_zeta, bounds::NEUROMUSCULAR_ZETA);
    let error_gain = at(&pop.error_gain, bounds::ERROR_GAIN);
    let error_integral_gain_1_s = at(&pop.error_integral_gain, bounds::ERROR_INTEGRAL_GAIN);
    let remnant_std_mm = at(&pop.remnant_std_mm, bounds::REMNANT_STD_MM);
    let shake_aversion_per_mm = at(&pop.shake_aversion_per_mm, bounds::SHAKE_AVERSION_PER_MM);
    let learning_excess = at(&pop.learning_excess, bounds::LEARNING_EXCESS);
    let learning_tests = at(&pop.learning_tests, bounds::LEARNING_TESTS);
    let fatigue_per_hour = at(&pop.fatigue_per_hour, bounds::FATIGUE_PER_HOUR);
    let body_k_h = at(&pop.body_k_h, bounds::BODY_K_H);
    let torso_f_hz = at(&pop.torso_f_hz, bounds::TORSO_F_HZ);
    let torso_zeta = at(&pop.torso_zeta, bounds::TORSO_ZETA);
    let arm_f_hz = at(&pop.arm_f_hz, bounds::ARM_F_HZ);
    let arm_zeta = at(&pop.arm_zeta, bounds::ARM_ZETA);
    let grip_stiffening_per_m_s2 = at(
        &pop.grip_stiffening_per_m_s2,
        bounds::GRIP_STIFFENING_PER_M_S2,
    );
    let survey_bias_points = pop.survey_bias_sd * rng.normal();
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
    }
}

/// What a subject takes away from a test: how far off the target they were, how much the
/// seat shook, how late the machine followed, and how much the cylinder shook on the display.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Perception {
    /// RMS of target − cylinder position (mm).
    pub rms_error_mm: f64,
    /// RMS cab acceleration felt (m/s²): 0 at the desk.
    pub felt_rms_m_s2: f64,
    /// Lag (s) at which the cylinder position best matches the target (cross-correlation,
    /// searched up to 1.5 s in 10 ms steps).
    pub response_lag_s: f64,
    /// RMS of the cylinder's motion above 1.5 Hz (mm): shake seen on the display.
    pub seen_shake_mm: f64,
}

/// Longest response lag searched (s) and its step.
const MAX_LAG_S: f64 = 1.5;
const LAG_STEP_S: f64 = 0.01;

/// What the subject perceived of a test from its record (target, cylinder position and cab
/// acceleration at the loop rate `dt`).
pub fn perceive(target: &[f32], y: &[f32], cab_accel: &[f32], seat: Seat, dt: f64) -> Perception {
    let n = target.len().min(y.len()).min(cab_accel.len());
    if n == 0 {
        return Perception {
            rms_error_mm: 0.0,
            felt_rms_m_s2: 0.0,
            response_lag_s: 0.0,
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
    // The lag: the shift that minimises the mean-squared difference between the delayed
    // target and the cylinder (a cross-correlation that ignores the signals' levels).
    let step = ((LAG_STEP_S / dt).round() as usize).max(1);
    let max = ((MAX_LAG_S / dt).round() as usize).min(n.saturating_sub(1));
    let mut best = (f64::INFINITY, 0usize);
    for lag in (0..=max).step_by(step) {
        let m = n - lag;
        let mse = (0..m)
            .step_by(step)
            .map(|i| (f64::from(target[i]) - f64::from(y[i + lag])).powi(2))
            .sum::<f64>()
            / m.div_ceil(step) as f64;
        if mse < best.0 {
            best = (mse, lag);
        }
    }
    let mut hp = crate::filters::FirstOrder::high_pass(2.0 * std::f64::consts::PI * 1.5, dt);
    let seen_shake_mm = rms(&mut y[..n].iter().map(|&v| hp.step(f64::from(v))));
    Perception {
        rms_error_mm,
        felt_rms_m_s2,
        response_lag_s: best.1 as f64 * dt,
        seen_shake_mm,
    }
}

/// The levels a typical subject calls "middling" for each perceived quantity: a rating sits
/// at the scale's middle when the test was like this, one standard unit higher for each
/// factor `SCALE_FACTOR` better. Calibrated on the default population tracking the
/// published protocol (medians over the five compensators and both seats; docs/synthetic-
/// subjects.md).
pub const MIDDLING: Perception = Perception {
    rms_error_mm: 9.0,
    felt_rms_m_s2: 1.0,
    response_lag_s: 0.45,
    seen_shake_mm: 0.3,
};
/// How many times better (smaller) a quantity must be to raise a rating by one standard
/// unit: (scale − 1)/4 points.
const SCALE_FACTOR: f64 = 2.0;

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
    let speed = better(MIDDLING.response_lag_s, p.response_lag_s.max(0.05));
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
