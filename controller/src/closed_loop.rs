//! One tick of the simulated rig in closed loop: plant, accelerometer, body, feedthrough and
//! compensator, in the order the real-time loop runs them. The offline simulation, the
//! analysis and the real-time process all call this same `tick`.

use serde::{Deserialize, Serialize};

use crate::cancellation::{Cancelled, Canceller};
use crate::compensator::{Compensator, CompensatorSpec};
use crate::error::DesignError;
use crate::model::{Body, Measurement, Plant};
use crate::params::{BodyModel, LoopParams, PlantParams, Seat};
use crate::state::LinearState;

/// Everything that defines a closed loop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoopSetup {
    pub plant: PlantParams,
    pub body: BodyModel,
    pub loop_params: LoopParams,
    /// On the machine or at the desk (key `station`, the parameter files' name).
    #[serde(rename = "station")]
    pub seat: Seat,
    pub compensator: CompensatorSpec,
}

/// What drives the loop this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Drive {
    /// The operator's intended hand position p_h (mm of device travel); the device reads
    /// p_h − h and the cylinder reference is K_BF·(p_h − h).
    Hand(f64),
    /// The cylinder reference itself (bench tests: no operator, no feedthrough).
    Reference(f64),
    /// The identification test: the cylinder reference is the excitation `r_c`, the device
    /// reads `hand` − h and is recorded, and nothing of it reaches the reference (K_BF = 0
    /// for the loop, whatever the trial's K_BF).
    Excited { hand: f64, r_c: f64 },
}

/// Signals of one tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TickRecord {
    /// Intended hand position p_h (mm); 0 when driven by a reference.
    pub hand: f64,
    /// Hand motion forced by cab vibration h (mm).
    pub feedthrough: f64,
    /// Cylinder reference r_c (mm).
    pub r_c: f64,
    /// Valve command applied (saturated).
    pub valve: f64,
    /// Cylinder position y (mm), measured at the start of the tick.
    pub y: f64,
    /// Seat accelerometer (mm/s²), measured at the start of the tick.
    pub cab_accel: f64,
    /// What cancellation subtracted from the device's reading (mm; 0 without it).
    pub cancellation: f64,
    /// Cancellation's guard turned it off on this tick (for the rest of the test).
    pub cancellation_tripped: bool,
}

/// The cylinder reference from the device's reading: K_BF times the reading less what the
/// canceller (if any) predicts the cab added to it. The one path of the simulated and the
/// real rig's loops.
#[inline]
pub(crate) fn reference_from_device(
    k_bf: f64,
    device_mm: f64,
    cab_accel_mm_s2: f64,
    canceller: &mut Option<Canceller>,
) -> (f64, Cancelled) {
    let cancelled = canceller
        .as_mut()
        .map_or(Cancelled::default(), |c| c.step(cab_accel_mm_s2));
    (k_bf * (device_mm - cancelled.output_mm), cancelled)
}

#[derive(Debug, Clone)]
pub struct ClosedLoop {
    pub(crate) plant: Plant,
    pub(crate) body: Body,
    pub(crate) compensator: Compensator,
    pub(crate) k_bf: f64,
    pub(crate) seat: Seat,
    /// Model-based cancellation of the feedthrough, when the test has it.
    pub(crate) canceller: Option<Canceller>,
    last: Measurement,
}

impl ClosedLoop {
    pub fn new(setup: &LoopSetup, noise_seed: u64) -> Result<Self, DesignError> {
        setup.loop_params.validate()?;
        setup.body.validate()?;
        let dt = setup.loop_params.dt;
        Ok(Self {
            plant: Plant::new(setup.plant, dt, noise_seed)?,
            body: Body::new(setup.body, dt),
            compensator: Compensator::build(&setup.compensator, &setup.plant, dt)?,
            k_bf: setup.loop_params.k_bf,
            seat: setup.seat,
            canceller: None,
            last: Measurement::default(),
        })
    }

    /// The same loop on another rig: the compensator stays as designed (for the setup's
    /// plant), the rig it runs on is `rig` — how a design meets a machine that differs from
    /// its model.
    pub fn with_rig(&self, rig: PlantParams, noise_seed: u64) -> Result<Self, DesignError> {
        let dt = self.plant.dt();
        Ok(Self {
            plant: Plant::new(rig, dt, noise_seed)?,
            ..self.clone()
        })
    }

    pub fn compensator(&self) -> &Compensator {
        &self.compensator
    }

    /// The measurement of the last tick (what a pursuit display shows now).
    pub fn last_measurement(&self) -> Measurement {
        self.last
    }

    /// The true cab acceleration at the operator's seat (mm/s²): what a person on the
    /// machine feels; 0 at the desk.
    pub fn felt_accel(&self) -> f64 {
        match self.seat {
            Seat::On => self.plant.state()[crate::model::idx::XC_DD],
            Seat::Off => 0.0,
        }
    }

    /// The operator's grip on the device (`Body::set_grip`).
    pub fn set_grip(&mut self, grip: f64) {
        self.body.set_grip(grip);
    }

    pub fn set_k_bf(&mut self, k_bf: f64) {
        self.k_bf = k_bf;
    }

    /// Cancels the feedthrough with `canceller` from the next tick (None: no cancellation).
    pub fn set_canceller(&mut self, canceller: Option<Canceller>) {
        self.canceller = canceller;
    }

    pub fn canceller(&self) -> Option<&Canceller> {
        self.canceller.as_ref()
    }

    #[inline]
    pub fn tick(&mut self, drive: Drive) -> TickRecord {
        let m = self.plant.measure();
        self.last = m;
        // The body responds to the true cab motion; at the desk station it is not shaken.
        let h = match self.seat {
            Seat::On => self.body.step(self.plant.cab_displacement()),
            Seat::Off => 0.0,
        };
        let (hand, r_c, cancelled) = match drive {
            Drive::Hand(p_h) => {
                let (r_c, c) =
                    reference_from_device(self.k_bf, p_h - h, m.cab_accel, &mut self.canceller);
                (p_h, r_c, c)
            }
            Drive::Reference(r) => (0.0, r, Cancelled::default()),
            Drive::Excited { hand, r_c } => (hand, r_c, Cancelled::default()),
        };
        let v = self.compensator.step(r_c, m);
        let applied = self.plant.step(v);
        TickRecord {
            hand,
            feedthrough: h,
            r_c,
            valve: applied,
            y: m.y,
            cab_accel: m.cab_accel,
            cancellation: cancelled.output_mm,
            cancellation_tripped: cancelled.tripped_now,
        }
    }

    /// Back to rest: plant, body, compensator and canceller states zeroed.
    pub fn reset(&mut self) {
        self.plant.write_state(&[0.0; 7]);
        self.body.reset();
        self.compensator.reset();
        if let Some(c) = &mut self.canceller {
            c.reset();
        }
        self.last = Measurement::default();
    }
}

/// Plant, body, compensator, then the canceller's filters when there is one.
impl LinearState for ClosedLoop {
    fn state_len(&self) -> usize {
        self.plant.state_len()
            + self.body.state_len()
            + self.compensator.state_len()
            + self.canceller.as_ref().map_or(0, LinearState::state_len)
    }
    fn read_state(&self, out: &mut [f64]) {
        let (p, b, c) = (
            self.plant.state_len(),
            self.body.state_len(),
            self.compensator.state_len(),
        );
        self.plant.read_state(out);
        self.body.read_state(&mut out[p..]);
        self.compensator.read_state(&mut out[p + b..]);
        if let Some(k) = &self.canceller {
            k.read_state(&mut out[p + b + c..]);
        }
    }
    fn write_state(&mut self, s: &[f64]) {
        let (p, b, c) = (
            self.plant.state_len(),
            self.body.state_len(),
            self.compensator.state_len(),
        );
        self.plant.write_state(s);
        self.body.write_state(&s[p..]);
        self.compensator.write_state(&s[p + b..]);
        if let Some(k) = &mut self.canceller {
            k.write_state(&s[p + b + c..]);
        }
    }
}
