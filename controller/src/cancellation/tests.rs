use super::*;
use crate::closed_loop::{ClosedLoop, Drive, LoopSetup};
use crate::compensator::{CompensatorKind, study_spec};
use crate::params::{BodyModel, LoopParams, PlantParams, Seat};
use crate::rng::Rng;

const DT: f64 = 1e-3;

/// A body of the default population's middle, and one far from it.
const BODIES: [[f64; 5]; 2] = [[0.5, 1.1, 0.4, 2.0, 0.35], [0.9, 0.7, 0.25, 3.2, 0.6]];

fn model(b: [f64; 5]) -> CancellationModel {
    CancellationModel {
        k_h: b[0],
        torso_f_hz: b[1],
        torso_zeta: b[2],
        arm_f_hz: b[3],
        arm_zeta: b[4],
        gain: 1.0,
        phase_lag_deg: 0.0,
        phase_ref_hz: 2.0,
        limit_mm: 50.0,
    }
}

/// Ĥ is the identification's continuous body model (`fit::feedthrough`, written from T and
/// A directly), to 1 % and 0.5° over the identification's band: the two biquads are the
/// same body.
#[test]
fn the_canceller_is_the_identifications_body_over_its_band() {
    for b in BODIES {
        let c = Canceller::new(&model(b), DT).unwrap();
        let theta = b.map(f64::ln);
        for i in 0..=40 {
            let f = 0.5 * 16f64.powf(f64::from(i) / 40.0);
            // mm per mm/s² against mm per m/s².
            let ours = c.response(f, DT) * 1e3;
            let fitted = crate::identification::fit::feedthrough(&theta, f);
            let ratio = ours / fitted;
            assert!(
                (ratio.norm() - 1.0).abs() < 0.01 && ratio.arg().abs().to_degrees() < 0.5,
                "{b:?} at {f:.2} Hz: {ours} against {fitted}"
            );
        }
    }
}

/// The wrong model's phase lag is exactly the stated one at its frequency, at unit gain,
/// and its gain error is the stated factor.
#[test]
fn a_wrong_model_lags_by_the_stated_phase_at_its_frequency() {
    let exact = Canceller::new(&model(BODIES[0]), DT).unwrap();
    let wrong = Canceller::new(
        &CancellationModel {
            gain: 1.3,
            phase_lag_deg: 60.0,
            phase_ref_hz: 2.0,
            ..model(BODIES[0])
        },
        DT,
    )
    .unwrap();
    let r = wrong.response(2.0, DT) / exact.response(2.0, DT);
    assert!((r.norm() - 1.3).abs() < 1e-9, "{r}");
    assert!((r.arg().to_degrees() + 60.0).abs() < 1e-6, "{r}");
}

#[test]
fn a_model_out_of_its_range_is_refused_naming_the_field() {
    let e = Canceller::new(
        &CancellationModel {
            phase_lag_deg: 200.0,
            ..model(BODIES[0])
        },
        DT,
    )
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "cancellation.phase_lag_deg = 200 is out of range: it must be a finite number in [0, 170]"
    );
    let e = Canceller::new(
        &CancellationModel {
            k_h: f64::NAN,
            ..model(BODIES[0])
        },
        DT,
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("cancellation.k_h = NaN"), "{e}");
}

/// A rider with the body `b` on the machine under `kind`'s study design, `plant` the rig,
/// at the study's K_BF.
fn on_the_machine(kind: CompensatorKind, b: [f64; 5], plant: PlantParams) -> LoopSetup {
    LoopSetup {
        plant,
        body: BodyModel::Seated {
            k_h: b[0],
            torso_f_hz: b[1],
            torso_zeta: b[2],
            arm_f_hz: b[3],
            arm_zeta: b[4],
        },
        loop_params: LoopParams { dt: DT, k_bf: 0.78 },
        seat: Seat::On,
        compensator: study_spec(kind, &plant),
    }
}

fn band_power(x: &[f64], lo: f64, hi: f64) -> f64 {
    super::offline::band_power(x, DT, lo, hi)
}

/// What a test with cancellation gives: the feedthrough in the device's reading (−h), what
/// the canceller subtracted, and whether the guard tripped.
struct Run {
    feedthrough: Vec<f64>,
    cancelled: Vec<f64>,
    tripped: bool,
}

/// 60 s on the machine under `kind`'s study design with the body `b`: a person tracking
/// random steps (a lagged step command and remnant, independent of the loop), cancelled by
/// `cancel` (None: not cancelled).
fn run(kind: CompensatorKind, b: [f64; 5], cancel: Option<CancellationModel>) -> Run {
    let setup = on_the_machine(kind, b, PlantParams::default());
    let mut lp = ClosedLoop::new(&setup, 7).unwrap();
    lp.set_canceller(cancel.map(|m| Canceller::new(&m, DT).unwrap()));
    let mut rng = Rng::new(11);
    let (mut step, mut hand, mut remnant) = (0.0, 0.0, 0.0);
    let ticks = (60.0 / DT) as usize;
    let mut out = Run {
        feedthrough: Vec::with_capacity(ticks),
        cancelled: Vec::with_capacity(ticks),
        tripped: false,
    };
    for t in 0..ticks {
        if t % 3000 == 0 {
            step = rng.uniform(-40.0, 40.0);
        }
        // A 0.3 s lag to the step, and 1 mm of remnant below about 2 Hz.
        hand += DT / 0.3 * (step - hand);
        remnant += DT * 12.0 * (rng.normal() * 1.0 * (2.0 / (12.0 * DT)).sqrt() - remnant);
        let rec = lp.tick(Drive::Hand(hand + remnant));
        out.feedthrough.push(-rec.feedthrough);
        out.cancelled.push(rec.cancellation);
    }
    out.tripped = lp.canceller().is_some_and(Canceller::tripped);
    out
}

/// The share of the feedthrough's power in 0.5–5 Hz that cancellation removed from the
/// device's reading.
fn removed(r: &Run) -> f64 {
    let residual: Vec<f64> = r
        .feedthrough
        .iter()
        .zip(&r.cancelled)
        .map(|(h, c)| h - c)
        .collect();
    1.0 - band_power(&residual, 0.5, 5.0) / band_power(&r.feedthrough, 0.5, 5.0)
}

/// Issue 38's bars on a synthetic person whose body is known: the exact model removes 90 %
/// of the feedthrough's power in 0.5–5 Hz, a model 30 % too strong 70 %, under the PID and
/// the LQR, and the guard stays quiet.
#[test]
fn the_exact_model_removes_nine_tenths_of_the_feedthrough_and_a_strong_one_seven() {
    for kind in [CompensatorKind::Pid, CompensatorKind::Lqr] {
        for b in BODIES {
            let exact = run(kind, b, Some(model(b)));
            let strong = run(
                kind,
                b,
                Some(CancellationModel {
                    gain: 1.3,
                    ..model(b)
                }),
            );
            let (e, s) = (removed(&exact), removed(&strong));
            eprintln!("{kind:?} {b:?}: exact {e:.4}, +30 % {s:.4}");
            assert!(e >= 0.9, "{kind:?} {b:?}: exact removed {e}");
            assert!(s >= 0.7, "{kind:?} {b:?}: +30 % removed {s}");
            assert!(!exact.tripped && !strong.tripped);
        }
    }
}

/// The guard's bound: an output past `limit_mm` turns cancellation off for the rest of the
/// test, at once and for good.
#[test]
fn an_output_past_its_bound_turns_cancellation_off_for_the_rest_of_the_test() {
    let mut c = Canceller::new(
        &CancellationModel {
            limit_mm: 0.5,
            ..model(BODIES[0])
        },
        DT,
    )
    .unwrap();
    let mut first = None;
    for t in 0..20_000 {
        let a = 3000.0 * (2.0 * PI * 2.0 * t as f64 * DT).sin();
        let out = c.step(a);
        if out.tripped_now && first.is_none() {
            first = Some(t);
        }
        if first.is_some() {
            assert_eq!(out.output_mm, 0.0);
        } else {
            assert!(out.output_mm.abs() <= 0.5);
        }
    }
    assert!(first.is_some());
    assert!(c.tripped());
}

/// The analysis reads the cancelled loop off its tick (the canceller's filters are states
/// of the loop): under the thesis's LQR a body coupled twice the population's median makes
/// the loop unstable at the study's K_BF 0.78, and the exact model's cancellation makes it
/// stable to K_BF 20 (the analysis's top), up to which the feedthrough no longer closes a
/// loop; a model 30 % too strong leaves 30 % of it: stable to 4.0 against the uncancelled
/// 0.62 (asserted: more than 2.5 times).
#[test]
fn cancellation_is_in_the_loop_the_stability_analysis_reads() {
    use crate::analysis::{LinearizedLoop, linear_setup};
    let b = [1.0, 1.1, 0.4, 2.0, 0.35];
    let setup = on_the_machine(CompensatorKind::Lqr, b, PlantParams::default());
    let read = |cancel: Option<CancellationModel>| {
        let mut lp = ClosedLoop::new(&linear_setup(&setup), 0).unwrap();
        lp.set_canceller(cancel.map(|m| Canceller::new(&m, DT).unwrap()));
        let lin = LinearizedLoop::read_off(&mut lp, DT);
        (lin.is_stable(0.78).unwrap(), lin.max_stable_kbf().unwrap())
    };
    let (plain, exact, strong) = (
        read(None),
        read(Some(CancellationModel {
            limit_mm: 100.0,
            ..model(b)
        })),
        read(Some(CancellationModel {
            gain: 1.3,
            limit_mm: 100.0,
            ..model(b)
        })),
    );
    eprintln!("uncancelled {plain:?}, exact {exact:?}, +30 % {strong:?}");
    assert!(!plain.0, "{plain:?}");
    assert!(exact.0 && strong.0, "{exact:?} {strong:?}");
    let k = |r: (bool, Option<f64>)| r.1.unwrap_or(f64::INFINITY);
    assert!(k(exact) >= 19.9, "{exact:?}");
    assert!(k(strong) > 2.5 * k(plain), "{strong:?} against {plain:?}");
}

/// The feedthrough a wrong model leaves, measured on the platform against scipy's
/// |1 − Ĥ/H|² (`tools/fixtures/make_cancellation_fixture.py`, written from the docs): the
/// cab shaken at each grid frequency by a sinusoidal reference (noise-free accelerometer,
/// the seated body of the fixture), the canceller run on the accelerometer's reading, and
/// the residual's power at that frequency over the feedthrough's, from a DFT over whole
/// periods after the loop settled. Issue 38 asks within 5 %; they agree to 3·10⁻⁷ (asserted:
/// 10⁻³), the same linear filters computed twice.
#[test]
fn the_residual_a_wrong_model_leaves_is_scipys() {
    let fixture: serde_json::Value =
        serde_json::from_str(include_str!("../../fixtures/cancellation_residual.json")).unwrap();
    let num = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
    let body = &fixture["body"];
    let b = ["k_h", "torso_f_hz", "torso_zeta", "arm_f_hz", "arm_zeta"].map(|k| num(body, k));
    let plant = PlantParams {
        accel_noise_std: 0.0,
        engine_vibration_rms: 0.0,
        ..PlantParams::default()
    };
    let setup = on_the_machine(CompensatorKind::Pid, b, plant);
    let ticks: Vec<u64> = fixture["ticks_a_period"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_u64().unwrap())
        .collect();
    for (name, m) in fixture["models"].as_object().unwrap() {
        let cm = CancellationModel {
            k_h: num(m, "k_h"),
            torso_f_hz: num(m, "torso_f_hz"),
            torso_zeta: num(m, "torso_zeta"),
            arm_f_hz: num(m, "arm_f_hz"),
            arm_zeta: num(m, "arm_zeta"),
            gain: num(m, "gain"),
            phase_lag_deg: num(m, "phase_lag_deg"),
            phase_ref_hz: num(m, "phase_ref_hz"),
            limit_mm: 100.0,
        };
        for (i, &n) in ticks.iter().enumerate() {
            let mut lp = ClosedLoop::new(&setup, 1).unwrap();
            let mut c = Canceller::new(&cm, DT).unwrap();
            let w = 2.0 * PI / n as f64;
            // 12 s to settle, then 8 s or at least 4 whole periods, whichever is longer.
            let settle = (12_000 / n + 1) * n;
            let periods = (8_000 / n).max(4);
            let (mut d, mut r) = (
                nalgebra::Complex::new(0.0, 0.0),
                nalgebra::Complex::new(0.0, 0.0),
            );
            for k in 0..settle + periods * n {
                let rec = lp.tick(Drive::Reference(3.0 * (w * k as f64).sin()));
                let out = c.step(rec.cab_accel).output_mm;
                if k >= settle {
                    let e = nalgebra::Complex::from_polar(1.0, -w * k as f64);
                    d += e * -rec.feedthrough;
                    r += e * (-rec.feedthrough - out);
                }
            }
            let measured = r.norm_sqr() / d.norm_sqr();
            let expected = fixture["residual"][name][i].as_f64().unwrap();
            assert!(
                (measured / expected - 1.0).abs() < 1e-3,
                "{name} at {} Hz: measured {measured}, scipy {expected}",
                1000.0 / n as f64
            );
        }
    }
}

/// A fit of the body `b`, each parameter's interval ±`rel` of it.
fn fit_of(b: [f64; 5], rel: f64) -> bdft_protocol::identification::BodyFit {
    let e = |v: f64| bdft_protocol::identification::Estimate {
        value: v,
        lo: v * (1.0 - rel),
        hi: v * (1.0 + rel),
    };
    bdft_protocol::identification::BodyFit {
        k_h: e(b[0]),
        torso_f_hz: e(b[1]),
        torso_zeta: e(b[2]),
        arm_f_hz: e(b[3]),
        arm_zeta: e(b[4]),
        residual_rms: 0.1,
        unidentified: Default::default(),
    }
}

/// The check before a cancelling test: the subject's own model passes with every body of
/// its interval, a model 30 % strong too; a 60° lag and another person's body are refused
/// naming the body and why (the lag's residual is scipy's 2.70 at 5 Hz, and it destabilizes
/// the LQR loop); a fit with a parameter not identified gives no bodies to check.
#[test]
fn the_check_before_a_test_refuses_a_model_worse_than_none_and_names_where() {
    use super::check::{bodies_of, check};
    let b = BODIES[0];
    let bodies = bodies_of(&fit_of(b, 0.1)).unwrap();
    assert_eq!(bodies.len(), 11);
    let setup = on_the_machine(CompensatorKind::Lqr, b, PlantParams::default());
    let verdict = |m: CancellationModel| check(&m, &bodies, &setup).unwrap();
    let own = verdict(model(b));
    assert!(own.passes(), "{own:?}");
    let worst = own
        .bodies
        .iter()
        .map(|c| c.worst_residual)
        .fold(0.0, f64::max);
    // ±10 % on any one parameter leaves at most a few percent of the feedthrough.
    assert!(worst < 0.1, "{worst}");
    assert!(
        verdict(CancellationModel {
            gain: 1.3,
            ..model(b)
        })
        .passes()
    );
    let lag = verdict(CancellationModel {
        phase_lag_deg: 60.0,
        phase_ref_hz: 2.0,
        ..model(b)
    });
    assert!(!lag.passes());
    let fitted = &lag.bodies[0];
    assert_eq!(fitted.body, "as fitted");
    assert!(
        (fitted.worst_residual / 2.7024 - 1.0).abs() < 0.01 && fitted.worst_at_hz == 5.0,
        "{fitted:?}"
    );
    // Under the LQR the lag does worse than leave feedthrough: it destabilizes the loop.
    let why = lag.failure().unwrap();
    assert_eq!(
        why,
        "with the body as fitted the cancelled loop is unstable"
    );
    let other = verdict(model(BODIES[1])).failure().unwrap();
    assert!(other.contains("worse than none"), "{other}");
    let mut unidentified = fit_of(b, 0.1);
    unidentified.unidentified.insert(
        "arm_f_hz".into(),
        "its interval spans a factor of 12".into(),
    );
    assert!(bodies_of(&unidentified).is_err());
}

/// The check reads stability with the body of every interval end: a rider coupled twice the
/// median under the LQR is stable with their own model at the study's K_BF, and unstable
/// uncancelled (`cancellation_is_in_the_loop_the_stability_analysis_reads`); a model that
/// passes nothing (gain 0) is refused for the loop's instability.
#[test]
fn the_check_before_a_test_reads_the_cancelled_loops_stability() {
    use super::check::{bodies_of, check};
    let b = [1.0, 1.1, 0.4, 2.0, 0.35];
    let bodies = bodies_of(&fit_of(b, 0.1)).unwrap();
    let setup = on_the_machine(CompensatorKind::Lqr, b, PlantParams::default());
    let own = check(&model(b), &bodies, &setup).unwrap();
    assert!(own.bodies.iter().all(|c| c.stable), "{own:?}");
    let none = check(
        &CancellationModel {
            gain: 0.0,
            ..model(b)
        },
        &bodies,
        &setup,
    )
    .unwrap();
    assert!(
        none.failure()
            .unwrap()
            .ends_with("the cancelled loop is unstable"),
        "{none:?}"
    );
}
