//! The operator's seat-to-hand dynamics: how cab motion becomes unwanted hand motion h.

use crate::filters::Biquad;
use crate::params::BodyModel;
use crate::state::LinearState;
use std::f64::consts::PI;

/// A body model ready to run at the loop rate.
#[derive(Debug, Clone)]
pub struct Body {
    pub(crate) model: BodyModel,
    pub(crate) dt: f64,
    /// Present for models with dynamics; the rigid mass is a pure gain. For the seated body
    /// the torso's transmissibility.
    pub(crate) filter: Option<Biquad>,
    /// The seated body's arm on the device (hand per torso motion).
    pub(crate) arm: Option<Biquad>,
    /// The arm's frequency now as a multiple of the model's (the grip: 1 = relaxed).
    pub(crate) grip: f64,
}

/// The base-excitation transmissibility k·(2ζωs + ω²)/(s² + 2ζωs + ω²), pre-warped at its
/// peak.
pub(crate) fn transmissibility(k: f64, f_hz: f64, zeta: f64, dt: f64) -> Biquad {
    let w = 2.0 * PI * f_hz;
    Biquad::tustin(
        [0.0, k * 2.0 * zeta * w, k * w * w],
        [1.0, 2.0 * zeta * w, w * w],
        dt,
        Some(w),
    )
}

impl Body {
    pub fn new(model: BodyModel, dt: f64) -> Self {
        let (filter, arm) = match model {
            BodyModel::RigidMass { .. } => (None, None),
            BodyModel::SingleResonance { k_h, f_hz, zeta } => {
                (Some(transmissibility(k_h, f_hz, zeta, dt)), None)
            }
            BodyModel::Seated {
                torso_f_hz,
                torso_zeta,
                arm_f_hz,
                arm_zeta,
                ..
            } => (
                Some(transmissibility(1.0, torso_f_hz, torso_zeta, dt)),
                Some(transmissibility(1.0, arm_f_hz, arm_zeta, dt)),
            ),
        };
        Self {
            model,
            dt,
            filter,
            arm,
            grip: 1.0,
        }
    }

    /// Stiffens (or relaxes) the seated body's grip: the arm's frequency becomes `grip` times
    /// the model's. The filter's state is kept, so a slowly changing grip moves smoothly.
    /// Other bodies have no grip to change. Allocation-free: callable from the tick.
    pub fn set_grip(&mut self, grip: f64) {
        if let (
            Some(arm),
            BodyModel::Seated {
                arm_f_hz, arm_zeta, ..
            },
        ) = (&mut self.arm, self.model)
        {
            if grip != self.grip && grip.is_finite() && grip > 0.0 {
                self.grip = grip;
                arm.retune(&transmissibility(1.0, arm_f_hz * grip, arm_zeta, self.dt));
            }
        }
    }

    pub fn model(&self) -> BodyModel {
        self.model
    }

    /// Hand displacement (mm) forced by the cab displacement x_c (mm).
    #[inline]
    pub fn step(&mut self, cab_displacement: f64) -> f64 {
        match (&mut self.filter, &mut self.arm, self.model) {
            (Some(torso), Some(arm), BodyModel::Seated { k_h, .. }) => {
                let hand = arm.step(torso.step(cab_displacement));
                k_h * (cab_displacement - hand)
            }
            (Some(f), _, _) => f.step(cab_displacement),
            (None, _, BodyModel::RigidMass { k_h }) => k_h * cab_displacement,
            (None, _, _) => unreachable!("models with dynamics always have a filter"),
        }
    }

    pub fn reset(&mut self) {
        for f in [&mut self.filter, &mut self.arm].into_iter().flatten() {
            f.reset();
        }
    }
}

impl LinearState for Body {
    fn state_len(&self) -> usize {
        [&self.filter, &self.arm]
            .into_iter()
            .flatten()
            .map(|f| f.state_len())
            .sum()
    }
    fn read_state(&self, out: &mut [f64]) {
        let mut at = 0;
        for f in [&self.filter, &self.arm].into_iter().flatten() {
            f.read_state(&mut out[at..]);
            at += f.state_len();
        }
    }
    fn write_state(&mut self, s: &[f64]) {
        let mut at = 0;
        for f in [&mut self.filter, &mut self.arm].into_iter().flatten() {
            f.write_state(&s[at..]);
            at += f.state_len();
        }
    }
}

/// A typical seated body (torso 1.1 Hz, arm 2.5 Hz, the thesis's K_H) for the tests that run
/// every body model.
#[cfg(test)]
pub(crate) const SEATED_FOR_TESTS: BodyModel = BodyModel::Seated {
    k_h: 0.56,
    torso_f_hz: 1.1,
    torso_zeta: 0.4,
    arm_f_hz: 2.5,
    arm_zeta: 0.35,
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rigid_mass_is_a_gain_and_resonant_body_amplifies_at_its_frequency() {
        let mut rigid = Body::new(BodyModel::RigidMass { k_h: 0.56 }, 1e-3);
        assert!((rigid.step(10.0) - 5.6).abs() < 1e-12);
        let (k_h, f_hz, zeta) = (0.5, 5.0, 0.3);
        let body = Body::new(BodyModel::SingleResonance { k_h, f_hz, zeta }, 1e-3);
        let w = 2.0 * PI * f_hz;
        let h = body.filter.unwrap().response(w, 1e-3).norm();
        // |(2ζωjω + ω²)/(−ω² + 2ζωjω + ω²)| at ω = √(1 + 4ζ²)/(2ζ).
        let want = k_h * (1.0 + 4.0 * zeta * zeta).sqrt() / (2.0 * zeta);
        assert!((h - want).abs() < 1e-9, "{h} vs {want}");
        assert!((body.filter.unwrap().response(0.0, 1e-3).norm() - k_h).abs() < 1e-12);
    }

    /// h/x_c of a running body at ω, measured by driving it with a sine and fitting the
    /// steady-state output (least squares on sin and cos over whole periods).
    fn measured_response(body: &mut Body, w: f64, dt: f64) -> nalgebra::Complex<f64> {
        body.reset();
        let period = (2.0 * PI / w / dt).round() as usize;
        let settle = 40 * period;
        let (mut s, mut c) = (0.0, 0.0);
        for k in 0..settle + 20 * period {
            let t = k as f64 * dt;
            let h = body.step((w * t).sin());
            if k >= settle {
                s += h * (w * t).sin();
                c += h * (w * t).cos();
            }
        }
        let n = (20 * period) as f64 / 2.0;
        nalgebra::Complex::new(s / n, c / n)
    }

    #[test]
    fn a_seated_body_passes_no_static_cab_motion_and_tends_to_the_rigid_mass_above_its_peaks() {
        // h/x_c = k_h·(1 − T·A), each a base-excitation transmissibility
        // (2ζωs + ω²)/(s² + 2ζωs + ω²): the analytic value at s = jω.
        let (k_h, ft, zt, fa, za) = (0.56, 1.1, 0.4, 2.5, 0.35);
        let model = BodyModel::Seated {
            k_h,
            torso_f_hz: ft,
            torso_zeta: zt,
            arm_f_hz: fa,
            arm_zeta: za,
        };
        let dt = 1e-3;
        let mut body = Body::new(model, dt);
        let tr = |s: nalgebra::Complex<f64>, f: f64, z: f64| {
            let w = 2.0 * PI * f;
            (s * (2.0 * z * w) + w * w) / (s * s + s * (2.0 * z * w) + w * w)
        };
        for f_hz in [0.5, 1.0, 4.0, 6.2] {
            let w = 2.0 * PI * f_hz;
            let s = nalgebra::Complex::new(0.0, w);
            let want = (nalgebra::Complex::from(1.0) - tr(s, ft, zt) * tr(s, fa, za)) * k_h;
            let got = measured_response(&mut body, w, dt);
            assert!(
                (got - want).norm() < 0.01 * want.norm().max(0.05),
                "{f_hz} Hz: {got} vs {want}"
            );
        }
        // A steady cab offset leaves the hand where the device is: no feedthrough.
        body.reset();
        let h = (0..20_000).map(|_| body.step(10.0)).last().unwrap();
        assert!(h.abs() < 1e-9, "{h}");
        // Far above both peaks the hand stays behind: the rigid mass k_h·x_c.
        let got = measured_response(&mut body, 2.0 * PI * 60.0, dt);
        assert!((got.norm() - k_h).abs() < 0.01, "{got}");
    }

    #[test]
    fn a_stiffer_grip_raises_the_arm_frequency_and_a_relaxed_one_restores_it() {
        let model = SEATED_FOR_TESTS;
        let dt = 1e-3;
        let mut body = Body::new(model, dt);
        let stiff = Body::new(
            BodyModel::Seated {
                k_h: 0.56,
                torso_f_hz: 1.1,
                torso_zeta: 0.4,
                arm_f_hz: 2.5 * 1.4,
                arm_zeta: 0.35,
            },
            dt,
        );
        body.set_grip(1.4);
        assert_eq!(
            body.arm.unwrap().coefficients(),
            stiff.arm.unwrap().coefficients()
        );
        body.set_grip(1.0);
        assert_eq!(
            body.arm.unwrap().coefficients(),
            Body::new(model, dt).arm.unwrap().coefficients()
        );
        // A rigid mass has no grip to change.
        let mut rigid = Body::new(BodyModel::default(), dt);
        rigid.set_grip(2.0);
        assert!((rigid.step(1.0) - 0.56).abs() < 1e-12);
    }
}
