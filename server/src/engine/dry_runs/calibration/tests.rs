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
        .find(|c| c.compensator == controller && c.seat == seat.as_str())
        .expect("cell")
}

const PID_FAMILY: [&str; 3] = ["pid", "pid-notch", "pid-shaper"];
const CONTROLLERS: [&str; 5] = ["pid", "pid-notch", "pid-shaper", "lqr", "lqr-cabvel"];

#[test]
fn riding_costs_accuracy_with_every_compensator() {
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
            .compensators
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
fn people_lose_tests_to_the_interlock_about_as_often_as_the_thesiss() {
    // The thesis ran "80 tests (minus two incomplete tests)" (§6.2, reason not given): the
    // pilot loses at most two of its 80, the population at most 3 % of its tests (2 of 80
    // is 2.5 %; its 95 % binomial interval reaches 8.7 %).
    let stopped = |f: &Findings| f.cells.iter().map(|c| c.stopped).sum::<usize>();
    let pilot = stopped(pilot(140.0));
    assert!(pilot <= 2, "{pilot} of the pilot's 80 tests stopped");
    let tests = 1000 * 10;
    let population = stopped(population(140.0));
    assert!(population * 100 <= 3 * tests, "{population} stopped");
}

#[test]
fn riding_shakes_the_cab_more_with_every_compensator_and_the_desk_is_table_8s() {
    // §6.2: the thesis's people shook the cab more on the machine with every controller;
    // at the desk they shook it as Table 8's off-tractor column says (mean over subjects of
    // the mean-squared cab acceleration), here within 1.5× in every cell.
    for f in both() {
        for (k, thesis) in super::findings::THESIS_DESK_MS_CAB_ACCEL_E5 {
            let ms = |seat| cell(f, k, seat).mean_ms_cab_accel;
            assert!(
                ms(Seat::On) > ms(Seat::Off),
                "{k}: on {} off {}",
                ms(Seat::On),
                ms(Seat::Off)
            );
            let ratio = ms(Seat::Off) / (thesis * 1e5);
            assert!(
                (1.0 / 1.5..=1.5).contains(&ratio),
                "{k}: desk/Table 8 {ratio}"
            );
        }
    }
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
        .filter(|c| c.seat == Seat::On || c.compensator == 0)
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
        .find(|c| c.compensator == controller && c.seat == seat.as_str())
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
