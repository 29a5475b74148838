//! The state-space designs: LQR on the 7-state plant with a full-order observer, without
//! cab feedback (`lqr`, β = 0), with active cab-velocity damping (`lqr-cabvel`) and with cab
//! acceleration feedback (`lqr-cabacc`, for comparison).

use nalgebra::{DMatrix, RowSVector, SMatrix, SVector, Vector2};

use crate::error::DesignError;
use crate::filters::FirstOrder;
use crate::linalg::{CareSolution, care, eigenvalues, place_observer, zoh};
use crate::model::{Measurement, design_model, idx, saturate};
use crate::params::PlantParams;
use crate::state::LinearState;
pub use bdft_protocol::params::{CabOutput, LqrParams, ObserverDesign};

fn cab_state_index(cab: CabOutput) -> usize {
    match cab {
        CabOutput::Velocity => idx::XC_D,
        CabOutput::Acceleration => idx::XC_DD,
    }
}

/// The cab signal as the observer receives it.
#[derive(Debug, Clone)]
pub(crate) enum CabSignal {
    /// Accelerometer → high-pass (offset) → leaky integrator = cab velocity.
    Velocity {
        highpass: FirstOrder,
        leak: FirstOrder,
    },
    Acceleration,
}

/// The continuous-time design, kept for reports and tests.
#[derive(Debug, Clone)]
pub struct LqrDesign {
    /// Design model (input u, the velocity reference).
    pub a: DMatrix<f64>,
    pub b: DMatrix<f64>,
    /// Measured outputs [y; cab].
    pub c: DMatrix<f64>,
    pub x: DMatrix<f64>,
    pub k: DMatrix<f64>,
    pub care_residual: f64,
    pub l: DMatrix<f64>,
    pub nx: DMatrix<f64>,
}

/// The design model (A, B), the measured outputs C and the Riccati solution.
type Regulator = (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, CareSolution);

/// The regulator of `p` with cab weight `beta` on `plant` with its modes scaled by `scale`.
fn regulator(
    p: &LqrParams,
    beta: f64,
    plant: &PlantParams,
    scale: f64,
) -> Result<Regulator, DesignError> {
    let plant = &PlantParams {
        f1_hz: plant.f1_hz * scale,
        f2_hz: plant.f2_hz * scale,
        ..*plant
    };
    let (a, b) = design_model(plant, p.inner_loop_gain);
    let a = DMatrix::from_column_slice(7, 7, a.as_slice());
    let b = DMatrix::from_column_slice(7, 1, b.as_slice());
    let mut c = DMatrix::zeros(2, 7);
    c[(0, idx::Y)] = 1.0;
    c[(1, cab_state_index(p.cab_output))] = 1.0;
    let weighted = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![p.alpha, beta])) * &c;
    let q = weighted.transpose() * &weighted;
    let r = DMatrix::from_element(1, 1, 1.0);
    let sol = care(&a, &b, &q, &r)?;
    Ok((a, b, c, sol))
}

/// Damping ratio of the regulated first mode: the eigenvalue of A − BK whose natural
/// frequency is nearest the first mode's (`plant.f1_hz · scale`).
pub fn first_mode_damping(
    p: &LqrParams,
    beta: f64,
    plant: &PlantParams,
    scale: f64,
) -> Result<f64, DesignError> {
    let (a, b, _, sol) = regulator(p, beta, plant, scale)?;
    let w1 = 2.0 * std::f64::consts::PI * plant.f1_hz * scale;
    eigenvalues(&(&a - &b * &sol.k))?
        .into_iter()
        .filter(|z| z.im > 0.0)
        .min_by(|x, y| (x.norm() - w1).abs().total_cmp(&(y.norm() - w1).abs()))
        .map(|z| -z.re / z.norm())
        .ok_or(DesignError::Singular("no oscillatory closed-loop mode"))
}

/// The cab weight a design made for modes moved up (`design_mode_scale` > 1) uses: β, raised
/// until the regulated first mode is as damped as the design at scale 1 damps it. Why: the
/// same weight on cab velocity damps a higher mode less (ζ 0.178 at scale 1, 0.151, 0.131,
/// 0.115 at 1.1, 1.2, 1.3 for the default cab-velocity design), which cost the scheduled
/// design reduction and margin above the nominal modes; holding the damping takes β about
/// ×1.3^2.5 at 1.3. Below (scale < 1) β is kept: it already damps the mode about as much
/// (0.175, 0.188, 0.199 at 0.7, 0.8, 0.9), and the designs there are today's.
pub fn held_beta(p: &LqrParams, plant: &PlantParams) -> Result<f64, DesignError> {
    if p.design_mode_scale <= 1.0 || p.beta == 0.0 {
        return Ok(p.beta);
    }
    let zeta = |beta| first_mode_damping(p, beta, plant, p.design_mode_scale);
    let target = first_mode_damping(p, p.beta, plant, 1.0)?;
    if zeta(p.beta)? >= target {
        return Ok(p.beta);
    }
    // ζ rises with β: bisect log β over [β, 64 β] (measured: ≈ 1.3^2.5 ≈ 1.9 at 1.3).
    let (mut lo, mut hi) = (p.beta.ln(), (64.0 * p.beta).ln());
    if zeta(hi.exp())? < target {
        return Ok(hi.exp());
    }
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if zeta(mid.exp())? < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(hi.exp())
}

impl LqrDesign {
    /// The design on `plant` with its structure modes scaled by `p.design_mode_scale`, above 1
    /// with the cab weight raised to hold the first mode's nominal damping (`held_beta`).
    pub fn new(p: &LqrParams, plant: &PlantParams) -> Result<Self, DesignError> {
        let (a, b, c, sol) = regulator(p, held_beta(p, plant)?, plant, p.design_mode_scale)?;
        let l = match p.observer {
            ObserverDesign::Placed => place_observer(&a, &c, &p.observer_poles)?,
            ObserverDesign::Kalman {
                input_noise,
                structure_noise,
                position_noise,
                cab_noise,
            } => {
                // Process noise on the input and on the structure's top derivative (the cab
                // forced): W = q_u·BBᵀ + q_s·e₃e₃ᵀ; measurement noise V = diag(r_y, r_cab).
                let mut w = &b * b.transpose() * input_noise;
                w[(3, 3)] += structure_noise;
                let v = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![
                    position_noise,
                    cab_noise,
                ]));
                kalman_gain(&a, &c, &w, &v)?
            }
        };
        // N̄ method: [A B; C_y 0][N_x; N_u] = [0; 1].
        let mut bordered = DMatrix::zeros(8, 8);
        bordered.view_mut((0, 0), (7, 7)).copy_from(&a);
        bordered.view_mut((0, 7), (7, 1)).copy_from(&b);
        bordered[(7, idx::Y)] = 1.0;
        let mut rhs = nalgebra::DVector::zeros(8);
        rhs[7] = 1.0;
        let n = bordered
            .lu()
            .solve(&rhs)
            .ok_or(DesignError::Singular("[A B; C 0] of the reference scaling"))?;
        Ok(Self {
            nx: DMatrix::from_column_slice(7, 1, &n.as_slice()[..7]),
            a,
            b,
            c,
            x: sol.x,
            k: sol.k,
            care_residual: sol.residual,
            l,
        })
    }
}

/// Steady-state Kalman gain L = PCᵀV⁻¹ of ẋ = Ax + w, z = Cx + v (intensities W, V), with P
/// the stabilizing solution of the dual Riccati equation AP + PAᵀ − PCᵀV⁻¹CP + W = 0, i.e.
/// the LQR equation for (Aᵀ, Cᵀ, W, V), whose gain is Lᵀ.
pub fn kalman_gain(
    a: &DMatrix<f64>,
    c: &DMatrix<f64>,
    w: &DMatrix<f64>,
    v: &DMatrix<f64>,
) -> Result<DMatrix<f64>, DesignError> {
    Ok(care(&a.transpose(), &c.transpose(), w, v)?.k.transpose())
}

/// The running LQR: everything fixed-size, nothing allocated per tick.
#[derive(Debug, Clone)]
pub struct Lqr {
    design: LqrDesign,
    params: LqrParams,
    pub(crate) k: RowSVector<f64, 7>,
    pub(crate) nx: SVector<f64, 7>,
    /// Observer x̂[k+1] = Φx̂[k] + Γ_u u[k] + Γ_z z[k]: the continuous observer
    /// ẋ̂ = (A − LC)x̂ + Bu + Lz discretized by zero-order hold, so its poles are exactly
    /// e^{p·dt} for the placed p.
    pub(crate) phi: SMatrix<f64, 7, 7>,
    pub(crate) gamma_u: SVector<f64, 7>,
    pub(crate) gamma_z: SMatrix<f64, 7, 2>,
    pub(crate) xhat: SVector<f64, 7>,
    pub(crate) rate: FirstOrder,
    pub(crate) cab: CabSignal,
    pub(crate) k_p: f64,
    pub(crate) v_max: f64,
}

impl Lqr {
    pub fn new(p: &LqrParams, plant: &PlantParams, dt: f64) -> Result<Self, DesignError> {
        let design = LqrDesign::new(p, plant)?;
        let ao = &design.a - &design.l * &design.c;
        let mut inputs = DMatrix::zeros(7, 3);
        inputs.view_mut((0, 0), (7, 1)).copy_from(&design.b);
        inputs.view_mut((0, 1), (7, 2)).copy_from(&design.l);
        let (phi, gamma) = zoh(&ao, &inputs, dt);
        Ok(Self {
            k: RowSVector::from_row_slice(design.k.as_slice()),
            nx: SVector::from_column_slice(design.nx.as_slice()),
            phi: SMatrix::from_column_slice(phi.as_slice()),
            gamma_u: SVector::from_column_slice(gamma.column(0).as_slice()),
            gamma_z: SMatrix::from_column_slice(gamma.columns(1, 2).into_owned().as_slice()),
            xhat: SVector::zeros(),
            rate: FirstOrder::derivative(1.0, p.rate_filter_w, dt),
            cab: match p.cab_output {
                CabOutput::Velocity => CabSignal::Velocity {
                    highpass: FirstOrder::high_pass(p.cab_highpass_w, dt),
                    leak: FirstOrder::leaky_integrator(p.cab_leak_w, dt),
                },
                CabOutput::Acceleration => CabSignal::Acceleration,
            },
            k_p: p.inner_loop_gain / plant.k_vc,
            v_max: plant.v_max,
            params: *p,
            design,
        })
    }

    pub fn design(&self) -> &LqrDesign {
        &self.design
    }

    pub fn params(&self) -> &LqrParams {
        &self.params
    }

    /// K_P of the inner velocity loop V = K_P(u − ẏ).
    pub fn inner_gain(&self) -> f64 {
        self.k_p
    }

    #[inline]
    pub fn step(&mut self, r_c: f64, m: Measurement) -> f64 {
        // Bad samples are replaced by zero so they cannot poison the filters and observer;
        // the runtime counts and reports them, the maths only has to stay finite.
        let y = if m.y.is_finite() { m.y } else { 0.0 };
        let a = if m.cab_accel.is_finite() {
            m.cab_accel
        } else {
            0.0
        };
        let r_c = if r_c.is_finite() { r_c } else { 0.0 };
        let y_rate = self.rate.step(y);
        let cab = match &mut self.cab {
            CabSignal::Velocity { highpass, leak } => leak.step(highpass.step(a)),
            CabSignal::Acceleration => a,
        };
        let u = -(self.k * (self.xhat - self.nx * r_c))[0];
        let v = saturate(self.k_p * (u - y_rate), self.v_max);
        // The observer must see the velocity reference the valve actually executed, or a
        // saturated valve would drive the estimate away from the plant (observer windup).
        let u_applied = v / self.k_p + y_rate;
        self.xhat =
            self.phi * self.xhat + self.gamma_u * u_applied + self.gamma_z * Vector2::new(y, cab);
        v
    }

    pub fn reset(&mut self) {
        self.xhat = SVector::zeros();
        self.rate.reset();
        if let CabSignal::Velocity { highpass, leak } = &mut self.cab {
            highpass.reset();
            leak.reset();
        }
    }
}

impl LinearState for Lqr {
    fn state_len(&self) -> usize {
        match self.cab {
            CabSignal::Velocity { .. } => 10,
            CabSignal::Acceleration => 8,
        }
    }
    fn read_state(&self, out: &mut [f64]) {
        out[..7].copy_from_slice(self.xhat.as_slice());
        self.rate.read_state(&mut out[7..]);
        if let CabSignal::Velocity { highpass, leak } = &self.cab {
            highpass.read_state(&mut out[8..]);
            leak.read_state(&mut out[9..]);
        }
    }
    fn write_state(&mut self, s: &[f64]) {
        self.xhat.copy_from_slice(&s[..7]);
        self.rate.write_state(&s[7..]);
        if let CabSignal::Velocity { highpass, leak } = &mut self.cab {
            highpass.write_state(&s[8..]);
            leak.write_state(&s[9..]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensator::{CompensatorKind, CompensatorSpec, default_spec};
    use crate::fixtures::{matrix, reference};
    use crate::linalg::{care_residual, eigenvalues};

    fn params_of(kind: CompensatorKind) -> LqrParams {
        match default_spec(kind, &PlantParams::default()) {
            CompensatorSpec::Lqr { lqr }
            | CompensatorSpec::LqrCabvel { lqr }
            | CompensatorSpec::LqrCabacc { lqr } => lqr,
            _ => unreachable!(),
        }
    }

    #[test]
    fn riccati_solutions_match_scipy_and_have_small_residuals() {
        let plant = PlantParams::default();
        for case in reference()["care"].as_array().unwrap() {
            let kind: CompensatorKind = case["name"].as_str().unwrap().parse().unwrap();
            let p = params_of(kind);
            assert_eq!(
                p.beta,
                case["beta"].as_f64().unwrap(),
                "{kind}: default β differs from the fixture"
            );
            let d = LqrDesign::new(&p, &plant).unwrap();
            let r = DMatrix::from_element(1, 1, 1.0);
            let q = matrix(&case["Q"]);
            assert!(care_residual(&d.a, &d.b, &q, &r, &d.x) < 1e-10, "{kind}");
            let want_k = matrix(&case["K"]);
            let scale = want_k.amax();
            for j in 0..7 {
                // Relative to the largest gain: lqr's cab gains are zero in exact arithmetic.
                assert!(
                    (d.k[(0, j)] - want_k[(0, j)]).abs() < 1e-7 * scale,
                    "{kind} K[{j}] {} vs {}",
                    d.k[(0, j)],
                    want_k[(0, j)]
                );
            }
            let want_x = matrix(&case["X"]);
            assert!((&d.x - &want_x).amax() < 1e-7 * want_x.amax(), "{kind} X");
            let want_nx: Vec<f64> = case["Nx"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            for (j, want) in want_nx.iter().enumerate() {
                assert!((d.nx[(j, 0)] - want).abs() < 1e-12, "{kind} Nx[{j}]");
            }
        }
    }

    #[test]
    fn observer_poles_are_where_they_were_placed() {
        let plant = PlantParams::default();
        for kind in [
            CompensatorKind::Lqr,
            CompensatorKind::LqrCabvel,
            CompensatorKind::LqrCabacc,
        ] {
            let p = params_of(kind);
            let d = LqrDesign::new(&p, &plant).unwrap();
            let mut ev: Vec<f64> = eigenvalues(&(&d.a - &d.l * &d.c))
                .unwrap()
                .iter()
                .map(|z| {
                    assert!(z.im.abs() < 1e-3, "{kind}: complex observer pole {z}");
                    z.re
                })
                .collect();
            ev.sort_by(f64::total_cmp);
            let mut want = p.observer_poles;
            want.sort_by(f64::total_cmp);
            for (g, w) in ev.iter().zip(want) {
                assert!((g - w).abs() < 1e-4 * w.abs(), "{kind}: {g} vs {w}");
            }
            // The discrete observer's poles are exactly e^{p·dt}.
            let l = Lqr::new(&p, &plant, 1e-3).unwrap();
            let phi = DMatrix::from_column_slice(7, 7, l.phi.as_slice());
            let mut zs: Vec<f64> = eigenvalues(&phi).unwrap().iter().map(|z| z.re).collect();
            zs.sort_by(f64::total_cmp);
            let mut want_z: Vec<f64> = p.observer_poles.iter().map(|p| (p * 1e-3).exp()).collect();
            want_z.sort_by(f64::total_cmp);
            for (g, w) in zs.iter().zip(want_z) {
                assert!((g - w).abs() < 1e-6, "{kind}: {g} vs {w}");
            }
        }
    }

    #[test]
    fn kalman_gains_match_scipys_dual_riccati_solution() {
        let plant = PlantParams::default();
        for case in reference()["kalman"].as_array().unwrap() {
            let name = case["name"].as_str().unwrap();
            let spec =
                crate::compensator::variants::variant(&format!("{name}:kalman"), &plant, 1e-3)
                    .unwrap();
            let (CompensatorSpec::LqrCabvel { lqr: p } | CompensatorSpec::LqrCabacc { lqr: p }) =
                spec
            else {
                unreachable!()
            };
            let ObserverDesign::Kalman { cab_noise, .. } = p.observer else {
                unreachable!()
            };
            assert!((cab_noise - case["V"][1][1].as_f64().unwrap()).abs() < 1e-12 * cab_noise);
            let d = LqrDesign::new(&p, &plant).unwrap();
            let want = matrix(&case["L"]);
            for i in 0..7 {
                for j in 0..2 {
                    let w = want[(i, j)];
                    // Relative to the column's largest entry: the gains span many decades.
                    let scale = want.column(j).amax();
                    assert!(
                        (d.l[(i, j)] - w).abs() < 1e-6 * scale,
                        "{name} L[{i},{j}] {} vs {w}",
                        d.l[(i, j)]
                    );
                }
            }
        }
    }

    #[test]
    fn the_kalman_observer_estimates_cab_acceleration_better_than_the_placed_one() {
        use crate::closed_loop::{ClosedLoop, Drive, LoopSetup};
        use crate::params::{BodyModel, LoopParams, Seat};
        // Closed loop on the machine with the accelerometer noise on, driven by a swept
        // hand motion; the error of the estimated cab acceleration against the true one.
        // Seen: lqr-cabacc 225 against 11,700 (mm/s²)², lqr-cabvel 2,500 against 5,300.
        let error_ms = |name: &str| {
            let plant = PlantParams::default();
            let setup = LoopSetup {
                compensator: crate::compensator::variants::variant(name, &plant, 1e-3).unwrap(),
                plant,
                body: BodyModel::default(),
                loop_params: LoopParams::default(),
                seat: Seat::On,
            };
            let mut lp = ClosedLoop::new(&setup, 7).unwrap();
            let mut state = vec![0.0; lp.state_len()];
            let (mut sum, mut n) = (0.0, 0);
            for k in 0..20_000 {
                let t = k as f64 * 1e-3;
                lp.tick(Drive::Hand(
                    10.0 * (2.0 * std::f64::consts::PI * 0.5 * t).sin(),
                ));
                lp.read_state(&mut state);
                if k >= 2_000 {
                    let e = state[7 + idx::XC_DD] - state[idx::XC_DD];
                    sum += e * e;
                    n += 1;
                }
            }
            sum / n as f64
        };
        for kind in ["lqr-cabacc", "lqr-cabvel"] {
            let placed = error_ms(kind);
            let kalman = error_ms(&format!("{kind}:kalman"));
            assert!(
                kalman < 0.5 * placed,
                "{kind}: Kalman {kalman:.1} vs placed {placed:.1} (mm/s²)²"
            );
        }
    }

    #[test]
    fn tracks_a_constant_reference_without_offset_on_the_design_model() {
        // N̄ scaling: at steady state on the nominal model y = r exactly.
        let plant = PlantParams::default();
        let d = LqrDesign::new(&params_of(CompensatorKind::LqrCabvel), &plant).unwrap();
        let acl = &d.a - &d.b * &d.k;
        let ss = acl.clone().lu().solve(&(-&d.b * (&d.k * &d.nx))).unwrap();
        assert!((ss[(idx::Y, 0)] - 1.0).abs() < 1e-10, "{}", ss[(idx::Y, 0)]);
        let _ = matrix; // fixture helper used above
    }
}

#[cfg(test)]
mod cab_velocity_tests {
    use crate::filters::FirstOrder;

    #[test]
    fn highpass_and_leaky_integrator_turn_acceleration_into_velocity_at_the_modes() {
        // Velocity = acceleration/(jω): at the structure modes the chain must have gain 1/ω
        // within 1 % and a phase of −90° within 3°, while a constant offset is removed.
        let dt = 1e-3;
        let hp = FirstOrder::high_pass(0.5, dt);
        let leak = FirstOrder::leaky_integrator(0.5, dt);
        for f_hz in [4.0, 6.2] {
            let w = 2.0 * std::f64::consts::PI * f_hz;
            let h = hp.response(w, dt) * leak.response(w, dt);
            assert!(
                (h.norm() * w - 1.0).abs() < 0.01,
                "{f_hz} Hz gain {}",
                h.norm() * w
            );
            assert!(
                (h.arg().to_degrees() + 90.0).abs() < 3.0,
                "{f_hz} Hz phase {}",
                h.arg().to_degrees()
            );
        }
        assert!((hp.response(0.0, dt) * leak.response(0.0, dt)).norm() < 1e-12);
    }
}
