use super::*;
use crate::analysis::LinearizedLoop;
use crate::analysis::nyquist::OpenLoop;
use crate::compensator::variants::variant;
use crate::compensator::{CompensatorKind, NotchParams};
use crate::param_set::ParamSet;
use crate::params::{BodyModel, PlantParams};

const DT: f64 = 1e-3;

fn setup(kind: CompensatorKind, k_bf: f64) -> LoopSetup {
    ParamSet::default().setup(kind, Seat::On, k_bf)
}

/// The continuous frequency a Tustin section pre-warped at `w` shows at θ = ωT.
fn tustin_freq(theta: f64, w: f64) -> f64 {
    w * (theta / 2.0).tan() / (w * DT / 2.0).tan()
}

/// k(2ζωs + ω²)/(s² + 2ζωs + ω²) at s = jΩ.
fn transmissibility(k: f64, f_hz: f64, zeta: f64, big_w: f64) -> Complex<f64> {
    let w = 2.0 * PI * f_hz;
    let s = Complex::new(0.0, big_w);
    k * (2.0 * zeta * w * s + w * w) / (s * s + 2.0 * zeta * w * s + w * w)
}

fn body_map(body: BodyModel) -> StateSpace {
    let mut b = Body::new(body, DT);
    probe(&mut b, 1, 1, |b, u, y| y[0] = b.step(u[0]))
}

#[test]
fn body_responses_are_the_analytic_transmissibilities_through_tustin() {
    let (k_h, f_hz, zeta) = (0.5, 5.0, 0.3);
    let single = body_map(BodyModel::SingleResonance { k_h, f_hz, zeta });
    let (tf, tz, af, az) = (4.5, 0.35, 7.0, 0.25);
    let seated = body_map(BodyModel::Seated {
        k_h: 0.56,
        torso_f_hz: tf,
        torso_zeta: tz,
        arm_f_hz: af,
        arm_zeta: az,
    });
    for f in [0.2, 1.0, 4.5, 5.0, 7.0, 20.0, 100.0] {
        let theta = 2.0 * PI * f * DT;
        let want = transmissibility(k_h, f_hz, zeta, tustin_freq(theta, 2.0 * PI * f_hz));
        let got = single.response(0, 0, theta);
        assert!(
            (got - want).norm() < 1e-6 * want.norm(),
            "{f} Hz: {got} vs {want}"
        );
        // h = k_h(1 − T·A)x_c, each biquad pre-warped at its own peak.
        let t = transmissibility(1.0, tf, tz, tustin_freq(theta, 2.0 * PI * tf));
        let a = transmissibility(1.0, af, az, tustin_freq(theta, 2.0 * PI * af));
        let want = 0.56 * (1.0 - t * a);
        let got = seated.response(0, 0, theta);
        assert!(
            (got - want).norm() < 1e-6 * want.norm().max(1e-3),
            "{f} Hz: {got} vs {want}"
        );
    }
    // The seated body passes no static cab motion; the rigid mass is its gain everywhere.
    assert!(seated.response(0, 0, 0.0).norm() < 1e-9);
    let rigid = body_map(BodyModel::RigidMass { k_h: 0.56 });
    assert!((rigid.response(0, 0, 1.3) - Complex::from(0.56)).norm() < 1e-9);
}

#[test]
fn the_notch_read_through_the_compensator_has_depth_zeta_at_its_frequency() {
    let s = setup(CompensatorKind::PidNotch, 0.78);
    let notch = NotchParams::default();
    let comp = compensator_map(&s).unwrap();
    // From the reference the PID sees N·r, from y it sees −y: N = −G_r/G_y.
    let n = |f: f64| {
        let t = 2.0 * PI * f * DT;
        -comp.response(0, 0, t) / comp.response(0, 1, t)
    };
    // D_N(jω_N) = 2ζ_N·j/(1 + j)² = ζ_N, kept exactly by the pre-warped Tustin map.
    assert!(
        (n(notch.f_hz) - Complex::from(notch.zeta)).norm() < 1e-6,
        "{}",
        n(notch.f_hz)
    );
    assert!((n(0.01).norm() - 1.0).abs() < 1e-4);
    assert!((n(200.0).norm() - 1.0).abs() < 2e-2);
}

#[test]
fn the_rig_parts_are_their_continuous_transfer_functions_well_below_the_sample_rate() {
    let p = PlantParams::default();
    let s = setup(CompensatorKind::Pid, 0.78);
    let grid = [0.1, 0.5, 2.0, 4.0, 6.2];
    let parts = parts(&s, &grid).unwrap();
    let [w1, w2] = p.mode_omegas();
    for (i, &f) in grid.iter().enumerate() {
        let w = 2.0 * PI * f;
        let jw = Complex::new(0.0, w);
        // The zero-order hold delays by half a sample; its other effects are O((ωT)²).
        let hold = Complex::from_polar(1.0, -w * DT / 2.0);
        let wv = p.w_vc;
        let cyl = p.k_vc * wv * wv / (jw * (jw * jw + 2.0 * p.z_vc * wv * jw + wv * wv)) * hold;
        let mode =
            |w: f64, z: f64| (2.0 * z * w * jw + w * w) / (jw * jw + 2.0 * z * w * jw + w * w);
        let structure = p.k_s * mode(w1, p.z1) * mode(w2, p.z2) * jw * jw;
        for (bode, want, tol) in [(&parts[0], cyl, 2e-3), (&parts[1], structure, 2e-2)] {
            let got_db = bode.mag_db[i];
            let want_db = 20.0 * want.norm().log10();
            assert!(
                (got_db - want_db).abs() < 20.0 * tol,
                "{} at {f} Hz: {got_db} vs {want_db}",
                bode.name
            );
        }
        let want_phase = cyl.arg().to_degrees();
        let got = parts[0].phase_deg[i];
        assert!(
            ((got - want_phase + 180.0).rem_euclid(360.0) - 180.0).abs() < 0.2,
            "{f} Hz: {got} vs {want_phase}"
        );
    }
}

#[test]
fn the_inner_velocity_loop_is_its_design_model_transfer_function() {
    let s = setup(CompensatorKind::LqrCabvel, 0.78);
    let p = PlantParams::default();
    let kk = match &s.compensator {
        CompensatorSpec::LqrCabvel { lqr } => lqr.inner_loop_gain,
        _ => unreachable!(),
    };
    let m = inner_loop_map(&s).unwrap();
    for f in [0.05, 0.5, 3.0] {
        let w = 2.0 * PI * f;
        let jw = Complex::new(0.0, w);
        let wv = p.w_vc;
        // kk ω²/(s(s² + 2ζωs + (1 + kk)ω²)), half a sample late (the hold).
        let want = kk * wv * wv / (jw * (jw * jw + 2.0 * p.z_vc * wv * jw + (1.0 + kk) * wv * wv))
            * Complex::from_polar(1.0, -w * DT / 2.0);
        let got = m.response(0, 0, w * DT);
        assert!(
            (got - want).norm() < 2e-3 * want.norm(),
            "{f} Hz: {got} vs {want}"
        );
    }
    assert!(inner_loop_map(&setup(CompensatorKind::Pid, 0.78)).is_none());
}

#[test]
fn closed_loop_dc_gain_is_one_with_integral_action_and_analytic_on_a_rigid_body() {
    let p = PlantParams::default();
    for kind in [
        CompensatorKind::Pid,
        CompensatorKind::PidNotch,
        CompensatorKind::PidShaper,
    ] {
        let s = setup(kind, 0.3);
        let off = closed_loop_map(&s, Seat::Off, s.plant)
            .unwrap()
            .response(0, 0, 0.0);
        assert!(
            (off - Complex::from(1.0)).norm() < 1e-9,
            "{kind} off: {off}"
        );
        // On the machine a rigid body feeds K_H·K_S·y back at DC: y/r = 1/(1 + K_BF·K_H·K_S).
        let on = closed_loop_map(&s, Seat::On, s.plant)
            .unwrap()
            .response(0, 0, 0.0);
        let want = 1.0 / (1.0 + 0.3 * 0.56 * p.k_s);
        assert!(
            (on - Complex::from(want)).norm() < 1e-9,
            "{kind} on: {on} vs {want}"
        );
        // The seated body passes no static cab motion: DC gain 1 on the machine too.
        let mut seated = s.clone();
        seated.body = BodyModel::Seated {
            k_h: 0.56,
            torso_f_hz: 4.5,
            torso_zeta: 0.35,
            arm_f_hz: 7.0,
            arm_zeta: 0.25,
        };
        let on = closed_loop_map(&seated, Seat::On, seated.plant)
            .unwrap()
            .response(0, 0, 0.0);
        assert!(
            (on - Complex::from(1.0)).norm() < 1e-9,
            "{kind} seated: {on}"
        );
    }
}

#[test]
fn the_shaper_split_off_is_the_whole_sampled_loop() {
    let s = setup(CompensatorKind::PidShaper, 0.78);
    let open = OpenLoop::new(&s).unwrap();
    let mut whole = ClosedLoop::new(&linear_setup(&s), 0).unwrap();
    let whole = probe(&mut whole, 1, 1, |lp, u, y| {
        y[0] = lp.tick(Drive::Reference(u[0])).feedthrough;
    });
    assert!(
        whole.a().nrows() > 150,
        "the delay line is in the whole loop"
    );
    for f in [0.3, 2.4, 4.0, 5.1, 6.2, 30.0] {
        let t = 2.0 * PI * f * DT;
        let (a, b) = (open.response(t), whole.response(0, 0, t));
        assert!(
            (a - b).norm() < 1e-9 * b.norm().max(1e-6),
            "{f} Hz: {a} vs {b}"
        );
    }
}

/// The Nyquist verdict and margin against the eigenvalues of the sampled loop, for every
/// design, below and above its margin.
#[test]
fn nyquist_verdict_agrees_with_the_closed_loop_eigenvalues() {
    let params = ParamSet::default();
    let mut designs: Vec<LoopSetup> = CompensatorKind::ALL
        .iter()
        .map(|&k| setup(k, 0.78))
        .collect();
    let mut ei = setup(CompensatorKind::PidShaper, 0.78);
    ei.compensator = variant("pid-shaper:ei", &params.plant, DT).unwrap();
    designs.push(ei);
    let mut flips = 0;
    for s in &designs {
        let name = s.compensator.kind().name();
        let lin = LinearizedLoop::new(s).unwrap();
        let open = OpenLoop::new(s).unwrap();
        let margin = open.max_stable_up_to(MAX_KBF);
        let mut ks = vec![0.3, 0.78, 3.0];
        if let Some(m) = margin.filter(|&m| m > 0.0) {
            ks.extend([0.995 * m, 1.005 * m]);
            assert!(
                lin.is_stable(0.995 * m).unwrap() && !lin.is_stable(1.005 * m).unwrap(),
                "{name}: margin {m}"
            );
            flips += 1;
        }
        for k in ks {
            let ny = open.nyquist(k).unwrap();
            let eig = lin.is_stable(k).unwrap();
            assert_eq!(ny.stable, eig, "{name} at K_BF {k}: {ny:?}");
            assert!(ny.closed_loop_unstable >= 0, "{name} at {k}");
        }
    }
    assert!(flips >= 5, "most designs lose stability within the range");
}

#[test]
fn under_a_condition_the_report_is_of_the_machine_as_it_runs_and_its_margins_the_gates() {
    use crate::analysis::robustness::OnRig;
    use crate::params::MachineCondition;
    // On tires the first mode falls to 0.75 × 4.0 Hz; the designs stay made for the stilts.
    let base = setup(CompensatorKind::Pid, 0.78);
    let rig = "tires"
        .parse::<MachineCondition>()
        .unwrap()
        .apply(&base.plant)
        .unwrap();
    let designs: Vec<(String, CompensatorSpec)> = [
        CompensatorKind::PidNotch,
        CompensatorKind::Lqr,
        CompensatorKind::LqrCabvel,
    ]
    .iter()
    .map(|&k| (k.name().to_string(), setup(k, 0.78).compensator))
    .collect();
    let r = report(&base, &designs, rig).unwrap();
    let structure = r
        .parts
        .iter()
        .find(|b| b.name.starts_with("structure"))
        .unwrap();
    let (peak, _) = r
        .freqs_hz
        .iter()
        .zip(&structure.mag_db)
        .filter(|(f, _)| (1.0..5.0).contains(*f))
        .max_by(|a, b| a.1.total_cmp(b.1))
        .unwrap();
    assert!((peak / 3.0 - 1.0).abs() < 0.05, "structure peak {peak} Hz");
    // Each design's Nyquist margin on tires is what the sampled loop's eigenvalues on tires
    // say (`OnRig`, the gate's judge under a condition), not the stilts'.
    for ((name, spec), c) in designs.iter().zip(&r.compensators) {
        let s = LoopSetup {
            compensator: spec.clone(),
            ..base.clone()
        };
        let gate = OnRig::new(&s)
            .unwrap()
            .max_stable_kbf(rig, MAX_KBF)
            .unwrap();
        let stilts = LinearizedLoop::new(&s).unwrap().margin(&s).unwrap();
        match (c.nyquist.max_stable_kbf, gate) {
            (Some(n), Some(g)) => assert!((n / g - 1.0).abs() < 1e-3, "{name}: {n} vs {g}"),
            (n, g) => assert_eq!(n, g, "{name}"),
        }
        assert_ne!(
            c.nyquist.max_stable_kbf, stilts,
            "{name}: the stilts' margin"
        );
    }
}
