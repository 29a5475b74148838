//! The default population against the thesis's findings (§6.2–6.3 of its eight people), on a
//! seeded 8-subject pilot and on a larger population (medians), so none regresses silently.

use std::sync::OnceLock;
use std::sync::atomic::AtomicBool;

use bdft_protocol::params::Seat;
use bdft_protocol::study::StudyParams;

use super::findings::{Findings, summarize};
use super::sim::{SubjectRef, all_cells, enrolled, simulate};
use super::surveys::{SurveyCell, surveys};
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

/// The test lengths the findings are checked at: the study form's shortest practical, a
/// middle one and the published 140 s.
const LENGTHS: [f64; 3] = [10.0, 30.0, 140.0];

fn cached(
    cache: &'static [OnceLock<Findings>; 3],
    trial_s: f64,
    subjects: impl FnOnce() -> Vec<SubjectRef>,
) -> &'static Findings {
    let at = LENGTHS
        .iter()
        .position(|&s| s == trial_s)
        .expect("one of LENGTHS");
    cache[at].get_or_init(|| findings(&subjects(), trial_s))
}

/// The 8-subject pilot of the default study seeded 11 (the issue's).
fn pilot(trial_s: f64) -> &'static Findings {
    static F: [OnceLock<Findings>; 3] = [OnceLock::new(), OnceLock::new(), OnceLock::new()];
    cached(&F, trial_s, || enrolled(11, 8))
}

/// 1,000 subjects of the default study seeded 1: the population's medians, which a pilot's
/// luck cannot carry.
fn population(trial_s: f64) -> &'static Findings {
    static F: [OnceLock<Findings>; 3] = [OnceLock::new(), OnceLock::new(), OnceLock::new()];
    cached(&F, trial_s, || enrolled(1, 1000))
}

/// Both, with the published 140 s tests.
fn both() -> [&'static Findings; 2] {
    [pilot(140.0), population(140.0)]
}

fn cell<'a>(f: &'a Findings, controller: &str, seat: Seat) -> &'a super::findings::CellSummary {
    f.cells
        .iter()
        .find(|c| c.controller == controller && c.station == seat.as_str())
        .expect("cell")
}

const PID_FAMILY: [&str; 3] = ["pid", "pid-notch", "pid-shaper"];
const CONTROLLERS: [&str; 5] = ["pid", "pid-notch", "pid-shaper", "lqr", "lqr-cabvel"];

#[test]
fn riding_costs_accuracy_with_every_controller() {
    for f in both() {
        let r: Vec<f64> = f.on_off_ratio.iter().map(|r| r.unwrap()).collect();
        // "The operator performs better off the tractor with every controller", by roughly
        // a quarter up to more than double.
        assert!(r.iter().all(|&x| x > 1.12), "on/off {r:?}");
        assert!(r.iter().any(|&x| x > 1.35), "on/off {r:?}");
    }
}

#[test]
fn riding_never_helps_at_any_test_length_the_form_allows() {
    for s in LENGTHS {
        for f in [pilot(s), population(s)] {
            assert!(
                f.on_off_ratio.iter().all(|r| r.unwrap() > 1.0),
                "{s} s: on/off {:?}",
                f.on_off_ratio
            );
        }
    }
}

#[test]
fn error_level_is_the_thesiss() {
    // Mean-squared errors of roughly 90 to 250 mm² (medians: 70–260 allowed).
    for f in both() {
        for c in &f.cells {
            assert!((70.0..=260.0).contains(&c.median_mse_tracking_mm2), "{c:?}");
        }
    }
}

#[test]
fn off_the_machine_the_lqr_tracks_best() {
    for f in both() {
        let lqr = cell(f, "lqr", Seat::Off).median_mse_tracking_mm2;
        for k in PID_FAMILY {
            let other = cell(f, k, Seat::Off).median_mse_tracking_mm2;
            assert!(lqr < other, "lqr {lqr} vs {k} {other}");
        }
    }
}

#[test]
#[ignore = "not reproduced yet (docs/synthetic-subjects.md): the LQR is second best on the machine"]
fn on_the_machine_the_lqr_tracks_worst_or_near_worst() {
    // "Worst or near worst on it", with the largest riding effect of all.
    for f in both() {
        let on = |k| cell(f, k, Seat::On).median_mse_tracking_mm2;
        let better = CONTROLLERS.iter().filter(|&&k| on(k) > on("lqr")).count();
        assert!(better <= 1, "lqr {} on, {better} designs worse", on("lqr"));
        let at = default_params()
            .controllers
            .iter()
            .position(|c| c.kind().name() == "lqr")
            .expect("the default study runs the lqr");
        let lqr = f.on_off_ratio[at].unwrap();
        assert!(
            f.on_off_ratio.iter().all(|r| r.unwrap() <= lqr),
            "on/off {:?}",
            f.on_off_ratio
        );
    }
}

#[test]
fn vibration_reductions_are_modest_and_the_lqr_shakes_most() {
    for f in both() {
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
    assert_eq!(stopped(pilot(140.0)), 0);
    // At most 1 % of the population's tests on the machine.
    let tests_on = 1000 * 5;
    let population = stopped(population(140.0));
    assert!(population * 100 <= tests_on, "{population} stopped");
}

#[test]
fn subjects_differ_consistently_across_their_tests() {
    for f in both() {
        let icc = f.icc_log_mse.unwrap();
        assert!(icc >= 0.5, "ICC {icc}");
    }
}

/// The pilot's survey answers with 140 s tests.
fn answers() -> &'static [SurveyCell] {
    static A: OnceLock<Vec<SurveyCell>> = OnceLock::new();
    A.get_or_init(|| {
        let params = default_params();
        surveys(&params, &enrolled(11, 8), &all_cells(&params)).unwrap()
    })
}

/// Mean rating `item` (0 accuracy, 1 speed, 2 smoothness) of `controller` at `seat`.
fn rated(controller: &str, seat: Seat, item: usize) -> f64 {
    answers()
        .iter()
        .find(|c| c.controller == controller && c.station == seat.as_str())
        .expect("cell")
        .mean_ratings[item]
}

#[test]
#[ignore = "not reproduced yet (docs/synthetic-subjects.md): off the machine the cab-velocity LQR ties the shaper"]
fn surveys_accuracy_alike_on_the_machine_and_the_lqr_designs_more_accurate_off_it() {
    let on: Vec<f64> = CONTROLLERS.iter().map(|k| rated(k, Seat::On, 0)).collect();
    let spread =
        on.iter().copied().fold(f64::MIN, f64::max) - on.iter().copied().fold(f64::MAX, f64::min);
    // Alike: within a point of each other on the 7-point scale.
    assert!(spread <= 1.0, "accuracy on the machine {on:?}");
    for lqr in ["lqr", "lqr-cabvel"] {
        for k in PID_FAMILY {
            assert!(
                rated(lqr, Seat::Off, 0) > rated(k, Seat::Off, 0),
                "{lqr} vs {k} off: {} vs {}",
                rated(lqr, Seat::Off, 0),
                rated(k, Seat::Off, 0)
            );
        }
    }
}

#[test]
fn surveys_the_notch_is_perceived_slower() {
    for seat in [Seat::On, Seat::Off] {
        assert!(
            rated("pid-notch", seat, 1) < rated("pid", seat, 1),
            "{seat:?}: notch {} vs pid {}",
            rated("pid-notch", seat, 1),
            rated("pid", seat, 1)
        );
    }
}

#[test]
#[ignore = "not reproduced yet (docs/synthetic-subjects.md): off the machine the two rate alike"]
fn surveys_cab_velocity_feels_faster_than_lqr_on_the_machine_and_slower_off_it() {
    let speed = |k, seat| rated(k, seat, 1);
    assert!(speed("lqr-cabvel", Seat::On) > speed("lqr", Seat::On));
    assert!(speed("lqr-cabvel", Seat::Off) < speed("lqr", Seat::Off));
}

#[test]
fn surveys_the_vibration_compensated_designs_feel_smoother_on_the_machine() {
    let smooth = |k| rated(k, Seat::On, 2);
    for (compensated, base) in [
        ("pid-notch", "pid"),
        ("pid-shaper", "pid"),
        ("lqr-cabvel", "lqr"),
    ] {
        assert!(
            smooth(compensated) > smooth(base),
            "{compensated} {} vs {base} {}",
            smooth(compensated),
            smooth(base)
        );
    }
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
