//! The operator's seat-to-hand dynamics: how cab motion becomes unwanted hand motion h.

use crate::filters::Biquad;
use crate::params::BodyModel;
use crate::state::LinearState;
use std::f64::consts::PI;

/// A body model ready to run at the loop rate.
#[derive(Debug, Clone)]
pub struct Body {
    model: BodyModel,
    /// Present for models with dynamics; the rigid mass is a pure gain.
    filter: Option<Biquad>,
}

impl Body {
    pub fn new(model: BodyModel, dt: f64) -> Self {
        let filter = match model {
            BodyModel::RigidMass { .. } => None,
            BodyModel::SingleResonance { k_h, f_hz, zeta } => {
                let w = 2.0 * PI * f_hz;
                Some(Biquad::tustin(
                    [0.0, k_h * 2.0 * zeta * w, k_h * w * w],
                    [1.0, 2.0 * zeta * w, w * w],
                    dt,
                    Some(w),
                ))
            }
        };
        Self { model, filter }
    }

    pub fn model(&self) -> BodyModel {
        self.model
    }

    /// Hand displacement (mm) forced by the cab displacement x_c (mm).
    #[inline]
    pub fn step(&mut self, cab_displacement: f64) -> f64 {
        match (&mut self.filter, self.model) {
            (Some(f), _) => f.step(cab_displacement),
            (None, BodyModel::RigidMass { k_h }) => k_h * cab_displacement,
            (None, _) => unreachable!("models with dynamics always have a filter"),
        }
    }

    pub fn reset(&mut self) {
        if let Some(f) = &mut self.filter {
            f.reset();
        }
    }
}

impl LinearState for Body {
    fn state_len(&self) -> usize {
        self.filter.as_ref().map_or(0, |f| f.state_len())
    }
    fn read_state(&self, out: &mut [f64]) {
        if let Some(f) = &self.filter {
            f.read_state(out);
        }
    }
    fn write_state(&mut self, s: &[f64]) {
        if let Some(f) = &mut self.filter {
            f.write_state(s);
        }
    }
}

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
}
