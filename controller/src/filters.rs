//! Discrete filters made from continuous prototypes by the bilinear (Tustin) transform,
//! pre-warped where one frequency must map exactly (a notch centre, a body resonance).
//!
//! Both sections use the transposed direct form II: the fewest states (one per order), and
//! those states are what [`LinearState`] exposes to the analysis.

use nalgebra::Complex;

use crate::state::LinearState;

/// The Tustin substitution s = c·(1 − z⁻¹)/(1 + z⁻¹). Plain Tustin has c = 2/dt; pre-warping
/// at ω makes the discrete response at ω equal the continuous one: c = ω / tan(ω·dt/2).
fn tustin_constant(dt: f64, prewarp: Option<f64>) -> f64 {
    match prewarp {
        Some(w) if w > 0.0 => w / (w * dt / 2.0).tan(),
        _ => 2.0 / dt,
    }
}

/// y[k] = b₀u[k] + b₁u[k−1] − a₁y[k−1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirstOrder {
    pub(crate) b0: f64,
    pub(crate) b1: f64,
    pub(crate) a1: f64,
    pub(crate) z: f64,
}

impl FirstOrder {
    /// Discretizes (n₁s + n₀)/(d₁s + d₀), coefficients given as [n₁, n₀], [d₁, d₀].
    pub fn tustin(num: [f64; 2], den: [f64; 2], dt: f64, prewarp: Option<f64>) -> Self {
        let c = tustin_constant(dt, prewarp);
        let a0 = den[0] * c + den[1];
        Self {
            b0: (num[0] * c + num[1]) / a0,
            b1: (num[1] - num[0] * c) / a0,
            a1: (den[1] - den[0] * c) / a0,
            z: 0.0,
        }
    }

    /// Filtered derivative g·s·ω/(s + ω): a differentiator above which noise is cut at ω.
    pub fn derivative(gain: f64, w: f64, dt: f64) -> Self {
        Self::tustin([gain * w, 0.0], [1.0, w], dt, None)
    }

    /// First-order high-pass s/(s + ω).
    pub fn high_pass(w: f64, dt: f64) -> Self {
        Self::tustin([1.0, 0.0], [1.0, w], dt, None)
    }

    /// Leaky integrator 1/(s + ω): an integrator above ω that cannot drift below it.
    pub fn leaky_integrator(w: f64, dt: f64) -> Self {
        Self::tustin([0.0, 1.0], [1.0, w], dt, None)
    }

    #[inline]
    pub fn step(&mut self, u: f64) -> f64 {
        let y = self.b0 * u + self.z;
        self.z = self.b1 * u - self.a1 * y;
        y
    }

    pub fn reset(&mut self) {
        self.z = 0.0;
    }

    /// Frequency response at ω (rad/s) for sample period dt.
    pub fn response(&self, w: f64, dt: f64) -> Complex<f64> {
        let zi = Complex::from_polar(1.0, -w * dt);
        (Complex::from(self.b0) + zi * self.b1) / (Complex::from(1.0) + zi * self.a1)
    }
}

impl LinearState for FirstOrder {
    fn state_len(&self) -> usize {
        1
    }
    fn read_state(&self, out: &mut [f64]) {
        out[0] = self.z;
    }
    fn write_state(&mut self, s: &[f64]) {
        self.z = s[0];
    }
}

/// y[k] = b₀u[k] + b₁u[k−1] + b₂u[k−2] − a₁y[k−1] − a₂y[k−2].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
    pub(crate) z: [f64; 2],
}

impl Biquad {
    /// Discretizes (n₂s² + n₁s + n₀)/(d₂s² + d₁s + d₀), coefficients highest power first.
    pub fn tustin(num: [f64; 3], den: [f64; 3], dt: f64, prewarp: Option<f64>) -> Self {
        let c = tustin_constant(dt, prewarp);
        let c2 = c * c;
        let expand = |p: [f64; 3]| {
            [
                p[0] * c2 + p[1] * c + p[2],
                2.0 * (p[2] - p[0] * c2),
                p[0] * c2 - p[1] * c + p[2],
            ]
        };
        let n = expand(num);
        let d = expand(den);
        Self {
            b: [n[0] / d[0], n[1] / d[0], n[2] / d[0]],
            a: [d[1] / d[0], d[2] / d[0]],
            z: [0.0; 2],
        }
    }

    /// Numerator [b₀, b₁, b₂] and denominator [1, a₁, a₂] in powers of z⁻¹.
    pub fn coefficients(&self) -> ([f64; 3], [f64; 3]) {
        (self.b, [1.0, self.a[0], self.a[1]])
    }

    #[inline]
    pub fn step(&mut self, u: f64) -> f64 {
        let y = self.b[0] * u + self.z[0];
        self.z[0] = self.b[1] * u - self.a[0] * y + self.z[1];
        self.z[1] = self.b[2] * u - self.a[1] * y;
        y
    }

    /// Takes `other`'s coefficients and keeps this filter's state: a slowly retuned filter
    /// (a stiffening grip) moves on without a jump.
    pub fn retune(&mut self, other: &Biquad) {
        self.b = other.b;
        self.a = other.a;
    }

    pub fn reset(&mut self) {
        self.z = [0.0; 2];
    }

    /// Frequency response at ω (rad/s) for sample period dt.
    pub fn response(&self, w: f64, dt: f64) -> Complex<f64> {
        let z1 = Complex::from_polar(1.0, -w * dt);
        let z2 = z1 * z1;
        (Complex::from(self.b[0]) + z1 * self.b[1] + z2 * self.b[2])
            / (Complex::from(1.0) + z1 * self.a[0] + z2 * self.a[1])
    }
}

impl LinearState for Biquad {
    fn state_len(&self) -> usize {
        2
    }
    fn read_state(&self, out: &mut [f64]) {
        out[..2].copy_from_slice(&self.z);
    }
    fn write_state(&mut self, s: &[f64]) {
        self.z.copy_from_slice(&s[..2]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 1e-3;

    #[test]
    fn prewarped_biquad_matches_the_continuous_response_at_the_warp_frequency() {
        // Resonant low-pass ω²/(s² + 2ζωs + ω²) at 50 Hz: at ω the continuous gain is 1/(2ζ)
        // with phase −90°.
        let w = 2.0 * std::f64::consts::PI * 50.0;
        let zeta = 0.2;
        let f = Biquad::tustin([0.0, 0.0, w * w], [1.0, 2.0 * zeta * w, w * w], DT, Some(w));
        let h = f.response(w, DT);
        assert!((h.norm() - 1.0 / (2.0 * zeta)).abs() < 1e-9, "{h}");
        assert!((h.arg() + std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert!((f.response(0.0, DT).norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn leaky_integrator_integrates_above_its_corner_and_holds_dc() {
        let w = 0.5;
        let f = FirstOrder::leaky_integrator(w, DT);
        // DC gain 1/ω, and |H(jΩ)| ≈ 1/Ω well above the corner.
        assert!((f.response(0.0, DT).norm() - 1.0 / w).abs() < 1e-9);
        let big = 25.0;
        let h = f.response(big, DT).norm();
        assert!((h * big - 1.0).abs() < 1e-3, "{h}");
        // A constant input settles instead of ramping away.
        let mut f = f;
        let mut y = 0.0;
        for _ in 0..100_000 {
            y = f.step(1.0);
        }
        assert!((y - 1.0 / w).abs() < 1e-6);
    }

    #[test]
    fn filtered_derivative_differentiates_a_ramp() {
        let mut d = FirstOrder::derivative(1.0, 300.0, DT);
        let mut out = 0.0;
        for k in 0..1000 {
            out = d.step(3.0 * k as f64 * DT);
        }
        assert!((out - 3.0).abs() < 1e-9, "{out}");
        let mut hp = FirstOrder::high_pass(0.5, DT);
        let mut last = 1.0;
        for _ in 0..100_000 {
            last = hp.step(2.0);
        }
        assert!(last.abs() < 1e-9, "high-pass must remove an offset: {last}");
    }
}
