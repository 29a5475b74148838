//! The power planner's tests: the simulated power against the exact power of the signed-rank
//! test, the exact floor, the model's estimate, and the cancellation factor's comparisons.

use super::*;

fn names(k: usize) -> Vec<String> {
    (0..k).map(|i| format!("c{i}")).collect()
}

/// Exact power of one exact signed-rank test at n when each difference's sign is positive
/// with probability q independently of its size: the chance of every sign pattern whose
/// R⁺ is in the rejection region, by enumerating all 2ⁿ patterns.
fn analytic_power(n: usize, q: f64, alpha: f64) -> f64 {
    let mut power = 0.0;
    for mask in 0u32..(1 << n) {
        let r_plus: u32 = (0..n as u32)
            .filter(|i| mask >> i & 1 == 1)
            .map(|i| i + 1)
            .sum();
        // p of this pattern: the share of patterns at least as extreme, two-sided.
        let extreme = |t: u32| {
            let (mut lo, mut hi) = (0u32, 0u32);
            for m2 in 0u32..(1 << n) {
                let s: u32 = (0..n as u32)
                    .filter(|i| m2 >> i & 1 == 1)
                    .map(|i| i + 1)
                    .sum();
                lo += u32::from(s <= t);
                hi += u32::from(s >= t);
            }
            (2.0 * f64::from(lo.min(hi)) / f64::from(1u32 << n)).min(1.0)
        };
        if extreme(r_plus) < alpha {
            let pos = mask.count_ones() as i32;
            power += q.powi(pos) * (1.0 - q).powi(n as i32 - pos);
        }
    }
    power
}

#[test]
fn the_simulated_power_at_a_known_effect_matches_the_exact_power() {
    let (n, q, alpha, draws) = (9, 0.85, 0.05, 20_000);
    let want = analytic_power(n, q, alpha);
    let mut rng = Rng::new(11);
    // Two compensators: one comparison, Holm is the identity. Differences: size uniform,
    // sign positive with probability q, independent.
    let got = plan_with(&names(2), &[(0, 1)], n, alpha, draws, &mut rng, |rng, n| {
        (0..n)
            .map(|i| {
                let size = 1.0 + rng.next_f64() + i as f64 * 1e-9;
                let sign = if rng.next_f64() < q { 1.0 } else { -1.0 };
                vec![sign * size, 0.0]
            })
            .collect()
    });
    let se = (want * (1.0 - want) / draws as f64).sqrt();
    assert!(
        (got.pairs[0].power - want).abs() < 4.0 * se,
        "simulated {} against exact {want} (se {se})",
        got.pairs[0].power
    );
    assert!(
        want > 0.2 && want < 0.9,
        "a case that tells something: {want}"
    );
}

#[test]
fn the_floor_rules_out_eight_subjects_and_ten_pairs() {
    let model = Model {
        compensators: names(5),
        log_means: vec![0.0, 2.0, 4.0, 6.0, 8.0],
        residual_sd: 0.01,
        pilot_n: 8,
    };
    let pairs = every_pair(5);
    assert_eq!(pairs.len(), 10);
    let p8 = plan(&model, &pairs, 8, 0.05, 100, 1);
    assert!(p8.pairs.iter().all(|p| !p.possible && p.power == 0.0));
    assert!(p8.note.contains("0.078"), "{}", p8.note);
    // A huge effect with enough subjects: every pair found.
    let p10 = plan(&model, &pairs, 10, 0.05, 100, 1);
    assert!(
        p10.pairs.iter().all(|p| p.possible && p.power == 1.0),
        "{p10:?}"
    );
}

#[test]
fn a_cancellation_plan_compares_each_compensator_with_itself_cancelled_from_complete_subjects() {
    use crate::engine::results::study_data::{Cells, StudyData};
    let compensators = vec!["pid".to_string(), "lqr".to_string()];
    let (columns, pairs) = comparisons(&compensators, Some(CancellationArm::Personal));
    assert_eq!(columns, ["pid", "lqr", "pid+personal", "lqr+personal"]);
    assert_eq!(pairs, [(0, 2), (1, 3)]);
    // Three subjects: the third has no cancelled LQR test (its cell was not run) and is
    // left out; the desk's cells never count.
    let subject = |values: &[(&str, &str, f64)]| -> Cells {
        values
            .iter()
            .map(|&(key, seat, v)| {
                let mut cell = [None; 6];
                cell[0] = Some(v);
                ((key.to_string(), seat.to_string()), cell)
            })
            .collect()
    };
    let data = StudyData {
        compensators: compensators.clone(),
        arms: vec![CancellationArm::Personal],
        seats: vec!["on".into(), "off".into()],
        subjects: vec![
            subject(&[
                ("pid", "on", 100.0),
                ("lqr", "on", 80.0),
                ("pid+personal", "on", 90.0),
                ("lqr+personal", "on", 60.0),
                ("pid", "off", 1.0),
            ]),
            subject(&[
                ("pid", "on", 120.0),
                ("lqr", "on", 100.0),
                ("pid+personal", "on", 96.0),
                ("lqr+personal", "on", 90.0),
            ]),
            subject(&[
                ("pid", "on", 50.0),
                ("lqr", "on", 40.0),
                ("pid+personal", "on", 45.0),
            ]),
        ],
        conditions: Default::default(),
    };
    let rows = data.complete_rows(&columns, 0, "on");
    assert_eq!(
        rows,
        [
            vec![100.0, 80.0, 90.0, 60.0],
            vec![120.0, 100.0, 96.0, 90.0]
        ]
    );
    let model = estimate(&columns, &rows).unwrap();
    // The model's effect of cancelling the PID is the mean log ratio of the complete
    // subjects' cancelled over uncancelled values.
    let effect = ((90.0f64 / 100.0).ln() + (96.0f64 / 120.0).ln()) / 2.0;
    assert!((model.log_means[2] - model.log_means[0] - effect).abs() < 1e-12);
    let p = plan(&model, &pairs, 12, 0.05, 200, 3);
    let named: Vec<(&str, &str)> = p
        .pairs
        .iter()
        .map(|q| (q.a.as_str(), q.b.as_str()))
        .collect();
    assert_eq!(named, [("pid", "pid+personal"), ("lqr", "lqr+personal")]);
    assert!(p.pairs.iter().all(|q| q.possible));
}

#[test]
fn the_model_recovers_means_and_spread_of_its_own_draws() {
    let model = Model {
        compensators: names(3),
        log_means: vec![1.0, 1.5, 2.0],
        residual_sd: 0.3,
        pilot_n: 0,
    };
    let mut rng = Rng::new(5);
    let y: Vec<Vec<f64>> = (0..2000)
        .map(|_| {
            let subject = rng.normal();
            model
                .log_means
                .iter()
                .map(|mu| (mu + subject + 0.3 * rng.normal()).exp())
                .collect()
        })
        .collect();
    let est = estimate(&model.compensators, &y).unwrap();
    for (a, b) in est.log_means.iter().zip(&model.log_means) {
        assert!((a - b).abs() < 0.1, "{a} vs {b}");
    }
    assert!((est.residual_sd - 0.3).abs() < 0.01, "{}", est.residual_sd);
}
