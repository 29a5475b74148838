//! Parameters of the experiment's signals and of the simulated subject.

use serde::{Deserialize, Serialize};

use super::{ParamError, check};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct OperatorParams {
    /// Visual-motor reaction delay τ (s).
    pub reaction_delay_s: f64,
    /// Neuromuscular corner ω_nm (rad/s) and damping ζ_nm: the arm follows the intended
    /// motion through ω_nm²/(s² + 2ζ_nm·ω_nm·s + ω_nm²).
    pub neuromuscular_w: f64,
    pub neuromuscular_zeta: f64,
    /// Proportional gain on the seen error (mm of cylinder per mm of error).
    pub error_gain: f64,
    /// Integral gain on the seen error (1/s).
    pub error_integral_gain: f64,
    /// Standard deviation of the remnant at the hand (mm of device travel); 0 = none.
    pub remnant_std_mm: f64,
    /// Lowering of the error gain per mm of RMS shake the operator sees on the cylinder
    /// (above 1.5 Hz): with an oscillatory controlled element people lower their gain.
    pub shake_aversion_per_mm: f64,
    /// Rise of the arm's frequency (fraction) per m/s² RMS of cab acceleration felt: people
    /// grip harder when shaken. Acts on a seated body (`BodyModel::Seated`) only.
    pub grip_stiffening_per_m_s2: f64,
    /// Rise of the remnant (fraction) per m/s² RMS of cab acceleration felt: whole-body
    /// vibration makes manual control noisier.
    pub vibration_remnant_per_m_s2: f64,
    /// Slowing of the operator per m/s² RMS of cab acceleration felt: the neuromuscular
    /// corner ω_nm falls by 1/(1 + this·felt). Whole-body vibration lowers the operator's
    /// gain and adds phase lag in the tracking band (crossover regression under a
    /// disturbing, oscillatory task).
    pub vibration_slowing_per_m_s2: f64,
    /// Crossover regression per m/s² RMS of cab acceleration felt: of the operator's
    /// correction (pursuit of the target and of the seen error, t − y_seen plus the error
    /// gain's part) the fraction x·felt/(1 + x·felt) is withheld, so its gain falls by
    /// 1/(1 + x·felt). McRuer: in a disturbing task people lower their crossover; unlike
    /// the slowing it leaves the arm's filtering of its own 4–6 Hz output as it was.
    pub vibration_regression_per_m_s2: f64,
    /// Added reaction delay per m/s² RMS of cab acceleration felt (s per m/s²), at most
    /// `MAX_VIBRATION_DELAY_S`: a shaken person sees and acts later (Levison 1976: motion
    /// as +0.05 s of pilot delay; McLeod: vibration's cost is phase lag in the linear,
    /// target-correlated part). Unlike the regression and the slowing it leaves the size and
    /// the spectrum of the commands as they were, so riding costs accuracy without calming
    /// the machine.
    #[serde(default)]
    pub vibration_delay_s_per_m_s2: f64,
    /// Motor noise of active tracking at the hand (mm, standard deviation): white noise
    /// through a first-order lag at `MOTOR_NOISE_CORNER_HZ`, added after the arm's
    /// neuromuscular lag, so its spectrum stays flat up to the tremor band where the
    /// remnant's falls off (Levison's motor noise on the control rate; the submovements'
    /// edges). It is what a desk operator's corrections put into the cab modes; 0 = none,
    /// as for an operator set up before it existed.
    pub motor_noise_mm: f64,
}

/// Corner of the motor noise's first-order lag (Hz): physiological tremor and the edges of
/// submovements reach 6–12 Hz (shared/docs/person-model-evidence.md §2–3).
pub const MOTOR_NOISE_CORNER_HZ: f64 = 8.0;

/// The most delay felt vibration adds to an operator's reaction (s): the delay's ring is
/// sized for it when the operator is built, so the tick never allocates.
pub const MAX_VIBRATION_DELAY_S: f64 = 0.3;

impl Default for OperatorParams {
    fn default() -> Self {
        Self {
            reaction_delay_s: 0.25,
            neuromuscular_w: 12.0,
            neuromuscular_zeta: 0.45,
            error_gain: 0.3,
            error_integral_gain: 0.5,
            remnant_std_mm: 0.5,
            shake_aversion_per_mm: 0.5,
            grip_stiffening_per_m_s2: 0.15,
            vibration_remnant_per_m_s2: 0.5,
            vibration_slowing_per_m_s2: 0.0,
            vibration_regression_per_m_s2: 0.0,
            vibration_delay_s_per_m_s2: 0.0,
            motor_noise_mm: 0.0,
        }
    }
}

impl OperatorParams {
    /// The vibration effects and the error gain take the population's bounds
    /// (`population::bounds`): one range for a parameter whether it is set by hand or
    /// drawn. The delay, the arm, the integral gain and the remnant allow more than a
    /// draw does: a drawn subject's learning and fatigue lengthen its delay and raise its
    /// remnant (up to the population's bounds, inside these), and a hand-set operator may
    /// be an outlier.
    pub fn validate(&self) -> Result<(), ParamError> {
        use super::population::bounds::*;
        let checks = [
            (
                "operator.reaction_delay_s",
                self.reaction_delay_s,
                (0.0, 1.0),
            ),
            (
                "operator.neuromuscular_w",
                self.neuromuscular_w,
                (0.5, 200.0),
            ),
            (
                "operator.neuromuscular_zeta",
                self.neuromuscular_zeta,
                (0.05, 3.0),
            ),
            (
                "operator.shake_aversion_per_mm",
                self.shake_aversion_per_mm,
                SHAKE_AVERSION_PER_MM,
            ),
            (
                "operator.grip_stiffening_per_m_s2",
                self.grip_stiffening_per_m_s2,
                GRIP_STIFFENING_PER_M_S2,
            ),
            (
                "operator.vibration_remnant_per_m_s2",
                self.vibration_remnant_per_m_s2,
                VIBRATION_REMNANT_PER_M_S2,
            ),
            (
                "operator.vibration_slowing_per_m_s2",
                self.vibration_slowing_per_m_s2,
                VIBRATION_SLOWING_PER_M_S2,
            ),
            (
                "operator.vibration_regression_per_m_s2",
                self.vibration_regression_per_m_s2,
                VIBRATION_REGRESSION_PER_M_S2,
            ),
            (
                "operator.vibration_delay_s_per_m_s2",
                self.vibration_delay_s_per_m_s2,
                VIBRATION_DELAY_S_PER_M_S2,
            ),
            ("operator.error_gain", self.error_gain, ERROR_GAIN),
            (
                "operator.error_integral_gain",
                self.error_integral_gain,
                (0.0, 10.0),
            ),
            ("operator.remnant_std_mm", self.remnant_std_mm, (0.0, 50.0)),
            (
                "operator.motor_noise_mm",
                self.motor_noise_mm,
                MOTOR_NOISE_MM,
            ),
        ];
        for (name, value, (low, high)) in checks {
            check(name, value, low, high)?;
        }
        Ok(())
    }
}

/// How the protocol's random-step targets are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct StepParams {
    /// Time between steps (s).
    pub interval_s: f64,
    /// Step levels stay within ±range_mm (the machine's desired range of motion).
    pub range_mm: f64,
    /// Standard deviation every target must have, so no controller gets a harder signal.
    pub std_mm: f64,
}

impl Default for StepParams {
    fn default() -> Self {
        Self {
            interval_s: 2.0,
            range_mm: 40.0,
            std_mm: 20.0,
        }
    }
}

impl StepParams {
    pub fn validate(&self) -> Result<(), ParamError> {
        check("steps.interval_s", self.interval_s, 0.05, 60.0)?;
        check("steps.range_mm", self.range_mm, 0.1, 1000.0)?;
        // Zero-mean levels confined to ±R have a standard deviation of at most R; near that
        // bound almost every draw would be rejected, so keep a margin.
        check("steps.std_mm", self.std_mm, 0.01, 0.8 * self.range_mm)
    }
}
