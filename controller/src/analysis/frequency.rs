//! Frequency responses of the sampled blocks as they run: each part (valve/cylinder,
//! structure, body), each compensator and each closed loop, as Bode data over a log grid.
//!
//! Each block's state-space map is read off its own `step` ([`probe`], the same reading the
//! stability analysis does on `ClosedLoop::tick`), so the plots are of the code that runs:
//! the plant's zero-order hold, the Tustin filters, the shaper's delays. Its response is
//! then evaluated on the unit circle ([`StateSpace::response`], O(n²) a frequency).

use std::f64::consts::PI;

use nalgebra::{Complex, DMatrix};
use serde::{Deserialize, Serialize};

use super::design_view::{ModelComparison, compare};
use super::nyquist::{LoopParts, Nyquist};
use super::state_space::{StateSpace, probe};
use super::{linear_rig, linear_setup};
use crate::closed_loop::{ClosedLoop, Drive, LoopSetup};
use crate::compensator::{Compensator, CompensatorSpec};
use crate::error::DesignError;
use crate::linalg::zoh;
use crate::model::{Body, Measurement, Plant, design_model, idx};
use crate::params::{MAX_KBF, PlantParams, Seat, check};

/// One response on the report's frequency grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Bode {
    /// What responds to what, e.g. "cylinder position y per valve command V".
    pub name: String,
    /// Unit of the gain (output unit / input unit).
    pub unit: String,
    pub mag_db: Vec<f64>,
    /// Unwrapped along the grid, starting in (−180, 180].
    pub phase_deg: Vec<f64>,
}

impl Bode {
    pub fn from_response(
        name: &str,
        unit: &str,
        freqs_hz: &[f64],
        dt: f64,
        g: impl Fn(f64) -> Complex<f64>,
    ) -> Self {
        let mut mag_db = Vec::with_capacity(freqs_hz.len());
        let mut phase_deg: Vec<f64> = Vec::with_capacity(freqs_hz.len());
        for &f in freqs_hz {
            let r = g(2.0 * PI * f * dt);
            mag_db.push(20.0 * r.norm().log10());
            let mut p = r.arg().to_degrees();
            if let Some(&prev) = phase_deg.last() {
                p += 360.0 * ((prev - p) / 360.0).round();
            }
            phase_deg.push(p);
        }
        Self {
            name: name.into(),
            unit: unit.into(),
            mag_db,
            phase_deg,
        }
    }
}

/// The log frequency grid of the plots: `n` points from `lo_hz` to `hi_hz`.
pub fn log_grid(lo_hz: f64, hi_hz: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| lo_hz * (hi_hz / lo_hz).powf(i as f64 / (n.max(2) - 1) as f64))
        .collect()
}

/// Frequency-domain views of one compensator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompensatorFrequency {
    pub name: String,
    /// The compensator alone: valve command per reference and per each measurement it uses.
    pub compensator: Vec<Bode>,
    /// Cylinder position per cylinder reference, on the machine (feedthrough closed at the
    /// report's K_BF; the reference is K_BF·p_h) and off it.
    pub closed_loop_on: Bode,
    pub closed_loop_off: Bode,
    /// The cylinder under the LQR's inner velocity loop: position per velocity reference, in
    /// the design model the LQR was computed on (zero-order hold); absent for the PID family,
    /// which has no inner loop.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inner_loop: Option<Bode>,
    /// The loop gain with the feedthrough opened, at the report's K_BF.
    pub nyquist: Nyquist,
    /// Closed-loop poles in both views, with the cause of each difference.
    pub poles: ModelComparison,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrequencyReport {
    /// The machine's condition the designs run on, when it is not the thesis's rig on
    /// stilts they were made for (set by the caller that chose it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub condition: Option<String>,
    pub kbf: f64,
    pub dt: f64,
    pub freqs_hz: Vec<f64>,
    /// The rig and the body: valve/cylinder, structure, body.
    pub parts: Vec<Bode>,
    pub compensators: Vec<CompensatorFrequency>,
}

/// Grid of the report: 0.05 Hz to just below the Nyquist frequency.
pub fn report_grid(dt: f64) -> Vec<f64> {
    log_grid(0.05, 0.45 / dt, 240)
}

/// The rig's and the body's responses for `setup` (its plant and body; noise and dead-band
/// off, as the analysis linearizes).
pub fn parts(setup: &LoopSetup, freqs_hz: &[f64]) -> Result<Vec<Bode>, DesignError> {
    let dt = setup.loop_params.dt;
    let mut plant = Plant::new(linear_rig(setup.plant), dt, 0)?;
    // Outputs are the measurements at the start of the tick, as the loop reads them.
    let rig = probe(&mut plant, 1, 2, |p, u, y| {
        let m = p.measure();
        p.step(u[0]);
        y[0] = m.y;
        y[1] = m.cab_accel;
    });
    let mut body = Body::new(setup.body, dt);
    let body = probe(&mut body, 1, 1, |b, u, y| y[0] = b.step(u[0]));
    Ok(vec![
        Bode::from_response(
            "valve/cylinder: cylinder position y per valve command V",
            "mm per unit V",
            freqs_hz,
            dt,
            |t| rig.response(0, 0, t),
        ),
        Bode::from_response(
            "structure: cab acceleration per cylinder position",
            "mm/s² per mm",
            freqs_hz,
            dt,
            |t| rig.response(1, 0, t) / rig.response(0, 0, t),
        ),
        Bode::from_response(
            &format!("body ({}): hand per cab displacement", body_kind(setup)),
            "mm per mm",
            freqs_hz,
            dt,
            |t| body.response(0, 0, t),
        ),
    ])
}

/// The body model's name as parameters spell it (`rigid-mass`, `seated`, …).
fn body_kind(setup: &LoopSetup) -> String {
    serde_json::to_value(setup.body)
        .ok()
        .and_then(|v| v["kind"].as_str().map(String::from))
        .unwrap_or_default()
}

/// The compensator's map from [reference, y, cab acceleration] to the valve command.
pub fn compensator_map(setup: &LoopSetup) -> Result<StateSpace, DesignError> {
    // An adaptive design's map is its fixed design's (frozen at r = 1, `linear_setup`).
    let spec = setup.compensator.frozen_at(1.0);
    let mut c = Compensator::build(&spec, &setup.plant, setup.loop_params.dt)?;
    Ok(probe(&mut c, 3, 1, |c, u, v| {
        v[0] = c.step(
            u[0],
            Measurement {
                y: u[1],
                cab_accel: u[2],
            },
        );
    }))
}

/// Cylinder position per cylinder reference of the closed loop at `seat`, the design made
/// for the setup's plant running on `rig`: on the machine the operator's device drives it
/// (reference K_BF·p_h, feedthrough closed), off it the reference drives it directly.
pub fn closed_loop_map(
    setup: &LoopSetup,
    seat: Seat,
    rig: PlantParams,
) -> Result<StateSpace, DesignError> {
    let mut s = linear_setup(setup);
    s.seat = seat;
    let k_bf = s.loop_params.k_bf;
    let mut lp = ClosedLoop::new(&s, 0)?.with_rig(linear_rig(rig), 0)?;
    Ok(probe(&mut lp, 1, 1, |lp, u, y| {
        let drive = if seat == Seat::On && k_bf > 0.0 {
            Drive::Hand(u[0] / k_bf)
        } else {
            Drive::Reference(u[0])
        };
        y[0] = lp.tick(drive).y;
    }))
}

/// The whole report: the parts of `rig` (the machine as it runs: `base`'s plant, or it under
/// a condition) with `base`'s body, at its loop period and K_BF, and each named design, made
/// for `base`'s plant, on them.
pub fn report(
    base: &LoopSetup,
    designs: &[(String, CompensatorSpec)],
    rig: PlantParams,
) -> Result<FrequencyReport, DesignError> {
    let freqs_hz = report_grid(base.loop_params.dt);
    let compensators = designs
        .iter()
        .map(|(name, spec)| {
            let setup = LoopSetup {
                compensator: spec.clone(),
                ..base.clone()
            };
            Ok(CompensatorFrequency {
                name: name.clone(),
                ..compensator_frequency(&setup, &freqs_hz, rig)?
            })
        })
        .collect::<Result<Vec<_>, DesignError>>()?;
    let machine = LoopSetup {
        plant: rig,
        ..base.clone()
    };
    Ok(FrequencyReport {
        condition: None,
        kbf: base.loop_params.k_bf,
        dt: base.loop_params.dt,
        parts: parts(&machine, &freqs_hz)?,
        freqs_hz,
        compensators,
    })
}

/// The LQR designs' cylinder under the inner velocity loop V = K_P(u − ẏ), sampled with a
/// zero-order hold; `None` for designs without that loop.
pub fn inner_loop_map(setup: &LoopSetup) -> Option<StateSpace> {
    let (CompensatorSpec::Lqr { lqr }
    | CompensatorSpec::LqrCabvel { lqr }
    | CompensatorSpec::LqrCabacc { lqr }) = &setup.compensator.frozen_at(1.0)
    else {
        return None;
    };
    let (a, b) = design_model(&setup.plant, lqr.inner_loop_gain);
    let (ad, bd) = zoh(
        &DMatrix::from_column_slice(7, 7, a.as_slice()),
        &DMatrix::from_column_slice(7, 1, b.as_slice()),
        setup.loop_params.dt,
    );
    let mut c = DMatrix::zeros(1, 7);
    c[(0, idx::Y)] = 1.0;
    Some(StateSpace::new(ad, bd, c, DMatrix::zeros(1, 1)))
}

/// Everything for one compensator at the setup's K_BF, made for the setup's plant and run on
/// `rig`: its closed loops and Nyquist view on the rig; the compensator itself, its inner
/// loop and its pole comparison (design model against the code) as designed.
pub fn compensator_frequency(
    setup: &LoopSetup,
    freqs_hz: &[f64],
    rig: PlantParams,
) -> Result<CompensatorFrequency, DesignError> {
    let k_bf = setup.loop_params.k_bf;
    check("kbf", k_bf, 0.0, MAX_KBF)?;
    let dt = setup.loop_params.dt;
    let comp = compensator_map(setup)?;
    // The PID family reads only y; the LQR observers read the accelerometer too.
    let uses_cab = matches!(
        Compensator::build(&setup.compensator, &setup.plant, dt)?,
        Compensator::Lqr(_)
    );
    let mut compensator = vec![
        Bode::from_response("valve command per reference", "per mm", freqs_hz, dt, |t| {
            comp.response(0, 0, t)
        }),
        Bode::from_response(
            "valve command per cylinder position y",
            "per mm",
            freqs_hz,
            dt,
            |t| comp.response(0, 1, t),
        ),
    ];
    if uses_cab {
        compensator.push(Bode::from_response(
            "valve command per cab acceleration",
            "per mm/s²",
            freqs_hz,
            dt,
            |t| comp.response(0, 2, t),
        ));
    }
    let inner_loop = inner_loop_map(setup).map(|m| {
        Bode::from_response(
            "inner velocity loop closed (design model): y per velocity reference",
            "mm per mm/s",
            freqs_hz,
            dt,
            |t| m.response(0, 0, t),
        )
    });
    let on = closed_loop_map(setup, Seat::On, rig)?;
    let off = closed_loop_map(setup, Seat::Off, rig)?;
    Ok(CompensatorFrequency {
        name: setup.compensator.kind().name().to_string(),
        compensator,
        inner_loop,
        closed_loop_on: Bode::from_response(
            "closed loop on the machine: y per reference",
            "mm per mm",
            freqs_hz,
            dt,
            |t| on.response(0, 0, t),
        ),
        closed_loop_off: Bode::from_response(
            "closed loop off the machine: y per reference",
            "mm per mm",
            freqs_hz,
            dt,
            |t| off.response(0, 0, t),
        ),
        nyquist: LoopParts::new(setup)?
            .on_rig(linear_rig(rig))?
            .nyquist(k_bf)?,
        poles: compare(setup)?,
    })
}

#[cfg(test)]
mod tests;
