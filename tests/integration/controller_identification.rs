//! The identification test on the real controller process: the multisine is the cylinder
//! reference whatever the person's hand does (K_BF = 0 for the loop), and the hand — large
//! and changing — shows in the hand and device channels only.

use bdft_controller::identification::Multisine;
use bdft_protocol::identification::{IdentificationTask, MultisineSpec};
use bdft_protocol::params::{LoopParams, Seat};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::{Outcome, TargetSpec, record_channel};
use bdft_tests::controller_link::{Link, Proc, TrialLog};

use super::controller_starts::server_input_trial;

/// A short test: 1 transient and 2 recorded periods of 2 s.
const SPEC: MultisineSpec = MultisineSpec {
    f_min_hz: 0.5,
    f_max_hz: 8.0,
    lines: 12,
    period_s: 2.0,
    periods: 2,
    transient_periods: 1,
    rms_mm: 2.0,
    seed: 7,
};
/// Ticks between operator inputs.
const EVERY: u32 = 10;

/// Runs the identification trial `trial_id` in lockstep, sending `hand(batch)` before each
/// batch of ticks; returns the record.
fn run(link: &mut Link, trial_id: u64, hand: impl Fn(u64) -> f64) -> Vec<Vec<f32>> {
    let st = bdft_protocol::server_to_controller::StartTrial {
        seat: Seat::On,
        target: TargetSpec::Identification {
            excitation: SPEC,
            task: IdentificationTask::HoldStill,
        },
        duration_s: SPEC.duration_s(),
        ..server_input_trial(trial_id, SPEC.duration_s())
    };
    let ticks = (SPEC.duration_s() / LoopParams::default().dt).round() as u64;
    let mut log = TrialLog::default();
    link.start_and_wait(st);
    for batch in 0..ticks / u64::from(EVERY) {
        link.send(&ServerToController::OperatorInput {
            trial_id,
            seq: batch + 1,
            position_mm: hand(batch),
        });
        link.step(EVERY, &mut log);
    }
    // The result follows the last tick; a few more steps deliver it.
    for _ in 0..100 {
        if log.results.iter().any(|r| r.trial_id == trial_id) {
            break;
        }
        link.step(1, &mut log);
    }
    let result = log
        .results
        .iter()
        .find(|r| r.trial_id == trial_id)
        .expect("a result");
    assert_eq!(result.outcome, Outcome::Complete, "{result:?}");
    let rec = log.record(trial_id);
    assert_eq!(rec[0].len() as u64, ticks);
    rec
}

#[test]
fn an_identification_trial_drives_the_multisine_whatever_the_hand_does() {
    let ctl = Proc::controller(&["--lockstep"]);
    let (mut link, _) = Link::connect(&ctl);
    // ±60 mm, a new value every 10 ticks, over several frequencies.
    let wild = |b: u64| 60.0 * ((b as f64 * 0.37).sin() * (b as f64 * 0.051).cos());
    let moved = run(&mut link, 41, wild);
    let still = run(&mut link, 42, |_| 0.0);
    let ch = |name: &str| record_channel(name).unwrap();
    let (r_c, hand, feedthrough, device, y) = (
        ch("cyl_ref_mm"),
        ch("hand_mm"),
        ch("feedthrough_mm"),
        ch("device_mm"),
        ch("cyl_pos_mm"),
    );
    // The reference is the generator's multisine, tick for tick, in both trials.
    let m = Multisine::new(&SPEC, LoopParams::default().dt).unwrap();
    for (k, (&a, &b)) in moved[r_c].iter().zip(&still[r_c]).enumerate() {
        assert_eq!(a, m.at_tick(k as u64) as f32, "tick {k}");
        assert_eq!(a, b, "tick {k}");
    }
    // The whole loop is the same: the cylinder and the cab never saw the hand.
    assert_eq!(moved[y], still[y]);
    assert_eq!(moved[ch("cab_accel_mm_s2")], still[ch("cab_accel_mm_s2")]);
    // The hand channel carries the input (held between inputs, once it has arrived) and the
    // device reads it less the feedthrough.
    let mut seen = 0;
    for (k, &h) in moved[hand].iter().enumerate() {
        let batch = k as u64 / u64::from(EVERY);
        assert!(
            h == wild(batch) as f32 || (batch > 0 && h == wild(batch - 1) as f32) || h == 0.0,
            "tick {k}: hand {h}"
        );
        seen += usize::from(h == wild(batch) as f32);
        let want = f64::from(h) - f64::from(moved[feedthrough][k]);
        assert!(
            (f64::from(moved[device][k]) - want).abs() < 1e-3,
            "tick {k}"
        );
    }
    assert!(seen > moved[hand].len() / 2, "{seen}");
    let span = moved[device].iter().fold(0.0f32, |m, d| m.max(d.abs()));
    assert!(span > 30.0, "the device followed the hand: {span}");
    assert!(still[hand].iter().all(|&h| h == 0.0));
}
