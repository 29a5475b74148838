//! Valve/cylinder and structure as one 7-state linear system plus the rig's nonlinearities.
//!
//! States x = [x_c, ẋ_c, ẍ_c, x⃛_c, y, ẏ, ÿ]: the cab displacement and three derivatives, then
//! the cylinder position and two derivatives. Writing the structure in derivatives of x_c
//! driven by y, ẏ, ÿ realizes the transmissibility X_c/Y = K_S·N(s)/D(s) exactly, and makes
//! the cab acceleration a state (no direct feedthrough from the input).

use nalgebra::{SMatrix, SVector};

use crate::error::ParamError;
use crate::linalg::zoh;
use crate::params::PlantParams;
use crate::rng::Rng;
use crate::state::LinearState;

/// Indices into the plant state.
pub mod idx {
    pub const XC: usize = 0;
    pub const XC_D: usize = 1;
    pub const XC_DD: usize = 2;
    pub const Y: usize = 4;
    pub const Y_D: usize = 5;
    pub const Y_DD: usize = 6;
}

pub type PlantMatrix = SMatrix<f64, 7, 7>;
pub type PlantVector = SVector<f64, 7>;

/// What the rig's sensors report each tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Measurement {
    /// Cylinder position (mm about mid-stroke).
    pub y: f64,
    /// Seat accelerometer, fore-aft (mm/s²), including its noise.
    pub cab_accel: f64,
}

/// D(s) = s⁴ + a₃s³ + a₂s² + a₁s + a₀ and N(s) = b₂s² + b₁s + b₀ of the structure's
/// transmissibility X_c/Y = K_S·N/D, as ([a₀..a₃], [b₀..b₂]).
pub fn structure_polynomials(p: &PlantParams) -> ([f64; 4], [f64; 3]) {
    let [w1, w2] = p.mode_omegas();
    let (c1, c2) = (2.0 * p.z1 * w1, 2.0 * p.z2 * w2);
    let (k1, k2) = (w1 * w1, w2 * w2);
    // (s² + c1 s + k1)(s² + c2 s + k2)
    let den = [k1 * k2, c1 * k2 + c2 * k1, k1 + k2 + c1 * c2, c1 + c2];
    // (c1 s + k1)(c2 s + k2)
    let num = [k1 * k2, c1 * k2 + c2 * k1, c1 * c2];
    (den, num)
}

/// Builds A with the valve/cylinder row given by `cyl_row` = (coefficient of ẏ, of ÿ).
fn plant_matrix(p: &PlantParams, y_d_coeff: f64) -> PlantMatrix {
    let (den, num) = structure_polynomials(p);
    let mut a = PlantMatrix::zeros();
    a[(0, 1)] = 1.0;
    a[(1, 2)] = 1.0;
    a[(2, 3)] = 1.0;
    for i in 0..4 {
        a[(3, i)] = -den[i];
    }
    for i in 0..3 {
        a[(3, idx::Y + i)] = p.k_s * num[i];
    }
    a[(4, 5)] = 1.0;
    a[(5, 6)] = 1.0;
    a[(6, idx::Y_D)] = y_d_coeff;
    a[(6, idx::Y_DD)] = -2.0 * p.z_vc * p.w_vc;
    a
}

/// The physical plant, input the valve command V:
/// y⃛ = −ω²ẏ − 2ζωÿ + K_VC ω² V.
pub fn continuous_plant(p: &PlantParams) -> (PlantMatrix, PlantVector) {
    let w2 = p.w_vc * p.w_vc;
    let mut b = PlantVector::zeros();
    b[idx::Y_DD] = p.k_vc * w2;
    (plant_matrix(p, -w2), b)
}

/// The LQR design model: the cylinder under an inner proportional velocity loop
/// V = K_P(u − ẏ) with loop gain `kk` = K_P·K_VC, input the velocity reference u:
/// y⃛ = −(1 + kk)ω²ẏ − 2ζωÿ + kk ω² u.
pub fn design_model(p: &PlantParams, kk: f64) -> (PlantMatrix, PlantVector) {
    let w2 = p.w_vc * p.w_vc;
    let mut b = PlantVector::zeros();
    b[idx::Y_DD] = kk * w2;
    (plant_matrix(p, -(1.0 + kk) * w2), b)
}

/// Valve command as the valve sees it: saturated to ±v_max, and a non-finite request (a bug
/// or a corrupted message upstream) becomes zero rather than full travel.
#[inline]
pub fn saturate(v: f64, v_max: f64) -> f64 {
    if v.is_finite() {
        v.clamp(-v_max, v_max)
    } else {
        0.0
    }
}

/// The simulated rig: the discretized plant with valve saturation and dead-band, hard stroke
/// limits and a noisy accelerometer.
#[derive(Debug, Clone)]
pub struct Plant {
    ad: PlantMatrix,
    bd: PlantVector,
    x: PlantVector,
    params: PlantParams,
    dt: f64,
    pub(crate) noise: Rng,
    /// The engine tone's phase (rad), advanced once per step.
    pub(crate) engine_phase: f64,
}

/// The engine's vibration in the accelerometer's reading at `phase`: a tone of
/// `engine_vibration_rms` (mm/s² RMS).
#[inline]
pub(crate) fn engine(p: &PlantParams, phase: f64) -> f64 {
    p.engine_vibration_rms * std::f64::consts::SQRT_2 * phase.sin()
}

/// The engine tone's phase one step of `dt` after `phase`, kept in [0, 2π) so its sine stays
/// exact over hours.
#[inline]
pub(crate) fn engine_advance(p: &PlantParams, phase: f64, dt: f64) -> f64 {
    let next = phase + std::f64::consts::TAU * p.engine_hz * dt;
    if next >= std::f64::consts::TAU {
        next - std::f64::consts::TAU
    } else {
        next
    }
}

impl Plant {
    pub fn new(params: PlantParams, dt: f64, noise_seed: u64) -> Result<Self, ParamError> {
        params.validate()?;
        let (a, b) = continuous_plant(&params);
        let (ad, bd) = zoh(
            &nalgebra::DMatrix::from_column_slice(7, 7, a.as_slice()),
            &nalgebra::DMatrix::from_column_slice(7, 1, b.as_slice()),
            dt,
        );
        Ok(Self {
            ad: PlantMatrix::from_column_slice(ad.as_slice()),
            bd: PlantVector::from_column_slice(bd.as_slice()),
            x: PlantVector::zeros(),
            params,
            dt,
            noise: Rng::new(noise_seed),
            engine_phase: 0.0,
        })
    }

    pub fn params(&self) -> &PlantParams {
        &self.params
    }

    /// The machine changing under a running loop (a load picked up mid-test): the same state,
    /// noise and engine tone, the dynamics of `params` from the next step.
    #[cfg(test)]
    pub(crate) fn changed_to(&self, params: PlantParams) -> Result<Self, ParamError> {
        Ok(Self {
            x: self.x,
            noise: self.noise,
            engine_phase: self.engine_phase,
            ..Self::new(params, self.dt, 0)?
        })
    }

    /// The sample period it was discretized at (s).
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The discrete transition matrices (Ad, Bd).
    pub fn discrete(&self) -> (&PlantMatrix, &PlantVector) {
        (&self.ad, &self.bd)
    }

    /// Sensor readings at the current instant.
    pub fn measure(&mut self) -> Measurement {
        let noise = if self.params.accel_noise_std > 0.0 {
            self.params.accel_noise_std * self.noise.normal()
        } else {
            0.0
        };
        Measurement {
            y: self.x[idx::Y],
            cab_accel: self.x[idx::XC_DD] + noise + engine(&self.params, self.engine_phase),
        }
    }

    /// True cab displacement x_c (what moves the operator's body).
    pub fn cab_displacement(&self) -> f64 {
        self.x[idx::XC]
    }

    pub fn state(&self) -> &PlantVector {
        &self.x
    }

    /// Advances one sample with valve command `v` held; returns the command actually applied.
    pub fn step(&mut self, v: f64) -> f64 {
        let p = &self.params;
        let mut v = saturate(v, p.v_max);
        if v.abs() <= p.dead_band {
            v = 0.0;
        } else {
            v -= p.dead_band.copysign(v);
        }
        self.x = self.ad * self.x + self.bd * v;
        self.engine_phase = engine_advance(&self.params, self.engine_phase, self.dt);
        // Hard end stops: the piston stops dead; motion away from the stop is still allowed.
        let s = p.stroke_mm;
        let y = self.x[idx::Y];
        if y.abs() > s {
            let dir = y.signum();
            self.x[idx::Y] = s * dir;
            for i in [idx::Y_D, idx::Y_DD] {
                if self.x[i] * dir > 0.0 {
                    self.x[i] = 0.0;
                }
            }
        }
        v
    }
}

impl LinearState for Plant {
    fn state_len(&self) -> usize {
        7
    }
    fn read_state(&self, out: &mut [f64]) {
        out[..7].copy_from_slice(self.x.as_slice());
    }
    fn write_state(&mut self, s: &[f64]) {
        self.x.copy_from_slice(&s[..7]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::{matrix, reference};

    #[test]
    fn continuous_and_zoh_matrices_match_scipy() {
        let fx = &reference()["plant_zoh"];
        let p = PlantParams::default();
        let (a, b) = continuous_plant(&p);
        let want_a = matrix(&fx["A"]);
        let want_b = matrix(&fx["B"]);
        for i in 0..7 {
            for j in 0..7 {
                let w = want_a[(i, j)];
                assert!(
                    (a[(i, j)] - w).abs() <= 1e-9 * w.abs().max(1.0),
                    "A[{i},{j}]"
                );
            }
            assert!((b[i] - want_b[(i, 0)]).abs() <= 1e-9 * want_b[(i, 0)].abs().max(1.0));
        }
        let plant = Plant::new(p, 1e-3, 0).unwrap();
        let (ad, bd) = plant.discrete();
        let want_ad = matrix(&fx["Ad"]);
        let want_bd = matrix(&fx["Bd"]);
        for i in 0..7 {
            for j in 0..7 {
                let w = want_ad[(i, j)];
                assert!(
                    (ad[(i, j)] - w).abs() <= 1e-9 * w.abs().max(1e-3),
                    "Ad[{i},{j}] {} vs {w}",
                    ad[(i, j)]
                );
            }
            let w = want_bd[(i, 0)];
            assert!(
                (bd[i] - w).abs() <= 1e-9 * w.abs().max(1e-6),
                "Bd[{i}] {} vs {w}",
                bd[i]
            );
        }
    }

    #[test]
    fn zoh_is_step_invariant() {
        // The defining property of ZOH: the discrete step response equals the continuous one
        // at the sample instants. Check y(t) for a unit valve step against a fine-step
        // integration of the continuous model (RK4 at dt/100).
        let p = PlantParams {
            accel_noise_std: 0.0,
            ..PlantParams::default()
        };
        let dt = 1e-3;
        let mut plant = Plant::new(p, dt, 0).unwrap();
        let (a, b) = continuous_plant(&p);
        let f = |x: &PlantVector| a * x + b * 1.0;
        let mut x = PlantVector::zeros();
        let h = dt / 100.0;
        for _ in 0..200 {
            plant.step(1.0);
            for _ in 0..100 {
                let k1 = f(&x);
                let k2 = f(&(x + k1 * (h / 2.0)));
                let k3 = f(&(x + k2 * (h / 2.0)));
                let k4 = f(&(x + k3 * h));
                x += (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
            }
            for i in 0..7 {
                let tol = 1e-7 * x[i].abs().max(1e-3);
                assert!(
                    (plant.state()[i] - x[i]).abs() < tol,
                    "state {i}: {} vs {}",
                    plant.state()[i],
                    x[i]
                );
            }
        }
    }

    #[test]
    fn structure_has_the_identified_modes_and_static_gain() {
        let p = PlantParams::default();
        let (den, num) = structure_polynomials(&p);
        // Static transmissibility K_S·b₀/a₀ = K_S (the cab follows slow boom motion).
        assert!((p.k_s * num[0] / den[0] - p.k_s).abs() < 1e-12);
        let (a, _) = continuous_plant(&p);
        let ev =
            crate::linalg::eigenvalues(&nalgebra::DMatrix::from_column_slice(7, 7, a.as_slice()))
                .unwrap();
        for (f, z) in [(p.f1_hz, p.z1), (p.f2_hz, p.z2)] {
            let w = 2.0 * std::f64::consts::PI * f;
            let want = nalgebra::Complex::new(-z * w, w * (1.0 - z * z).sqrt());
            assert!(
                ev.iter().any(|e| (e - want).norm() < 1e-8 * w),
                "mode {f} Hz missing: {ev:?}"
            );
        }
    }

    #[test]
    fn valve_saturates_and_rejects_non_finite_commands() {
        assert_eq!(saturate(25.0, 10.0), 10.0);
        assert_eq!(saturate(-25.0, 10.0), -10.0);
        assert_eq!(saturate(f64::NAN, 10.0), 0.0);
        assert_eq!(saturate(f64::INFINITY, 10.0), 0.0);
        let p = PlantParams {
            dead_band: 0.5,
            ..PlantParams::default()
        };
        let mut plant = Plant::new(p, 1e-3, 0).unwrap();
        assert_eq!(plant.step(0.4), 0.0);
        assert_eq!(plant.step(2.0), 1.5);
        assert_eq!(plant.step(1e9), 9.5);
    }

    #[test]
    fn stroke_limits_hold_the_cylinder() {
        let p = PlantParams {
            accel_noise_std: 0.0,
            ..PlantParams::default()
        };
        let mut plant = Plant::new(p, 1e-3, 0).unwrap();
        for _ in 0..3000 {
            plant.step(10.0); // 220 mm/s for 3 s would travel 660 mm
            assert!(plant.state()[idx::Y] <= p.stroke_mm);
        }
        assert_eq!(plant.state()[idx::Y], p.stroke_mm);
        // It comes back off the stop when commanded.
        for _ in 0..200 {
            plant.step(-10.0);
        }
        assert!(plant.state()[idx::Y] < p.stroke_mm - 10.0);
    }

    #[test]
    fn accelerometer_noise_is_seeded() {
        let p = PlantParams::default();
        let mut a = Plant::new(p, 1e-3, 9).unwrap();
        let mut b = Plant::new(p, 1e-3, 9).unwrap();
        let mut c = Plant::new(p, 1e-3, 10).unwrap();
        let (ma, mb, mc) = (a.measure(), b.measure(), c.measure());
        assert_eq!(ma, mb);
        assert_ne!(ma, mc);
    }
}
