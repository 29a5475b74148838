//! The nine compensators behind one interface: one `step` per tick from the cylinder
//! reference and the measurements to a saturated valve command, a `reset`, and the
//! parameters they were built from (recorded with every trial).
//!
//! `build` designs everything (Riccati, observer, shaper) and allocates once; `step` never
//! allocates, locks or blocks.
//!
//! `CompensatorKind` (the names used everywhere), `CompensatorSpec` (a design with all its
//! parameters, serializable: what is recorded with a trial), `Compensator` (built once, `step` per
//! tick). `pid`: PID with filtered derivative and conditional-integration anti-windup,
//! Ziegler–Nichols from the ultimate gain, the notch. `lqr`: LQR + observer (Luenberger with placed
//! poles, or the steady-state Kalman filter from the dual Riccati equation, `ObserverDesign`) + N̄
//! scaling, cab velocity from high-pass + leaky integrator. `variants`: the workbench's design
//! names (`pid-shaper:zvd`, `lqr-cabacc:kalman`, …). `adaptive`: the three adaptive designs
//! (estimator, schedule, and the fixed designs of this module prepared at a grid of ratios),
//! built here from their specs; a submodule, so it uses this module's designs without the two
//! importing each other.
//!
//! *Invariant:* `step` never allocates, locks, blocks or logs (checked by `alloc_check.rs`, a
//! counting allocator in the test binary, for every variant); fixed-size nalgebra types only.

pub mod adaptive;
mod lqr;
mod pid;
pub mod variants;

pub use bdft_protocol::params::{CompensatorKind, CompensatorSpec};
pub(crate) use lqr::CabSignal;
pub use lqr::{
    CabOutput, Lqr, LqrDesign, LqrParams, ObserverDesign, first_mode_damping, held_beta,
    kalman_gain,
};
pub use pid::{NotchParams, Pid, PidParams, notch_filter, tyreus_luyben_pi, ziegler_nichols};

use crate::error::DesignError;
use crate::filters::Biquad;
use crate::model::Measurement;
use crate::params::PlantParams;
use crate::shaper::{Shaper, ShaperParams};
use crate::state::LinearState;
use adaptive::Adaptive;
pub use bdft_protocol::params::{AdaptParams, AdaptationStatus};

/// The documented default design of `kind` for this plant (PID tuned by Ziegler–Nichols
/// from the plant's ultimate gain): the bench design, and the one the published stability
/// facts are about.
pub fn default_spec(kind: CompensatorKind, plant: &PlantParams) -> CompensatorSpec {
    spec_with_pid(kind, ziegler_nichols(plant))
}

/// The design of `kind` for tests with people on the machine: the PID family tuned slow
/// (`tyreus_luyben_pi`; notch and shaper keep the PID's gains, as in the original study),
/// the LQR designs as `default_spec`.
pub fn study_spec(kind: CompensatorKind, plant: &PlantParams) -> CompensatorSpec {
    spec_with_pid(kind, tyreus_luyben_pi(plant))
}

fn spec_with_pid(kind: CompensatorKind, pid: PidParams) -> CompensatorSpec {
    match kind {
        CompensatorKind::Pid => CompensatorSpec::Pid { pid },
        CompensatorKind::PidNotch => CompensatorSpec::PidNotch {
            pid,
            notch: NotchParams::default(),
        },
        CompensatorKind::PidShaper => CompensatorSpec::PidShaper {
            pid,
            shaper: ShaperParams::default(),
        },
        CompensatorKind::Lqr => CompensatorSpec::Lqr {
            lqr: LqrParams::for_output(CabOutput::Velocity, 0.0),
        },
        CompensatorKind::LqrCabvel => CompensatorSpec::LqrCabvel {
            lqr: LqrParams::for_output(CabOutput::Velocity, 2.0),
        },
        CompensatorKind::LqrCabacc => CompensatorSpec::LqrCabacc {
            lqr: LqrParams::for_output(CabOutput::Acceleration, 0.05),
        },
        CompensatorKind::PidNotchAdaptive => CompensatorSpec::PidNotchAdaptive {
            pid,
            notch: NotchParams::default(),
            adapt: AdaptParams::default(),
        },
        CompensatorKind::PidShaperAdaptive => CompensatorSpec::PidShaperAdaptive {
            pid,
            shaper: ShaperParams::default(),
            adapt: AdaptParams::default(),
        },
        CompensatorKind::LqrCabvelScheduled => CompensatorSpec::LqrCabvelScheduled {
            lqr: LqrParams::for_output(CabOutput::Velocity, 2.0),
            adapt: AdaptParams::default(),
        },
    }
}

/// What acts on the cylinder reference before the PID loop.
#[derive(Debug, Clone)]
pub enum Prefilter {
    None,
    Notch(Biquad),
    Shaper(Shaper),
}

/// A compensator ready to run.
#[derive(Debug, Clone)]
pub enum Compensator {
    Pid {
        pre: Prefilter,
        pid: Pid,
    },
    Lqr(Box<Lqr>),
    /// Estimator, schedule and prepared designs of an adaptive spec.
    Adaptive(Box<Adaptive>),
}

impl Compensator {
    /// Designs and builds the compensator for the plant at sample period `dt`.
    pub fn build(
        spec: &CompensatorSpec,
        plant: &PlantParams,
        dt: f64,
    ) -> Result<Self, DesignError> {
        spec.validate()?;
        plant.validate()?;
        if let Some(a) = Adaptive::new(spec, plant, dt)? {
            return Ok(Self::Adaptive(Box::new(a)));
        }
        Ok(match spec {
            CompensatorSpec::Pid { pid } => Self::Pid {
                pre: Prefilter::None,
                pid: Pid::new(pid, plant.v_max, dt),
            },
            CompensatorSpec::PidNotch { pid, notch } => Self::Pid {
                pre: Prefilter::Notch(notch_filter(notch, dt)),
                pid: Pid::new(pid, plant.v_max, dt),
            },
            CompensatorSpec::PidShaper { pid, shaper } => Self::Pid {
                pre: Prefilter::Shaper(Shaper::new(shaper, dt)),
                pid: Pid::new(pid, plant.v_max, dt),
            },
            CompensatorSpec::Lqr { lqr }
            | CompensatorSpec::LqrCabvel { lqr }
            | CompensatorSpec::LqrCabacc { lqr } => Self::Lqr(Box::new(Lqr::new(lqr, plant, dt)?)),
            CompensatorSpec::PidNotchAdaptive { .. }
            | CompensatorSpec::PidShaperAdaptive { .. }
            | CompensatorSpec::LqrCabvelScheduled { .. } => {
                unreachable!("adaptive specs are built above")
            }
        })
    }

    /// What an adaptive design reports (its estimate, confidence and retunes); None for the
    /// fixed designs.
    pub fn adaptation(&self) -> Option<AdaptationStatus> {
        match self {
            Self::Adaptive(a) => Some(a.status()),
            Self::Pid { .. } | Self::Lqr(_) => None,
        }
    }

    pub fn as_adaptive_mut(&mut self) -> Option<&mut Adaptive> {
        match self {
            Self::Adaptive(a) => Some(a),
            Self::Pid { .. } | Self::Lqr(_) => None,
        }
    }

    /// One tick: cylinder reference r_c (mm) and measurements → valve command, saturated.
    #[inline]
    pub fn step(&mut self, r_c: f64, m: Measurement) -> f64 {
        match self {
            Self::Pid { pre, pid } => {
                let r = match pre {
                    Prefilter::None => r_c,
                    Prefilter::Notch(f) => f.step(r_c),
                    Prefilter::Shaper(s) => s.step(r_c),
                };
                pid.step(r - m.y)
            }
            Self::Lqr(l) => l.step(r_c, m),
            Self::Adaptive(a) => a.step(r_c, m),
        }
    }

    /// Back to the state at construction: a new trial starts from rest.
    pub fn reset(&mut self) {
        match self {
            Self::Pid { pre, pid } => {
                match pre {
                    Prefilter::None => {}
                    Prefilter::Notch(f) => f.reset(),
                    Prefilter::Shaper(s) => s.reset(),
                }
                pid.reset();
            }
            Self::Lqr(l) => l.reset(),
            Self::Adaptive(a) => a.reset(),
        }
    }

    /// True if the reference path contains pure delays (the shaper): its discrete
    /// closed-loop eigenvalues then include the delay line's, which are not poles in rad/s.
    pub fn has_delays(&self) -> bool {
        match self {
            Self::Pid { pre, .. } => matches!(pre, Prefilter::Shaper(_)),
            Self::Lqr(_) => false,
            Self::Adaptive(a) => a.has_delays(),
        }
    }

    /// The delay an input shaper adds (s), if the design has one.
    pub fn shaper_duration(&self, dt: f64) -> Option<f64> {
        match self {
            Self::Pid {
                pre: Prefilter::Shaper(s),
                ..
            } => Some(s.duration(dt)),
            Self::Adaptive(a) => a.shaper_duration(),
            _ => None,
        }
    }

    fn prefilter_state(pre: &Prefilter) -> Option<&dyn LinearState> {
        match pre {
            Prefilter::None => None,
            Prefilter::Notch(f) => Some(f),
            Prefilter::Shaper(s) => Some(s),
        }
    }
}

impl LinearState for Compensator {
    fn state_len(&self) -> usize {
        match self {
            Self::Pid { pre, pid } => {
                Self::prefilter_state(pre).map_or(0, |p| p.state_len()) + pid.state_len()
            }
            Self::Lqr(l) => l.state_len(),
            Self::Adaptive(a) => a.state_len(),
        }
    }
    fn read_state(&self, out: &mut [f64]) {
        match self {
            Self::Pid { pre, pid } => {
                let n = Self::prefilter_state(pre).map_or(0, |p| {
                    p.read_state(out);
                    p.state_len()
                });
                pid.read_state(&mut out[n..]);
            }
            Self::Lqr(l) => l.read_state(out),
            Self::Adaptive(a) => a.read_state(out),
        }
    }
    fn write_state(&mut self, s: &[f64]) {
        match self {
            Self::Pid { pre, pid } => {
                let n = match pre {
                    Prefilter::None => 0,
                    Prefilter::Notch(f) => {
                        f.write_state(s);
                        f.state_len()
                    }
                    Prefilter::Shaper(sh) => {
                        sh.write_state(s);
                        sh.state_len()
                    }
                };
                pid.write_state(&s[n..]);
            }
            Self::Lqr(l) => l.write_state(s),
            Self::Adaptive(a) => a.write_state(s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_list_the_valid_ones() {
        for k in CompensatorKind::ALL {
            assert_eq!(k.name().parse::<CompensatorKind>().unwrap(), k);
            let json = serde_json::to_string(&k).unwrap();
            assert_eq!(json, format!("\"{}\"", k.name()));
        }
        let err = "pidd".parse::<CompensatorKind>().unwrap_err().to_string();
        assert!(
            err.contains("pid-notch") && err.contains("lqr-cabacc"),
            "{err}"
        );
    }

    #[test]
    fn every_compensator_saturates_and_resets_to_identical_behaviour() {
        let plant = PlantParams::default();
        for kind in CompensatorKind::ALL {
            let spec = default_spec(kind, &plant);
            let mut c = Compensator::build(&spec, &plant, 1e-3).unwrap();
            let run = |c: &mut Compensator| -> Vec<f64> {
                (0..500)
                    .map(|k| {
                        c.step(
                            1e4,
                            Measurement {
                                y: -(k as f64),
                                cab_accel: 1e5,
                            },
                        )
                    })
                    .collect()
            };
            let first = run(&mut c);
            assert!(
                first.iter().all(|v| v.abs() <= plant.v_max),
                "{kind} exceeds v_max"
            );
            c.reset();
            assert_eq!(
                run(&mut c),
                first,
                "{kind}: reset must restore the initial state"
            );
            // Non-finite measurements never produce a non-finite or unsaturated command.
            let v = c.step(
                f64::NAN,
                Measurement {
                    y: f64::INFINITY,
                    cab_accel: f64::NAN,
                },
            );
            assert!(v.is_finite() && v.abs() <= plant.v_max, "{kind}: {v}");
        }
    }

    #[test]
    fn robust_shaper_options_serialize_and_zv_reads_as_before() {
        use crate::shaper::ShaperMethod;
        let plant = PlantParams::default();
        let zv = serde_json::to_value(default_spec(CompensatorKind::PidShaper, &plant)).unwrap();
        assert!(zv["shaper"].get("method").is_none() && zv["shaper"].get("tolerance").is_none());
        let spec = CompensatorSpec::PidShaper {
            pid: ziegler_nichols(&plant),
            shaper: ShaperParams {
                tolerance: 0.08,
                ..ShaperParams::between_modes(ShaperMethod::TwoHumpEi)
            },
        };
        let json = serde_json::to_value(&spec).unwrap();
        assert_eq!(json["shaper"]["method"], "two-hump-ei");
        assert_eq!(json["shaper"]["tolerance"], 0.08);
        assert_eq!(
            serde_json::from_value::<CompensatorSpec>(json).unwrap(),
            spec
        );
        let bad: CompensatorSpec = serde_json::from_value(serde_json::json!({
            "kind": "pid-shaper", "pid": ziegler_nichols(&plant),
            "shaper": {"method": "ei", "tolerance": 0.9}
        }))
        .unwrap();
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("shaper.tolerance"), "{err}");
        let err = serde_json::from_value::<CompensatorSpec>(serde_json::json!({
            "kind": "pid-shaper", "pid": ziegler_nichols(&plant), "shaper": {"method": "zvdd"}
        }))
        .unwrap_err()
        .to_string();
        assert!(err.contains("zvd") && err.contains("two-hump-ei"), "{err}");
    }

    #[test]
    fn spec_serializes_with_its_kind_and_parameters() {
        let plant = PlantParams::default();
        let spec = default_spec(CompensatorKind::LqrCabvel, &plant);
        let json = serde_json::to_value(&spec).unwrap();
        assert_eq!(json["kind"], "lqr-cabvel");
        assert_eq!(json["lqr"]["beta"], 2.0);
        let back: CompensatorSpec = serde_json::from_value(json).unwrap();
        assert_eq!(back, spec);
    }
}
