//! The synthetic subject pool: each synthetic subject draws its own operator, body and
//! survey habits from the study's `PopulationParams` (`draw`) and becomes a slightly
//! different operator from test to test as they learn and tire (`operator`); what they
//! perceive of a test and answer is `perception`'s.
//!
//! Everything is a function of the draw's seed: the same study seed and enrolment index give
//! the same subject forever (`Rng::derive` keeps the streams apart).

use bdft_protocol::params::{BodyModel, BodySource, PopulationParams, Spread, SubjectDraw, bounds};

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
    let vibration_delay_s_per_m_s2 = at(
        &mut rng,
        &pop.vibration_delay_s_per_m_s2,
        bounds::VIBRATION_DELAY_S_PER_M_S2,
    );
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
        vibration_delay_s_per_m_s2,
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
        vibration_delay_s_per_m_s2: d.vibration_delay_s_per_m_s2,
        motor_noise_mm: (d.motor_noise_mm * (1.0 + u + f)).min(bounds::MOTOR_NOISE_MM.1),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::closed_loop::LoopSetup;
    use crate::compensator::study_spec;
    use crate::params::{LoopParams, PlantParams};
    use crate::simulate::{SignalKind, SimConfig, simulate};
    use bdft_protocol::params::{CompensatorKind, Seat, StepParams};

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
                "vibration_delay",
                pop.vibration_delay_s_per_m_s2,
                d.vibration_delay_s_per_m_s2,
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
    pub(crate) fn median_subject() -> SubjectDraw {
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
            &mut pop.vibration_delay_s_per_m_s2,
            &mut pop.motor_noise_mm,
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
                    seat,
                    compensator: study_spec(kind, &plant),
                },
                signal: SignalKind::Steps,
                duration_s: 140.0,
                seed,
                operator: operator(d, position, 0.0),
                steps: StepParams::default(),
                max_cab_rms_mm_s2: None,
                condition: Default::default(),
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
}
