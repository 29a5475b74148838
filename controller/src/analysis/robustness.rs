//! Robustness of a design: its largest stable K_BF when the machine and the operator differ
//! from the model it was designed on, as a 2-D map and as a Monte-Carlo pass rate.
//!
//! The compensator is designed once, on the nominal plant; each case runs it on a perturbed
//! rig ([`ClosedLoop::with_rig`]) and reads that loop's sampled map off the running code, as
//! `analyze` does. K_H is a gain of the body in every body model, and the feedthrough
//! closes through K_BF·h, so the loop depends on K_BF and K_H only through their product:
//! a K_H scale s divides the largest stable K_BF by s exactly. The map therefore searches
//! the largest stable loop gain once per structure-frequency scale and divides it along the
//! K_H axis, and a draw's verdict at the study's K_BF is the verdict at K_BF·s.
//!
//! Designs with an input shaper are judged from the loop's frequency response instead
//! ([`super::nyquist`]): their delay line adds ~210 states, whose eigenvalues cost ~0.4 s a
//! rig, while the open loop with the shaper as an exact FIR costs milliseconds. Both verdicts
//! agree (tested on the map's cells).

use serde::{Deserialize, Serialize};

use super::nyquist::LoopParts;
use super::{LinearizedLoop, linear_rig, linear_setup};
use crate::closed_loop::{ClosedLoop, LoopSetup};
use crate::error::{DesignError, ParamError};
use crate::params::{MAX_KBF, PlantParams, check};
use crate::rng::Rng;

/// A range of relative deviations from nominal, in percent: [lo, hi].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Range {
    pub lo: f64,
    pub hi: f64,
}

impl Range {
    pub const fn pct(lo: f64, hi: f64) -> Self {
        Self { lo, hi }
    }

    fn validate(&self, name: &'static str) -> Result<(), ParamError> {
        check(name, self.lo, -90.0, 500.0)?;
        check(name, self.hi, self.lo, 500.0)
    }

    /// The scale factor `i` of `n` evenly spaced across the range (the low end for n = 1).
    fn grid(&self, i: usize, n: usize) -> f64 {
        let f = if n > 1 {
            i as f64 / (n - 1) as f64
        } else {
            0.0
        };
        1.0 + (self.lo + f * (self.hi - self.lo)) / 100.0
    }

    fn draw(&self, rng: &mut Rng) -> f64 {
        1.0 + rng.uniform(self.lo, self.hi) / 100.0
    }
}

/// What varies and by how much, and how finely it is sampled.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RobustnessSpec {
    /// K_H (the map's first axis).
    pub kh: Range,
    /// Both structure frequencies (the map's second axis; drawn independently).
    pub freq: Range,
    /// Both structure damping ratios (drawn independently).
    pub damping: Range,
    /// The valve/cylinder's K_VC, ω_VC and ζ_VC (drawn independently).
    pub valve: Range,
    /// Map cells per axis.
    pub grid: usize,
    pub draws: usize,
    pub seed: u64,
    /// The study's K_BF, at which a draw passes if the loop is stable.
    pub kbf: f64,
}

impl Default for RobustnessSpec {
    fn default() -> Self {
        Self {
            kh: Range::pct(-50.0, 50.0),
            freq: Range::pct(-20.0, 20.0),
            damping: Range::pct(-30.0, 30.0),
            valve: Range::pct(-10.0, 10.0),
            grid: 50,
            draws: 1000,
            seed: 1,
            kbf: 0.78,
        }
    }
}

impl RobustnessSpec {
    pub fn validate(&self) -> Result<(), ParamError> {
        self.kh.validate("kh_range")?;
        self.freq.validate("freq_range")?;
        self.damping.validate("damping_range")?;
        self.valve.validate("valve_range")?;
        check("grid", self.grid as f64, 1.0, 200.0)?;
        check("draws", self.draws as f64, 0.0, 1e6)?;
        check("kbf", self.kbf, 0.0, MAX_KBF)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobustnessReport {
    pub design: String,
    pub spec: RobustnessSpec,
    /// K_H scale of each map row.
    pub kh_scales: Vec<f64>,
    /// Structure-frequency scale of each map column.
    pub freq_scales: Vec<f64>,
    /// Largest stable K_BF per cell [row][column]; `null` = stable up to MAX_KBF.
    pub max_stable_kbf: Vec<Vec<Option<f64>>>,
    /// Fraction of the draws stable at the study's K_BF (`null` without draws).
    pub pass_rate: Option<f64>,
}

/// One design (`setup.compensator`, designed on `setup.plant`) judged on other rigs: the
/// machine under a condition, or a perturbed one. The design is built once.
#[derive(Debug)]
pub struct OnRig {
    base: ClosedLoop,
    parts: LoopParts,
    dt: f64,
}

impl OnRig {
    pub fn new(setup: &LoopSetup) -> Result<Self, DesignError> {
        Ok(Self {
            base: ClosedLoop::new(&linear_setup(setup), 0)?,
            parts: LoopParts::new(setup)?,
            dt: setup.loop_params.dt,
        })
    }

    /// The largest stable K_BF (up to `limit`; `None` = stable there) on `rig`, linearized
    /// (`linear_rig`).
    pub fn max_stable_kbf(&self, rig: PlantParams, limit: f64) -> Result<Option<f64>, DesignError> {
        let rig = linear_rig(rig);
        if self.base.compensator().has_delays() {
            Ok(self.parts.on_rig(rig)?.max_stable_up_to(limit))
        } else {
            LinearizedLoop::read_off(&mut self.base.with_rig(rig, 0)?, self.dt)
                .max_stable_up_to(limit)
        }
    }

    /// Stable at loop gain `k_bf` on `rig`.
    pub fn is_stable(&self, rig: PlantParams, k_bf: f64) -> Result<bool, DesignError> {
        let rig = linear_rig(rig);
        if self.base.compensator().has_delays() {
            Ok(self.parts.on_rig(rig)?.is_stable(k_bf))
        } else {
            LinearizedLoop::read_off(&mut self.base.with_rig(rig, 0)?, self.dt).is_stable(k_bf)
        }
    }
}

/// The map and the pass rate of one design (`setup.compensator`, designed on `setup.plant`).
pub fn robustness(
    design: &str,
    setup: &LoopSetup,
    spec: &RobustnessSpec,
) -> Result<RobustnessReport, DesignError> {
    spec.validate()?;
    let on = OnRig::new(setup)?;
    let nominal = linear_rig(setup.plant);
    let margin = |rig: PlantParams, limit: f64| on.max_stable_kbf(rig, limit);
    let stable = |rig: PlantParams, k: f64| on.is_stable(rig, k);
    let n = spec.grid;
    let kh_scales: Vec<f64> = (0..n).map(|i| spec.kh.grid(i, n)).collect();
    let freq_scales: Vec<f64> = (0..n).map(|i| spec.freq.grid(i, n)).collect();
    // Loop gain K_BF·s searched up to where the smallest K_H scale could still need it.
    let kh_max = kh_scales.iter().copied().fold(0.0, f64::max);
    let mut columns = Vec::with_capacity(n);
    for &f in &freq_scales {
        let rig = PlantParams {
            f1_hz: nominal.f1_hz * f,
            f2_hz: nominal.f2_hz * f,
            ..nominal
        };
        columns.push(margin(rig, MAX_KBF * kh_max)?);
    }
    let max_stable_kbf = kh_scales
        .iter()
        .map(|&s| {
            columns
                .iter()
                .map(|g| match g {
                    Some(g) if g / s <= MAX_KBF => Some(g / s),
                    _ => None,
                })
                .collect()
        })
        .collect();
    let pass_rate = if spec.draws == 0 {
        None
    } else {
        let mut rng = Rng::derive(spec.seed, ROBUSTNESS_DRAWS);
        let mut passed = 0;
        for _ in 0..spec.draws {
            let s_kh = spec.kh.draw(&mut rng);
            let rig = PlantParams {
                f1_hz: nominal.f1_hz * spec.freq.draw(&mut rng),
                f2_hz: nominal.f2_hz * spec.freq.draw(&mut rng),
                z1: (nominal.z1 * spec.damping.draw(&mut rng)).min(0.99),
                z2: (nominal.z2 * spec.damping.draw(&mut rng)).min(0.99),
                k_vc: nominal.k_vc * spec.valve.draw(&mut rng),
                w_vc: nominal.w_vc * spec.valve.draw(&mut rng),
                z_vc: nominal.z_vc * spec.valve.draw(&mut rng),
                ..nominal
            };
            if stable(rig, spec.kbf * s_kh)? {
                passed += 1;
            }
        }
        Some(passed as f64 / spec.draws as f64)
    };
    Ok(RobustnessReport {
        design: design.to_string(),
        spec: *spec,
        kh_scales,
        freq_scales,
        max_stable_kbf,
        pass_rate,
    })
}

/// Purpose tag of the Monte-Carlo draws' stream ([`Rng::derive`]).
const ROBUSTNESS_DRAWS: u64 = 11;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::analyze;
    use crate::compensator::CompensatorKind;
    use crate::param_set::ParamSet;
    use crate::params::{BodyModel, Seat};

    fn spec(grid: usize, draws: usize) -> RobustnessSpec {
        RobustnessSpec {
            grid,
            draws,
            ..RobustnessSpec::default()
        }
    }

    #[test]
    fn the_nominal_cell_is_analyzes_margin_and_k_h_divides_it() {
        let setup = ParamSet::default().setup(CompensatorKind::Lqr, Seat::On, 0.78);
        let r = robustness("lqr", &setup, &spec(3, 0)).unwrap();
        assert_eq!(r.kh_scales, [0.5, 1.0, 1.5]);
        assert_eq!(r.freq_scales[1], 1.0);
        let want = analyze(&setup).unwrap().max_stable_kbf.unwrap();
        let got = r.max_stable_kbf[1][1].unwrap();
        assert!((got - want).abs() < 2e-5, "{got} vs {want}");
        // The K_H axis against a direct analysis with the body's K_H scaled.
        let mut scaled = setup.clone();
        scaled.body = BodyModel::RigidMass { k_h: 0.56 * 1.5 };
        let direct = analyze(&scaled).unwrap().max_stable_kbf.unwrap();
        let got = r.max_stable_kbf[2][1].unwrap();
        assert!((got - direct).abs() < 2e-5, "{got} vs {direct}");
        assert!(r.pass_rate.is_none());
    }

    #[test]
    fn zero_width_ranges_pass_every_draw_at_a_stable_kbf_and_none_at_an_unstable_one() {
        let zero = Range::pct(0.0, 0.0);
        let setup = ParamSet::default().setup(CompensatorKind::LqrCabvel, Seat::On, 0.78);
        let margin = analyze(&setup).unwrap().max_stable_kbf.unwrap();
        for (kbf, want) in [(0.9 * margin, 1.0), (1.1 * margin, 0.0)] {
            let s = RobustnessSpec {
                kh: zero,
                freq: zero,
                damping: zero,
                valve: zero,
                grid: 1,
                draws: 20,
                seed: 3,
                kbf,
            };
            let r = robustness("lqr-cabvel", &setup, &s).unwrap();
            assert_eq!(r.pass_rate, Some(want), "at K_BF {kbf}");
        }
    }

    /// The shaper designs' map comes from the frequency response; on every cell the
    /// eigenvalues of the whole sampled loop (delay line included) flip at its margin.
    #[test]
    fn the_shaper_map_agrees_with_the_eigenvalues_on_its_cells() {
        let setup = ParamSet::default().setup(CompensatorKind::PidShaper, Seat::On, 0.78);
        let r = robustness("pid-shaper", &setup, &spec(3, 0)).unwrap();
        let base = ClosedLoop::new(&linear_setup(&setup), 0).unwrap();
        let nominal = linear_rig(setup.plant);
        for (j, &f) in r.freq_scales.iter().enumerate() {
            let rig = PlantParams {
                f1_hz: nominal.f1_hz * f,
                f2_hz: nominal.f2_hz * f,
                ..nominal
            };
            let lin = LinearizedLoop::read_off(&mut base.with_rig(rig, 0).unwrap(), 1e-3);
            for (i, &s) in r.kh_scales.iter().enumerate() {
                // K_BF·s is the loop gain the cell's margin stands for.
                let m = r.max_stable_kbf[i][j].expect("the shaper loses stability in range");
                assert!(lin.is_stable(0.999 * m * s).unwrap(), "cell {i},{j}: {m}");
                assert!(!lin.is_stable(1.001 * m * s).unwrap(), "cell {i},{j}: {m}");
            }
        }
    }

    #[test]
    fn wider_ranges_pass_fewer_draws_and_ranges_are_checked() {
        let setup = ParamSet::default().setup(CompensatorKind::Lqr, Seat::On, 0.78);
        let narrow = RobustnessSpec {
            kh: Range::pct(-5.0, 5.0),
            freq: Range::pct(-2.0, 2.0),
            damping: Range::pct(-2.0, 2.0),
            valve: Range::pct(-2.0, 2.0),
            ..spec(1, 100)
        };
        let wide = RobustnessSpec {
            kh: Range::pct(0.0, 150.0),
            ..narrow
        };
        let a = robustness("lqr", &setup, &narrow)
            .unwrap()
            .pass_rate
            .unwrap();
        let b = robustness("lqr", &setup, &wide).unwrap().pass_rate.unwrap();
        assert_eq!(a, 1.0);
        assert!(b < a, "{b}");
        let bad = RobustnessSpec {
            kh: Range::pct(10.0, -10.0),
            ..spec(2, 1)
        };
        let err = robustness("lqr", &setup, &bad).unwrap_err().to_string();
        assert!(err.contains("kh_range"), "{err}");
    }
}
