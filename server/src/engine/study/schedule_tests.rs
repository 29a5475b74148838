//! The schedule's rules checked: the protocol's order, the design aids, the
//! identification's place and the cancellation factor.

use super::*;

#[test]
fn default_params_are_valid_and_hash_stably() {
    let p = default_params();
    p.validate().unwrap();
    let h = protocol_hash(&p);
    assert_eq!(h.len(), 64);
    assert_eq!(h, protocol_hash(&p.clone()));
    let mut q = p.clone();
    q.k_bf = 0.6;
    assert_ne!(protocol_hash(&q), h);
    // Field order of the submitted JSON does not matter.
    let text = serde_json::to_string(&p).unwrap();
    let reordered: serde_json::Value = serde_json::from_str(&text).unwrap();
    let back: StudyParams = serde_json::from_value(reordered).unwrap();
    assert_eq!(protocol_hash(&back), h);
}

#[test]
fn survey_and_consent_texts_are_counted_in_characters() {
    let mut p = default_params();
    p.survey.items[0].label = "é".repeat(300);
    p.survey.items[0].low_anchor = "é".repeat(60);
    p.survey.open_question = "é".repeat(300);
    p.consent.version = "é".repeat(40);
    p.validate()
        .expect("as many characters as allowed, whatever their bytes");
    p.survey.items[0].label.push('é');
    assert!(
        p.validate()
            .unwrap_err()
            .to_string()
            .starts_with("survey.items:")
    );
}

#[test]
fn the_consent_text_follows_the_study_durations_and_counts() {
    let mut p = default_params();
    let (consent, texts) = p.rendered_texts().unwrap();
    assert!(
        consent
            .text
            .contains("Then 10 tests of 140 seconds each: 5 while seated on the machine"),
        "{}",
        consent.text
    );
    assert_eq!(texts.before_test, "The test lasts 140 seconds.");
    assert!(
        texts
            .before_practice
            .starts_with("The test lasts 120 seconds.")
    );
    p.trial_s = 90.0;
    p.compensators.truncate(3);
    let (consent, _) = p.rendered_texts().unwrap();
    assert!(
        consent
            .text
            .contains("Then 6 tests of 90 seconds each: 3 while seated"),
        "{}",
        consent.text
    );
    // (120 s + 6 × 90 s) / 60 = 11 minutes.
    assert!(p.text_values().contains(&("minutes", "11".into())));
    p.consent.text = "{tests} tests, {test_count}".into();
    let err = p.validate().unwrap_err().to_string();
    assert!(
        err.starts_with("consent.text: unknown placeholder {test_count}; allowed: {tests}, {tests_per_station}, {trial_s}, {practice_s}, {minutes}, {procedure}"),
        "{err}"
    );
    p.consent = ConsentForm::default();
    p.texts.language = "not a tag!".into();
    assert!(
        p.validate()
            .unwrap_err()
            .to_string()
            .starts_with("texts.language:")
    );
}

#[test]
fn old_stored_studies_without_texts_still_parse() {
    let mut stored = serde_json::to_value(default_params()).unwrap();
    stored.as_object_mut().unwrap().remove("texts");
    let back: StudyParams = serde_json::from_value(stored).unwrap();
    assert_eq!(back.texts, StudyTexts::default());
}

#[test]
fn every_schedule_follows_the_protocol() {
    let p = default_params();
    for idx in 0..40 {
        let s = schedule(&p, 99, idx);
        assert_eq!(s, schedule(&p, 99, idx), "reproducible");
        assert_eq!(s.len(), 11);
        assert!(s[0].phase == TestPhase::Practice && s[0].seat == Seat::Off);
        let start = if idx % 2 == 0 { Seat::On } else { Seat::Off };
        let block = |b| s.iter().filter(move |t| t.block == b).collect::<Vec<_>>();
        let (b1, b2) = (block(1), block(2));
        assert!(b1.iter().all(|t| t.seat == start));
        assert!(b2.iter().all(|t| t.seat != start));
        for b in [&b1, &b2] {
            let mut ks: Vec<_> = b.iter().map(|t| t.compensator).collect();
            ks.sort();
            assert_eq!(
                ks,
                CompensatorKind::STUDY.to_vec(),
                "each compensator exactly once per seat"
            );
            assert_eq!(
                b.iter().map(|t| t.position).collect::<Vec<_>>(),
                vec![1, 2, 3, 4, 5]
            );
        }
        let o1: Vec<_> = b1.iter().map(|t| t.compensator).collect();
        let o2: Vec<_> = b2.iter().map(|t| t.compensator).collect();
        assert_ne!(o1, o2, "the second order differs from the first");
        // Blinded labels: one per compensator, the same at both seats, never a name.
        for t in &b1 {
            let twin = b2.iter().find(|u| u.compensator == t.compensator).unwrap();
            assert_eq!(t.blinded_label, twin.blinded_label);
            assert!(t.blinded_label.starts_with("Controller "));
        }
        let mut labels: Vec<_> = b1.iter().map(|t| t.blinded_label.clone()).collect();
        labels.sort();
        labels.dedup();
        assert_eq!(labels.len(), 5);
    }
    assert_ne!(
        schedule(&p, 99, 0),
        schedule(&p, 100, 0),
        "the study seed matters"
    );
}

#[test]
fn the_identification_test_comes_first_on_the_machine_or_first_of_all_when_personalized() {
    use bdft_protocol::study::IdentificationParams;
    let mut p = default_params();
    for personalized in [false, true] {
        p.identification = Some(IdentificationParams {
            personalized,
            ..Default::default()
        });
        for idx in 0..4 {
            let s = schedule(&p, 7, idx);
            let id = s
                .iter()
                .find(|t| t.phase == TestPhase::Identification)
                .unwrap();
            assert_eq!(id.seat, Seat::On);
            // The queue runs by block, then queue order.
            let first_scored = s
                .iter()
                .filter(|t| t.phase == TestPhase::Test)
                .min_by_key(|t| (t.block, t.queue_order))
                .unwrap();
            let first_on = s
                .iter()
                .filter(|t| t.phase == TestPhase::Test && t.seat == Seat::On)
                .min_by_key(|t| (t.block, t.queue_order))
                .unwrap();
            let before = |t: &ScheduledTest| (id.block, id.queue_order) < (t.block, t.queue_order);
            assert!(before(first_on), "{idx}");
            assert_eq!(
                before(first_scored),
                personalized || first_scored.seat == Seat::On
            );
        }
    }
}

#[test]
fn cancellation_is_crossed_with_the_compensators_on_the_machine_alone_and_blinded() {
    use bdft_protocol::study::{CancellationParams, IdentificationParams};
    use std::collections::{BTreeMap, BTreeSet};
    let mut p = default_params();
    p.identification = Some(IdentificationParams::default());
    p.cancellation = Some(CancellationParams {
        arms: vec![CancellationArm::Personal, CancellationArm::Generic],
        ..Default::default()
    });
    p.validate().unwrap();
    let (consent, _) = p.rendered_texts().unwrap();
    assert!(
        consent
            .text
            .contains("20 tests of 140 seconds each: 15 while seated on the machine"),
        "{}",
        consent.text
    );
    assert!(
        consent
            .text
            .contains("you are not told which tests these are")
    );
    for design in [OrderDesign::Random, OrderDesign::Williams] {
        p.order_design = design;
        // Over 15 subjects (the Williams rows for 15 cells) every cell is in every
        // position on the machine equally often.
        let mut positions: BTreeMap<(CompensatorKind, CancellationArm), BTreeSet<u32>> =
            BTreeMap::new();
        for idx in 0..15 {
            let s = schedule(&p, 3, idx);
            assert_eq!(s, schedule(&p, 3, idx), "reproducible");
            let scored: Vec<&ScheduledTest> =
                s.iter().filter(|t| t.phase == TestPhase::Test).collect();
            let on: Vec<_> = scored.iter().filter(|t| t.seat == Seat::On).collect();
            let off: Vec<_> = scored.iter().filter(|t| t.seat == Seat::Off).collect();
            assert_eq!((on.len(), off.len()), (15, 5));
            let cells: BTreeSet<_> = on.iter().map(|t| (t.compensator, t.cancellation)).collect();
            assert_eq!(cells.len(), 15, "each compensator once per arm");
            assert!(off.iter().all(|t| t.cancellation == CancellationArm::Off));
            // Slots unique and in order; the identification before every cancelling test.
            let slots: BTreeSet<u32> = s.iter().map(|t| t.slot).collect();
            assert_eq!(slots.len(), s.len());
            let id = s
                .iter()
                .find(|t| t.phase == TestPhase::Identification)
                .unwrap();
            for t in &on {
                assert!((id.block, id.queue_order) < (t.block, t.queue_order));
            }
            // Blind: a label per cell on the machine, none naming the arm; at the desk a
            // compensator has its uncancelled label.
            let labels: BTreeSet<&str> = on.iter().map(|t| t.blinded_label.as_str()).collect();
            assert_eq!(labels.len(), 15);
            assert!(labels.iter().all(|l| l.starts_with("Controller ")));
            for d in &off {
                let twin = on
                    .iter()
                    .find(|t| {
                        t.compensator == d.compensator && t.cancellation == CancellationArm::Off
                    })
                    .unwrap();
                assert_eq!(d.blinded_label, twin.blinded_label);
            }
            for t in &on {
                positions
                    .entry((t.compensator, t.cancellation))
                    .or_default()
                    .insert(t.position);
            }
        }
        if design == OrderDesign::Williams {
            assert!(positions.values().all(|p| p.len() == 15), "{positions:?}");
        }
    }
    // Without identification the factor is refused, naming it.
    p.identification = None;
    assert!(
        p.validate()
            .unwrap_err()
            .to_string()
            .starts_with("cancellation: a cancelling arm needs the study's identification")
    );
}

#[test]
fn studies_without_the_design_aids_keep_their_hash_orders_and_targets() {
    // A study stored before the design aids existed (its JSON without them) parses, and
    // hashes as its stored JSON did: at their defaults they are left out of the hashed
    // JSON.
    let p = default_params();
    let mut stored = serde_json::to_value(&p).unwrap();
    let fields = stored.as_object_mut().unwrap();
    fields.remove("order_design");
    fields.remove("matched_targets");
    let before = bdft_protocol::hex::sha256(stored.to_string().as_bytes());
    let parsed: StudyParams = serde_json::from_value(stored).unwrap();
    assert_eq!(parsed, p);
    assert_eq!(protocol_hash(&parsed), before);
    // Orders, labels and target seeds printed by this code at commit 548fbae, before the
    // design aids existed: a random-order study draws the same.
    let s = schedule(&p, 42, 1);
    let got: Vec<(String, u64)> = s
        .iter()
        .map(|t| {
            (
                format!("{} {}", t.compensator, t.blinded_label),
                t.target_seed,
            )
        })
        .collect();
    let want = [
        ("pid Practice", 2825990621681512),
        ("lqr-cabvel Controller 4", 8625465733573564),
        ("pid-shaper Controller 5", 8592553454261585),
        ("pid Controller 3", 5190547355146260),
        ("lqr Controller 2", 2912446273349778),
        ("pid-notch Controller 1", 7598544895189793),
        ("lqr Controller 2", 4814618595203681),
        ("pid-notch Controller 1", 7097563375347571),
        ("pid-shaper Controller 5", 4176194195833212),
        ("pid Controller 3", 2236093709095440),
        ("lqr-cabvel Controller 4", 1568883948158621),
    ];
    assert_eq!(got, want.map(|(a, b)| (a.to_string(), b)));
    // A matched or Williams study is a different protocol: another hash.
    let mut q = p.clone();
    q.order_design = OrderDesign::Williams;
    assert_ne!(protocol_hash(&q), protocol_hash(&p));
    let mut q = p.clone();
    q.matched_targets = true;
    assert_ne!(protocol_hash(&q), protocol_hash(&p));
}

#[test]
fn williams_schedules_follow_the_rows_at_each_seat() {
    for k in 2..=5 {
        let mut p = default_params();
        p.compensators.truncate(k);
        p.order_design = OrderDesign::Williams;
        let kinds: Vec<CompensatorKind> = p.compensators.iter().map(|c| c.kind()).collect();
        let rows = williams::rows(k);
        let n = rows.len() as u32;
        for idx in 0..2 * n {
            let s = schedule(&p, 5, idx);
            assert_eq!(s, schedule(&p, 5, idx), "reproducible");
            let order = |seat: Seat| -> Vec<usize> {
                s.iter()
                    .filter(|t| t.phase == TestPhase::Test && t.seat == seat)
                    .map(|t| kinds.iter().position(|&c| c == t.compensator).unwrap())
                    .collect()
            };
            assert_eq!(order(Seat::On), rows[(idx % n) as usize], "k {k}, {idx}");
            assert_eq!(
                order(Seat::Off),
                rows[((idx + n / 2) % n) as usize],
                "k {k}, {idx}"
            );
            assert_eq!(s[1].seat, starting_seat(idx));
            assert_ne!(order(Seat::On), order(Seat::Off));
        }
    }
}

#[test]
fn matched_study_targets_share_one_step_change() {
    let mut p = default_params();
    p.matched_targets = true;
    let wanted = 2.0 * p.target_std_mm * p.target_std_mm;
    for idx in 0..4 {
        for t in schedule(&p, 3, idx) {
            let tg = target(&p, &t).unwrap();
            assert!(
                (tg.ms_step_mm2 / wanted - 1.0).abs() < 1e-9,
                "{}",
                tg.ms_step_mm2
            );
            assert!(tg.mean_mm.abs() < 1e-9);
            assert!((tg.std_mm / p.target_std_mm - 1.0).abs() < 1e-12);
        }
    }
}

#[test]
fn orders_are_balanced_across_many_subjects() {
    // Random order: each compensator should come first about 1/5 of the time.
    let p = default_params();
    let mut first = std::collections::HashMap::new();
    let n = 2000;
    for idx in 0..n {
        let s = schedule(&p, 7, idx);
        *first.entry(s[1].compensator).or_insert(0) += 1;
    }
    for k in CompensatorKind::STUDY {
        let share = f64::from(first[&k]) / f64::from(n);
        // Binomial standard error at n = 2000: 0.009.
        assert!((share - 0.2).abs() < 0.04, "{k}: {share}");
    }
}

#[test]
fn targets_meet_the_statistics_for_every_test() {
    let p = default_params();
    for idx in 0..10 {
        for t in schedule(&p, 3, idx) {
            let tg = target(&p, &t).unwrap();
            assert!(tg.mean_mm.abs() <= 1.0);
            assert!((tg.std_mm / p.target_std_mm - 1.0).abs() <= 0.05);
            assert!(tg.levels_mm.iter().all(|l| l.abs() <= p.target_range_mm));
            assert_eq!(
                tg.levels_mm.len() as f64,
                (t.duration_s / p.step_interval_s).ceil()
            );
        }
    }
}
