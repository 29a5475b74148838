//! The default population against the thesis's findings (§6.2–6.3 of its eight people), on a
//! seeded 8-subject pilot and on a larger population (medians), so none regresses silently.

use std::sync::OnceLock;
use std::sync::atomic::AtomicBool;

use bdft_protocol::params::Seat;
use bdft_protocol::study::StudyParams;

use super::findings::{Findings, summarize};
use super::sim::{SubjectRef, all_cells, enrolled, simulate};
use crate::engine::dry_runs::job::Progress;
use crate::engine::study::schedule::default_params;

/// The findings of `subjects` of the default study with tests of `trial_s`.
fn findings(subjects: &[SubjectRef], trial_s: f64) -> Findings {
    let params = StudyParams {
        trial_s,
        practice_s: trial_s.min(120.0),
        ..default_params()
    };
    let cells = all_cells(&params);
    let rows = simulate(
        &params,
        subjects,
        &cells,
        &Progress::default(),
        &AtomicBool::new(false),
    )
    .unwrap();
    summarize(&params, &cells, &rows)
}

/// The 8-subject pilot of the default study seeded 11 (the issue's).
fn pilot() -> &'static Findings {
    static F: OnceLock<Findings> = OnceLock::new();
    F.get_or_init(|| findings(&enrolled(11, 8), 140.0))
}

/// 64 subjects of the default study seeded 1: what a slow dev-profile test affords (the
/// model card's table runs larger populations in a release build).
fn population() -> &'static Findings {
    static F: OnceLock<Findings> = OnceLock::new();
    F.get_or_init(|| findings(&enrolled(1, 64), 140.0))
}

fn cell<'a>(f: &'a Findings, controller: &str, seat: Seat) -> &'a super::findings::CellSummary {
    f.cells
        .iter()
        .find(|c| c.controller == controller && c.station == seat.as_str())
        .expect("cell")
}

const PID_FAMILY: [&str; 3] = ["pid", "pid-notch", "pid-shaper"];

fn riding_hurts(f: &Findings) {
    let r: Vec<f64> = f.on_off_ratio.iter().map(|r| r.unwrap()).collect();
    // "The operator performs better off the tractor with every controller", by roughly a
    // quarter up to more than double.
    assert!(r.iter().all(|&x| x > 1.12), "on/off {r:?}");
    assert!(r.iter().any(|&x| x > 1.35), "on/off {r:?}");
}

#[test]
fn riding_costs_accuracy_with_every_controller() {
    riding_hurts(pilot());
    riding_hurts(population());
}

#[test]
fn riding_never_helps_at_any_test_length_the_form_allows() {
    for (s, n) in [(10.0, 48), (30.0, 32)] {
        let f = findings(&enrolled(5, n), s);
        assert!(
            f.on_off_ratio.iter().all(|r| r.unwrap() > 1.0),
            "{s} s: on/off {:?}",
            f.on_off_ratio
        );
    }
}

#[test]
fn error_level_is_the_thesiss() {
    // Mean-squared errors of roughly 90 to 250 mm² (medians: 70–260 allowed).
    for f in [pilot(), population()] {
        for c in &f.cells {
            assert!((70.0..=260.0).contains(&c.median_mse_tracking_mm2), "{c:?}");
        }
    }
}

#[test]
fn off_the_machine_the_lqr_tracks_best() {
    for f in [pilot(), population()] {
        let lqr = cell(f, "lqr", Seat::Off).median_mse_tracking_mm2;
        for k in PID_FAMILY {
            let other = cell(f, k, Seat::Off).median_mse_tracking_mm2;
            assert!(lqr < other, "lqr {lqr} vs {k} {other}");
        }
    }
}

#[test]
fn vibration_reductions_are_modest_and_the_lqr_shakes_most() {
    for f in [pilot(), population()] {
        let acc = |k| cell(f, k, Seat::On).median_rms_cab_accel_m_s2;
        // "Some improvement" (shaper vs PID), "some reduction" (cab velocity vs LQR): less
        // than the 3–4× of before, still a reduction.
        for (better, base) in [("pid-shaper", "pid"), ("lqr-cabvel", "lqr")] {
            let ratio = acc(better) / acc(base);
            assert!((0.55..1.0).contains(&ratio), "{better}/{base}: {ratio}");
        }
        for k in PID_FAMILY {
            assert!(acc("lqr") > acc(k), "lqr {} vs {k} {}", acc("lqr"), acc(k));
        }
    }
}

#[test]
fn people_rarely_trip_the_interlock() {
    let stopped = |f: &Findings| f.cells.iter().map(|c| c.stopped).sum::<usize>();
    assert_eq!(stopped(pilot()), 0);
    // At most 2 % of the population's tests on the machine.
    let tests_on = 64 * 5;
    assert!(
        stopped(population()) * 50 <= tests_on,
        "{} stopped",
        stopped(population())
    );
}

#[test]
fn subjects_differ_consistently_across_their_tests() {
    let icc = population().icc_log_mse.unwrap();
    assert!(icc >= 0.5, "ICC {icc}");
}

mod calibrate {
    use std::sync::atomic::AtomicBool;

    use bdft_protocol::study::StudyParams;

    use crate::engine::dry_runs::calibration::fit::{FitReport, fit};
    use crate::engine::dry_runs::calibration::sim::{all_cells, enrolled, simulate};
    use crate::engine::dry_runs::calibration::target::{
        Metric, Target, from_subjects, parse_table,
    };
    use crate::engine::dry_runs::job::Progress;
    use crate::engine::study::schedule::default_params;
    use crate::error::AppError;

    /// The default study with 20 s tests: what a dev-profile test affords.
    fn study() -> StudyParams {
        StudyParams {
            trial_s: 20.0,
            practice_s: 20.0,
            ..default_params()
        }
    }

    /// The population the data come from: the default one with other medians.
    fn truth() -> StudyParams {
        let mut p = study();
        p.population.reaction_delay_s.median = 0.32;
        p.population.vibration_slowing_per_m_s2.median = 2.5;
        p
    }

    /// A pilot of `n` subjects of the true population (seed 77): each subject's metrics in
    /// every cell.
    fn pilot(n: u32) -> Target {
        let p = truth();
        let cells = all_cells(&p);
        let rows = simulate(
            &p,
            &enrolled(77, n),
            &cells,
            &Progress::default(),
            &AtomicBool::new(false),
        )
        .unwrap();
        from_subjects(&cells, rows)
    }

    fn run(target: &Target, source: &str) -> FitReport {
        fit(
            &study(),
            target,
            source,
            24,
            5,
            &Progress::default(),
            &AtomicBool::new(false),
        )
        .unwrap()
    }

    #[test]
    fn recovers_a_populations_own_medians_from_its_pilot_within_its_intervals() {
        let target = pilot(24);
        let report = run(&target, "pilot");
        let truth = truth().population;
        let want = |name: &str| match name {
            "reaction_delay_s" => Some(truth.reaction_delay_s.median),
            "vibration_slowing_per_m_s2" => Some(truth.vibration_slowing_per_m_s2.median),
            "error_gain" => Some(truth.error_gain.median),
            "body_k_h" => Some(truth.body_k_h.median),
            _ => None,
        };
        let delay = report
            .parameters
            .iter()
            .find(|p| p.name == "reaction_delay_s")
            .expect("the delay is identified by tracking error");
        assert!(report.objective < report.objective_before, "{report:#?}");
        for p in &report.parameters {
            if let Some(w) = want(&p.name) {
                assert!(
                    p.low <= w && w <= p.high,
                    "{}: {w} not in [{}, {}]",
                    p.name,
                    p.low,
                    p.high
                );
            }
        }
        // The start (0.25 s) is outside the delay's interval: the data moved it.
        assert!(delay.low > 0.25, "{delay:?}");
    }

    #[test]
    fn fits_a_published_style_table_within_its_stated_error_and_predicts_the_rest() {
        // Means of tracking error only, as a paper's table gives them, with sd and n.
        let target = pilot(32);
        let mut csv = String::from("controller,station,metric,mean,sd,n\n");
        for t in target
            .cells
            .iter()
            .filter(|t| t.metric == Metric::MseTrackingMm2)
        {
            let kind = study().controllers[t.cell.controller].kind();
            csv += &format!(
                "{},{},mse_tracking_mm2,{:.1},{:.1},{}\n",
                kind.name(),
                t.cell.seat.as_str(),
                t.mean,
                t.sd.unwrap(),
                t.n.unwrap()
            );
        }
        let table = parse_table(&study(), &csv).unwrap();
        assert_eq!(table.cells.len(), 10);
        let report = run(&table, "table");
        for c in &report.cells {
            let t = c.target.unwrap();
            let se = c.target_sd.unwrap() / (c.target_n.unwrap() as f64).sqrt();
            let stated = 2.5 * (se * se + c.monte_carlo_error.powi(2)).sqrt();
            assert!(
                (c.prediction - t).abs() <= stated,
                "{} {}: {} vs {t} ± {stated}",
                c.controller,
                c.station,
                c.prediction
            );
        }
        // Cab acceleration was not in the table: predicted in every cell.
        assert_eq!(
            report
                .predictions
                .iter()
                .filter(|p| p.metric == "ms_cab_accel")
                .count(),
            10
        );
    }

    fn refused(csv: &str) -> String {
        let mut p = study();
        p.controllers.truncate(3);
        match parse_table(&p, csv).and_then(|t| {
            crate::engine::dry_runs::calibration::fit::check_enough(&t)?;
            Ok(t)
        }) {
            Err(AppError::BadRequest(m)) => m,
            other => panic!("not refused: {other:?}"),
        }
    }

    #[test]
    fn bad_tables_are_refused_naming_the_row() {
        let head = "controller,station,metric,mean\n";
        let ok = "pid,on,mse_tracking_mm2,120\npid,off,mse_tracking_mm2,100\npid-notch,on,mse_tracking_mm2,110\n";
        let m = refused(&format!("{head}{ok}plain,on,mse_tracking_mm2,90\n"));
        assert!(
            m.starts_with("table row 4: controller \"plain\" is not one of pid"),
            "{m}"
        );
        let m = refused(&format!("{head}{ok}lqr,on,mse_tracking_mm2,90\n"));
        assert_eq!(
            m,
            "table row 4: the study runs no lqr test at the on station"
        );
        let m = refused(&format!("{head}{ok}pid-shaper,on,mse_tracking_mm2,-4\n"));
        assert!(
            m.starts_with("table row 4: mean -4: must be positive"),
            "{m}"
        );
        let m = refused(&format!("{head}{ok}pid-shaper,on,mse,4\n"));
        assert!(
            m.starts_with("table row 4: metric \"mse\": allowed mse_tracking_mm2"),
            "{m}"
        );
        let m = refused(&format!("{head}{ok}pid,on,mse_tracking_mm2,90\n"));
        assert!(
            m.starts_with("table row 4: pid at on (mse_tracking_mm2) is already"),
            "{m}"
        );
        let m = refused(&format!("{head}pid,sideways,mse_tracking_mm2,90\n"));
        assert!(m.starts_with("table row 1: station \"sideways\""), "{m}");
        let m = refused(&format!("{head}{ok}"));
        assert!(
            m.starts_with("table: 3 cells give 3 moments, too few for the 4 parameters"),
            "{m}"
        );
        let m = refused("controller,seat,metric,mean\n");
        assert!(m.starts_with("table: header"), "{m}");
    }
}
