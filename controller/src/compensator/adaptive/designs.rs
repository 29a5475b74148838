//! The prepared designs of an adaptive compensator, one per ratio of the schedule's grid,
//! and the tick that runs the active one and crossfades it with the one it replaces.

use bdft_protocol::params::{AdaptParams, CompensatorKind, CompensatorSpec, PlantParams};

use super::schedule::Switch;
use crate::compensator::{Compensator, Lqr, Pid, Prefilter};
use crate::error::DesignError;
use crate::filters::Biquad;
use crate::model::{Measurement, saturate};
use crate::shaper::DelayLine;
use crate::state::LinearState;

/// Grid steps either side of r = 1: the notch and the shaper are cheap to prepare and
/// lose reduction fast off their mode, so 1 % steps; the LQR's seven designs (a Riccati
/// equation and an observer each) are the schedule, and it degrades gently between.
pub fn grid_half(kind: CompensatorKind, adapt: &AdaptParams) -> usize {
    match kind {
        CompensatorKind::LqrCabvelScheduled => 3,
        _ => (adapt.range / 0.01).ceil() as usize,
    }
}

#[derive(Debug, Clone)]
pub enum Designs {
    /// A notch per ratio in front of the shared PID; while blending both notches run.
    Notch { notches: Vec<Biquad>, pid: Pid },
    /// A tap set per ratio reading one history, in front of the shared PID.
    Shaper {
        taps: Vec<Vec<(usize, f64)>>,
        line: DelayLine,
        pid: Pid,
    },
    /// An LQR with its observer per ratio.
    Lqr { lqrs: Vec<Lqr>, v_max: f64 },
}

impl Designs {
    /// Each design is what `Compensator::build` makes of the spec frozen at its ratio.
    pub fn new(
        spec: &CompensatorSpec,
        plant: &PlantParams,
        dt: f64,
        ratios: &[f64],
    ) -> Result<Self, DesignError> {
        let built = ratios
            .iter()
            .map(|&r| Compensator::build(&spec.frozen_at(r), plant, dt))
            .collect::<Result<Vec<_>, _>>()?;
        let mut pid_of_first = None;
        let mut notches = Vec::new();
        let mut taps = Vec::new();
        let mut lqrs = Vec::new();
        for c in built {
            match c {
                Compensator::Pid { pre, pid } => {
                    pid_of_first.get_or_insert(pid);
                    match pre {
                        Prefilter::Notch(f) => notches.push(f),
                        Prefilter::Shaper(s) => taps.push(s.taps().to_vec()),
                        Prefilter::None => unreachable!("adaptive PID designs have a prefilter"),
                    }
                }
                Compensator::Lqr(l) => lqrs.push(*l),
                Compensator::Adaptive(_) => unreachable!("a frozen design is fixed"),
            }
        }
        Ok(match (pid_of_first, notches.is_empty()) {
            (Some(pid), false) => Self::Notch { notches, pid },
            (Some(pid), true) => {
                // The lowest ratio has the longest shaper: the line is sized for it once.
                let longest = taps.iter().filter_map(|t| t.last()).map(|t| t.0).max();
                Self::Shaper {
                    line: DelayLine::new(longest.unwrap_or(0)),
                    taps,
                    pid,
                }
            }
            (None, _) => Self::Lqr {
                lqrs,
                v_max: plant.v_max,
            },
        })
    }

    /// Prepares design `to` to take over from `from`: the new notch or LQR starts from the
    /// old one's state (the shaper's tap sets share one history already).
    pub fn hand_over(&mut self, Switch { from, to }: Switch) {
        match self {
            Self::Notch { notches, .. } => notches[to].z = notches[from].z,
            Self::Shaper { .. } => {}
            Self::Lqr { lqrs, .. } => {
                // 7 observer states, the rate filter and the two accelerometer filters.
                let mut s = [0.0; 10];
                lqrs[from].read_state(&mut s);
                lqrs[to].write_state(&s);
            }
        }
    }

    /// One tick of design `active`, crossfaded with `blend`'s (old design, weight of the
    /// active one) while blending.
    #[inline]
    pub fn step(
        &mut self,
        active: usize,
        blend: Option<(usize, f64)>,
        r_c: f64,
        m: Measurement,
    ) -> f64 {
        // A bad reference must not poison the prefilters' or observers' states.
        let r_c = if r_c.is_finite() { r_c } else { 0.0 };
        let mix = |old: f64, new: f64, w: f64| old + w * (new - old);
        match self {
            Self::Notch { notches, pid } => {
                let new = notches[active].step(r_c);
                let r = blend.map_or(new, |(from, w)| mix(notches[from].step(r_c), new, w));
                pid.step(r - m.y)
            }
            Self::Shaper { taps, line, pid } => {
                line.push(r_c);
                let new = line.sum(&taps[active]);
                let r = blend.map_or(new, |(from, w)| mix(line.sum(&taps[from]), new, w));
                line.advance();
                pid.step(r - m.y)
            }
            Self::Lqr { lqrs, v_max } => {
                let new = lqrs[active].step(r_c, m);
                let v = blend.map_or(new, |(from, w)| mix(lqrs[from].step(r_c, m), new, w));
                saturate(v, *v_max)
            }
        }
    }

    pub fn reset(&mut self) {
        match self {
            Self::Notch { notches, pid } => {
                notches.iter_mut().for_each(Biquad::reset);
                pid.reset();
            }
            Self::Shaper { line, pid, .. } => {
                line.reset();
                pid.reset();
            }
            Self::Lqr { lqrs, .. } => lqrs.iter_mut().for_each(Lqr::reset),
        }
    }

    pub fn shaper_duration(&self, active: usize, dt: f64) -> Option<f64> {
        match self {
            Self::Shaper { taps, .. } => Some(taps[active].last().map_or(0.0, |t| t.0 as f64 * dt)),
            Self::Notch { .. } | Self::Lqr { .. } => None,
        }
    }

    /// The state of design `active` in the layout of its fixed counterpart (prefilter, then
    /// PID; or the LQR's).
    pub fn state_len(&self, active: usize) -> usize {
        match self {
            Self::Notch { notches, pid } => notches[active].state_len() + pid.state_len(),
            Self::Shaper { line, pid, .. } => line.state_len() + pid.state_len(),
            Self::Lqr { lqrs, .. } => lqrs[active].state_len(),
        }
    }

    pub fn read_state(&self, active: usize, out: &mut [f64]) {
        let (pre, pid): (&dyn LinearState, &Pid) = match self {
            Self::Notch { notches, pid } => (&notches[active], pid),
            Self::Shaper { line, pid, .. } => (line, pid),
            Self::Lqr { lqrs, .. } => return lqrs[active].read_state(out),
        };
        pre.read_state(out);
        pid.read_state(&mut out[pre.state_len()..]);
    }

    pub fn write_state(&mut self, active: usize, s: &[f64]) {
        let (pre, pid): (&mut dyn LinearState, &mut Pid) = match self {
            Self::Notch { notches, pid } => (&mut notches[active], pid),
            Self::Shaper { line, pid, .. } => (line, pid),
            Self::Lqr { lqrs, .. } => return lqrs[active].write_state(s),
        };
        pre.write_state(s);
        let n = pre.state_len();
        pid.write_state(&s[n..]);
    }
}
