//! The fit's tests (`fit`, `target`, `table_error`): a population's own medians recovered
//! from its pilot, a published-style table fitted within its stated error, bad tables
//! refused naming the row, the table's replicate errors against their analytic covariance.

mod calibrate {
    use std::sync::atomic::AtomicBool;

    use bdft_protocol::params::PopulationParams;
    use bdft_protocol::study::StudyParams;

    use crate::engine::dry_runs::calibration::fit::{FitReport, MEDIANS, fit, fit_with};
    use crate::engine::dry_runs::calibration::ratings::{ITEMS, PeopleRated, predicted};
    use crate::engine::dry_runs::calibration::sim::{all_cells, enrolled, simulate};
    use crate::engine::dry_runs::calibration::surveys::surveys;
    use crate::engine::dry_runs::calibration::target::{
        Metric, Target, from_subjects, hold_out, parse_table,
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
        p.population.vibration_delay_s_per_m_s2.median = 0.45;
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
            let kind = study().compensators[t.cell.compensator].kind();
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
                "vibration_delay_s_per_m_s2" => truth.vibration_delay_s_per_m_s2.median,
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
        let people = surveys(
            &truth(),
            &enrolled(77, 24),
            &all_cells(&truth()),
            &Progress::default(),
            &AtomicBool::new(false),
        )
        .unwrap();
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
                c.compensator,
                c.seat,
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
    /// population with the medians delay 0.30 s, error gain 0.36, vibration delay 0.45 s per m/s² and
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
        truth.population.vibration_delay_s_per_m_s2.median = 0.45;
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

    /// The coverage test's study: pid, pid-shaper and lqr at both stations (6 cells, 12
    /// rows of the two metrics) with 10 s tests, what a dev-profile test affords twenty
    /// fits of.
    fn small_study() -> StudyParams {
        let mut p = StudyParams {
            trial_s: 10.0,
            practice_s: 10.0,
            ..study()
        };
        p.compensators
            .retain(|c| ["pid", "pid-shaper", "lqr"].contains(&c.kind().name()));
        assert_eq!(p.compensators.len(), 3);
        p
    }

    /// A pilot's every row (both metrics) as a table with sd, n, unit and use, the rows at
    /// `held` (indices into the pilot's cells) marked hold-out.
    fn table_with_held_out(p: &StudyParams, pilot: &Target, held: &[usize]) -> String {
        let mut csv = String::from("controller,station,metric,mean,sd,n,unit,use\n");
        for (i, t) in pilot.cells.iter().enumerate() {
            csv += &format!(
                "{},{},{},{},{},{},{},{}\n",
                p.compensators[t.cell.compensator].kind().name(),
                t.cell.seat.as_str(),
                t.metric.name(),
                t.mean,
                t.sd.unwrap(),
                t.n.unwrap(),
                t.metric.units()[0].0,
                if held.contains(&i) { "hold-out" } else { "fit" }
            );
        }
        csv
    }

    /// Issue 42: over 20 synthetic populations near the default (each fitted median ×/÷ up
    /// to e^0.3, seeded), an 8-subject pilot's table with 5 of its 12 rows held out (a
    /// different 5 each time), fitted on the other 7 with 16 simulated subjects: the held-out
    /// rows' targets fall inside their 95 % prediction intervals in 88–99 of the 100 cases.
    /// The truth is drawn independently of the fit (its own seed, its own pilot's people),
    /// and the count is fixed by the seeds (the simulation is deterministic).
    #[test]
    fn held_out_rows_fall_inside_their_prediction_intervals_over_20_populations() {
        let base = small_study();
        let mut rng = bdft_controller::rng::Rng::new(4242);
        let (mut inside, mut total) = (0, 0);
        let mut misses = Vec::new();
        let mut verdicts = 0;
        for k in 0..20u64 {
            let mut truth = base.clone();
            for knob in MEDIANS {
                let v = (knob.get)(&truth.population) * (0.3 * (2.0 * rng.next_f64() - 1.0)).exp();
                (knob.set)(&mut truth.population, v.clamp(knob.bounds.0, knob.bounds.1));
            }
            let pilot = pilot_of(&truth, 1000 + k, 8);
            assert_eq!(pilot.cells.len(), 12);
            let held: Vec<usize> = (0..5).map(|j| (5 * k as usize + j) % 12).collect();
            let table = parse_table(&base, &table_with_held_out(&base, &pilot, &held)).unwrap();
            assert_eq!((table.cells.len(), table.held_out.len()), (7, 5));
            let report = fit_with(
                &base,
                &table,
                "coverage",
                16,
                k,
                false,
                &Progress::default(),
                &AtomicBool::new(false),
            )
            .unwrap();
            assert_eq!(report.held_out.len(), 5);
            verdicts += usize::from(report.goodness_of_fit.verdict.starts_with("fits"));
            for c in &report.held_out {
                let (low, high) = (c.low.unwrap(), c.high.unwrap());
                let t = c.target.unwrap();
                assert_eq!(c.inside, Some(low <= t && t <= high), "{c:?}");
                total += 1;
                if c.inside == Some(true) {
                    inside += 1;
                } else {
                    misses.push(format!(
                        "population {k}: {} {} {} {t:.4e} outside [{low:.4e}, {high:.4e}]",
                        c.compensator, c.seat, c.metric
                    ));
                }
            }
        }
        eprintln!(
            "coverage: {inside} of {total} held-out rows inside their 95 % intervals; {verdicts} of 20 fits judged \"fits\"; misses: {misses:#?}"
        );
        assert_eq!(total, 100);
        assert!((88..=99).contains(&inside), "{inside} of 100: {misses:#?}");
    }

    /// A table no population of the model can give (every controller's tracking error 20×
    /// higher at the desk than on the machine, from 100 people each) is judged a lack of
    /// fit, naming the worst cells; every fitted parameter within 1 % of a bound of
    /// `bdft_protocol::params::bounds` (or the fit's own floors) is named as at its bound,
    /// and no other.
    #[test]
    fn an_impossible_table_is_judged_a_lack_of_fit_and_its_parameters_at_a_bound_named() {
        let p = small_study();
        let mut csv = String::from("controller,station,metric,mean,sd,n\n");
        for kind in ["pid", "pid-shaper", "lqr"] {
            csv += &format!("{kind},on,mse_tracking_mm2,100,30,100\n");
            csv += &format!("{kind},off,mse_tracking_mm2,2000,600,100\n");
        }
        let table = parse_table(&p, &csv).unwrap();
        let report = fit_with(
            &p,
            &table,
            "impossible",
            16,
            3,
            false,
            &Progress::default(),
            &AtomicBool::new(false),
        )
        .unwrap();
        let g = &report.goodness_of_fit;
        assert!(
            g.verdict.starts_with("lack of fit") && g.p_value.unwrap() < 1e-6,
            "{g:?}"
        );
        assert!(g.verdict.contains("worst: "), "{g:?}");
        assert_eq!(g.dof, 7 - report.parameters.len() as i64, "{g:?}");
        let bounds = [
            (
                "reaction_delay_s",
                bdft_protocol::params::bounds::REACTION_DELAY_S,
            ),
            (
                "error_gain",
                (0.02, bdft_protocol::params::bounds::ERROR_GAIN.1),
            ),
            (
                "vibration_delay_s_per_m_s2",
                (
                    0.01,
                    bdft_protocol::params::bounds::VIBRATION_DELAY_S_PER_M_S2.1,
                ),
            ),
            ("body_k_h", bdft_protocol::params::bounds::BODY_K_H),
        ];
        for fp in &report.parameters {
            let Some(&(_, (lo, hi))) = bounds.iter().find(|b| b.0 == fp.name) else {
                continue;
            };
            let at = (fp.fitted / lo).ln().abs() <= 0.01 || (hi / fp.fitted).ln().abs() <= 0.01;
            let named = report.at_bound.iter().any(|a| a.starts_with(&fp.name));
            assert_eq!(
                at, named,
                "{} {} in [{lo}, {hi}]: {:?}",
                fp.name, fp.fitted, report.at_bound
            );
            if at {
                assert!(g.verdict.contains(&fp.name), "{g:?}");
            }
        }
        // Cab acceleration was never fitted: its discrepancy is unknown, and said so.
        let acc = &report.discrepancy[1];
        assert_eq!((acc.metric.as_str(), acc.log_sd), ("ms_cab_accel", None));
        assert!(report.predictions.iter().all(|c| c.metric != "ms_cab_accel"
            || c.note.as_deref().is_some_and(|n| n.contains("unknown"))));
    }

    #[test]
    fn units_hold_outs_and_unrecorded_metrics_are_read_or_refused_naming_the_row_or_item() {
        let p = study();
        // Table 8's desk column in the thesis's unit, ×10⁵ (mm/s²)²; tracking error in cm².
        let csv = "controller,station,metric,mean,sd,n,unit,use\n\
            pid,off,ms_cab_accel,3.02,0.5,8,1e5mm2/s4,\n\
            pid,off,mse_tracking_mm2,1.2,,,cm2,fit\n\
            lqr,off,ms_cab_accel,4.32,,,1e5 mm²/s⁴,hold-out\n\
            lqr,on,mse_tracking_mm2,1.5,,,cm2,\n";
        let mut t = parse_table(&p, csv).unwrap();
        assert_eq!((t.cells.len(), t.held_out.len()), (3, 1));
        assert!((t.cells[0].mean - 3.02e5).abs() < 1e-6, "{:?}", t.cells[0]);
        assert!((t.cells[0].sd.unwrap() - 0.5e5).abs() < 1e-6);
        assert!((t.cells[1].mean - 120.0).abs() < 1e-9);
        assert_eq!(t.held_out[0].row, Some(3));
        assert!((t.held_out[0].mean - 4.32e5).abs() < 1e-6);
        // --hold-out moves fitted rows out, a cell's every metric without one.
        hold_out(&p, &mut t, " pid:off:ms_cab_accel , lqr:on").unwrap();
        assert_eq!((t.cells.len(), t.held_out.len()), (1, 3));
        assert_eq!(t.cells[0].metric, Metric::MseTrackingMm2);

        let refused_table = |rows: &str| match parse_table(
            &p,
            &format!("controller,station,metric,mean,sd,n,unit,use\n{rows}"),
        ) {
            Err(AppError::BadRequest(m)) => m,
            other => panic!("not refused: {other:?}"),
        };
        assert_eq!(
            refused_table(
                "pid,off,ms_cab_accel,3.02,,,1e5mm2/s4,\npid,on,ms_cab_accel,302000,,,mm2/s4,\n"
            ),
            "table row 2: ms_cab_accel in mm2/s4, but row 1 gave it in 1e5mm2/s4; a table gives each metric in one unit"
        );
        assert_eq!(
            refused_table("pid,off,mse_tracking_mm2,3,,,ft2,\n"),
            "table row 1: unit \"ft2\" for mse_tracking_mm2: allowed mm2, cm2, m2"
        );
        assert_eq!(
            refused_table(
                "pid,on,mse_tracking_mm2,3,,,,fit\nlqr,on,mse_tracking_mm2,3,,,,\npid,on,mse_tracking_mm2,4,,,,hold-out\n"
            ),
            "table row 3: pid at on (mse_tracking_mm2) is held out here and fitted on row 1; a cell is fitted or held out, not both"
        );
        assert_eq!(
            refused_table("pid,on,mse_tracking_mm2,4,,,,hold-out\npid,on,mse_tracking_mm2,3,,,,\n"),
            "table row 2: pid at on (mse_tracking_mm2) is fitted here and held out on row 1; a cell is fitted or held out, not both"
        );
        assert_eq!(
            refused_table("pid,on,mse_tracking_mm2,4,,,,maybe\n"),
            "table row 1: use \"maybe\": allowed fit, hold-out"
        );
        assert!(
            refused_table("pid,on,rating_accuracy,4,,,,\n").starts_with(
                "table row 1: metric \"rating_accuracy\" is not one the study records; allowed mse_tracking_mm2 (mm2), ms_cab_accel (mm2/s4)"
            )
        );

        let table = parse_table(&p, "controller,station,metric,mean\npid,on,mse_tracking_mm2,3\npid,off,mse_tracking_mm2,3\n").unwrap();
        let refused_item = |spec: &str| {
            let mut t = table.clone();
            match hold_out(&p, &mut t, spec) {
                Err(AppError::BadRequest(m)) => m,
                other => panic!("not refused: {other:?}"),
            }
        };
        assert_eq!(
            refused_item("pid:on,lqr:off"),
            "hold_out item 2 \"lqr:off\": the target has no lqr at off to hold out (its fitted rows are the ones to name)"
        );
        assert_eq!(
            refused_item("pid:on:mse_tracking_mm2,pid:on"),
            "hold_out item 2 \"pid:on\": pid at on is held out already (an earlier item, or the table's use column)"
        );
        assert!(
            refused_item("pid:on:rating_speed").starts_with(
                "hold_out item 1 \"pid:on:rating_speed\": metric \"rating_speed\" is not one the study records"
            )
        );
        assert!(
            refused_item("pid-on")
                .starts_with("hold_out item 1 \"pid-on\": expected controller:station")
        );
        assert!(
            refused_item("plain:on")
                .starts_with("hold_out item 1 \"plain:on\": controller \"plain\" is not one of")
        );
        assert_eq!(
            refused_item("pid:up"),
            "hold_out item 1 \"pid:up\": station \"up\": allowed on, off"
        );
    }

    /// A row no simulated subject can complete (every test on the machine stopped by an
    /// interlock set at its lowest) is refused naming it, before any fitting: there is no
    /// mean to fit to (it once became ln 1e-12, an enormous finite misfit).
    #[test]
    fn a_row_the_population_cannot_complete_is_refused_naming_it() {
        let mut p = small_study();
        p.max_cab_rms_mm_s2 = 10.0;
        p.validate().unwrap();
        let csv = "controller,station,metric,mean\n\
                   pid,on,mse_tracking_mm2,160\npid,off,mse_tracking_mm2,110\n\
                   pid-shaper,on,mse_tracking_mm2,150\npid-shaper,off,mse_tracking_mm2,115\n\
                   lqr,on,mse_tracking_mm2,170\nlqr,off,mse_tracking_mm2,90\n";
        let target = parse_table(&p, csv).unwrap();
        match fit(
            &p,
            &target,
            "table",
            8,
            1,
            &Progress::default(),
            &AtomicBool::new(false),
        ) {
            Err(AppError::Conflict(m)) => {
                assert!(
                    m.starts_with("fewer than 2 of the 8 simulated subjects completed ")
                        && m.contains("pid on mse_tracking_mm2")
                        && m.contains("lqr on mse_tracking_mm2"),
                    "{m}"
                );
            }
            other => panic!("not refused: {other:?}"),
        }
    }

    fn refused(csv: &str) -> String {
        let mut p = study();
        p.compensators.truncate(3);
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
        assert_eq!(
            m,
            "table row 4: metric \"mse\" is not one the study records; allowed mse_tracking_mm2 (mm2), ms_cab_accel (mm2/s4)"
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
