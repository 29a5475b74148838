//! Whether a study can run, checked when it is created or edited (not first at enrolment or
//! at a trial's start): every test's target can be drawn, and every compensator — the
//! practice's included — can be built as the controller builds it. The parameters' ranges
//! are `StudyParams::validate`'s; this is what only building the parts can tell.

use bdft_controller::closed_loop::ClosedLoop;
use bdft_protocol::params::CompensatorSpec;
use bdft_protocol::study::StudyParams;

use super::schedule::draw_target;
use crate::error::{AppError, Result};

/// Target seeds tried per duration. A standard deviation near what the range allows fails
/// for some seeds and not others; a handful of seeds catches it before a subject's
/// enrolment does.
const TARGET_SEEDS: u64 = 16;

/// Checks a validated study: the first thing that cannot run, as `field: reason`.
pub fn check(params: &StudyParams) -> Result<()> {
    check_targets(params)?;
    for spec in designs(params) {
        check_design(params, &spec)?;
    }
    Ok(())
}

/// The designs a study's trials run: its compensators, and the practice's (the study's own
/// design of it, else that compensator's design for people, as enrolment chooses).
fn designs(params: &StudyParams) -> Vec<CompensatorSpec> {
    let mut specs = params.compensators.clone();
    if params.practice_s > 0.0
        && !specs
            .iter()
            .any(|c| c.kind() == params.practice_compensator)
    {
        specs.push(bdft_controller::compensator::study_spec(
            params.practice_compensator,
            &params.plant,
        ));
    }
    specs
}

fn check_targets(params: &StudyParams) -> Result<()> {
    let durations = [params.trial_s, params.practice_s];
    for duration in durations.into_iter().filter(|&d| d > 0.0) {
        let duration = duration.max(2.0 * params.step_interval_s);
        for seed in 0..TARGET_SEEDS {
            if let Err(e) = draw_target(params, duration, seed) {
                let steps = (duration / params.step_interval_s).ceil();
                if params.matched_targets {
                    return Err(AppError::BadRequest(format!(
                        "matched_targets: no target of {steps} steps with a standard deviation of {} mm and the matched step change fits within ±{} mm (target_range_mm) for every seed ({e}); turn matched_targets off, lengthen the tests (trial_s, practice_s) or lower target_std_mm",
                        params.target_std_mm, params.target_range_mm
                    )));
                }
                return Err(AppError::BadRequest(format!(
                    "target_std_mm: no target of {steps} steps with a standard deviation of {} mm fits within ±{} mm (target_range_mm) for every seed ({e}); lower target_std_mm or widen target_range_mm",
                    params.target_std_mm, params.target_range_mm
                )));
            }
        }
    }
    Ok(())
}

/// Builds the loop the controller builds for a trial of `spec` (plant, body and compensator
/// designed at the loop's sample period): a design that has no solution fails here.
pub(super) fn check_design(params: &StudyParams, spec: &CompensatorSpec) -> Result<()> {
    ClosedLoop::new(&super::stability::study_loop(params, spec), 0)
        .map(|_| ())
        .map_err(|e| {
            AppError::BadRequest(format!(
                "controllers: the {} design cannot be built: {e}",
                spec.kind()
            ))
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::study::schedule::default_params;

    #[test]
    fn the_default_study_can_run() {
        check(&default_params()).unwrap();
    }

    #[test]
    fn a_target_std_the_range_cannot_hold_is_refused_naming_target_std_mm() {
        let mut p = default_params();
        p.target_range_mm = 40.0;
        p.target_std_mm = 32.0;
        p.validate().expect("within the range check");
        let err = check(&p).unwrap_err().to_string();
        assert!(err.starts_with("target_std_mm: "), "{err}");
        assert!(err.contains("±40 mm"), "{err}");
    }

    #[test]
    fn an_lqr_design_without_a_riccati_solution_is_refused() {
        let mut p = default_params();
        for c in &mut p.compensators {
            if let CompensatorSpec::Lqr { lqr } = c {
                lqr.alpha = 1e-3;
            }
        }
        p.validate().expect("within the range checks");
        let err = check(&p).unwrap_err().to_string();
        assert!(
            err.starts_with("controllers: the lqr design cannot be built: the Riccati equation has no stabilizing solution"),
            "{err}"
        );
    }

    #[test]
    fn the_practice_design_is_built_too() {
        let mut p = default_params();
        p.compensators
            .retain(|c| c.kind() != bdft_protocol::params::CompensatorKind::Pid);
        let kinds: Vec<_> = designs(&p).iter().map(|c| c.kind()).collect();
        assert!(kinds.contains(&bdft_protocol::params::CompensatorKind::Pid));
        check(&p).unwrap();
    }
}
