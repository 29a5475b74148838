//! Compensator designs as data: which controller and all its parameters. This is what a
//! study records, the server stores and sends, and the controller builds from.

use serde::{Deserialize, Serialize};

use super::{AdaptParams, ParamError, check};

/// The compensators, by the names used everywhere (CLI, protocol, database, exports).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum CompensatorKind {
    Pid,
    PidNotch,
    PidShaper,
    Lqr,
    LqrCabvel,
    LqrCabacc,
    PidNotchAdaptive,
    PidShaperAdaptive,
    LqrCabvelScheduled,
}

impl CompensatorKind {
    /// All nine: the five of the human-subject study first, then cab acceleration feedback,
    /// then the three adaptive designs (issue 41).
    pub const ALL: [Self; 9] = [
        Self::Pid,
        Self::PidNotch,
        Self::PidShaper,
        Self::Lqr,
        Self::LqrCabvel,
        Self::LqrCabacc,
        Self::PidNotchAdaptive,
        Self::PidShaperAdaptive,
        Self::LqrCabvelScheduled,
    ];
    /// The five compared in the human-subject study.
    pub const STUDY: [Self; 5] = [
        Self::Pid,
        Self::PidNotch,
        Self::PidShaper,
        Self::Lqr,
        Self::LqrCabvel,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Pid => "pid",
            Self::PidNotch => "pid-notch",
            Self::PidShaper => "pid-shaper",
            Self::Lqr => "lqr",
            Self::LqrCabvel => "lqr-cabvel",
            Self::LqrCabacc => "lqr-cabacc",
            Self::PidNotchAdaptive => "pid-notch-adaptive",
            Self::PidShaperAdaptive => "pid-shaper-adaptive",
            Self::LqrCabvelScheduled => "lqr-cabvel-scheduled",
        }
    }

    /// The state-feedback designs (an LQR with or without cab feedback): the ones a
    /// personalized study tunes to each subject. The scheduled LQR is not among them:
    /// personalization tunes one design's weights, the schedule holds seven designs.
    pub fn is_lqr(self) -> bool {
        matches!(self, Self::Lqr | Self::LqrCabvel | Self::LqrCabacc)
    }

    /// The designs that retune themselves from an online estimate of the cab mode.
    pub fn is_adaptive(self) -> bool {
        self.fixed_counterpart().is_some()
    }

    /// The fixed design an adaptive one retunes (and falls back to when its estimate is not
    /// confident); none for the fixed designs.
    pub fn fixed_counterpart(self) -> Option<Self> {
        match self {
            Self::PidNotchAdaptive => Some(Self::PidNotch),
            Self::PidShaperAdaptive => Some(Self::PidShaper),
            Self::LqrCabvelScheduled => Some(Self::LqrCabvel),
            Self::Pid
            | Self::PidNotch
            | Self::PidShaper
            | Self::Lqr
            | Self::LqrCabvel
            | Self::LqrCabacc => None,
        }
    }
}

impl std::fmt::Display for CompensatorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for CompensatorKind {
    type Err = ParamError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| ParamError::Invalid {
                name: "compensator",
                message: format!(
                    "unknown compensator {s:?}; valid: {}",
                    Self::ALL.map(|k| k.name()).join(", ")
                ),
            })
    }
}

impl TryFrom<String> for CompensatorKind {
    type Error = ParamError;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

/// A compensator and all its parameters: enough to rebuild it exactly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum CompensatorSpec {
    Pid {
        pid: PidParams,
    },
    PidNotch {
        pid: PidParams,
        notch: NotchParams,
    },
    PidShaper {
        pid: PidParams,
        shaper: ShaperParams,
    },
    Lqr {
        lqr: LqrParams,
    },
    LqrCabvel {
        lqr: LqrParams,
    },
    LqrCabacc {
        lqr: LqrParams,
    },
    PidNotchAdaptive {
        pid: PidParams,
        notch: NotchParams,
        adapt: AdaptParams,
    },
    PidShaperAdaptive {
        pid: PidParams,
        shaper: ShaperParams,
        adapt: AdaptParams,
    },
    LqrCabvelScheduled {
        lqr: LqrParams,
        adapt: AdaptParams,
    },
}

impl CompensatorSpec {
    pub fn kind(&self) -> CompensatorKind {
        match self {
            Self::Pid { .. } => CompensatorKind::Pid,
            Self::PidNotch { .. } => CompensatorKind::PidNotch,
            Self::PidShaper { .. } => CompensatorKind::PidShaper,
            Self::Lqr { .. } => CompensatorKind::Lqr,
            Self::LqrCabvel { .. } => CompensatorKind::LqrCabvel,
            Self::LqrCabacc { .. } => CompensatorKind::LqrCabacc,
            Self::PidNotchAdaptive { .. } => CompensatorKind::PidNotchAdaptive,
            Self::PidShaperAdaptive { .. } => CompensatorKind::PidShaperAdaptive,
            Self::LqrCabvelScheduled { .. } => CompensatorKind::LqrCabvelScheduled,
        }
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        match self {
            Self::Pid { pid } => pid.validate(),
            Self::PidNotch { pid, notch } => pid.validate().and(notch.validate()),
            Self::PidShaper { pid, shaper } => pid.validate().and(shaper.validate()),
            Self::Lqr { lqr } | Self::LqrCabvel { lqr } | Self::LqrCabacc { lqr } => lqr.validate(),
            Self::PidNotchAdaptive { pid, notch, adapt } => {
                pid.validate().and(notch.validate()).and(adapt.validate())
            }
            Self::PidShaperAdaptive { pid, shaper, adapt } => {
                pid.validate().and(shaper.validate()).and(adapt.validate())
            }
            Self::LqrCabvelScheduled { lqr, adapt } => lqr.validate().and(adapt.validate()),
        }
    }

    /// The adaptation parameters of an adaptive design.
    pub fn adapt(&self) -> Option<&AdaptParams> {
        match self {
            Self::PidNotchAdaptive { adapt, .. }
            | Self::PidShaperAdaptive { adapt, .. }
            | Self::LqrCabvelScheduled { adapt, .. } => Some(adapt),
            Self::Pid { .. }
            | Self::PidNotch { .. }
            | Self::PidShaper { .. }
            | Self::Lqr { .. }
            | Self::LqrCabvel { .. }
            | Self::LqrCabacc { .. } => None,
        }
    }

    /// The lowest and highest ratio an adaptive design is retuned to
    /// (`AdaptParams::retune_bounds`); None for a fixed design.
    pub fn retune_bounds(&self) -> Option<(f64, f64)> {
        self.adapt().map(|a| a.retune_bounds(self.kind()))
    }

    /// The fixed design frozen at the mode-frequency ratio `r` (estimate / design
    /// frequency): the notch's centre and the shaper's modes at `r` times theirs, an LQR
    /// designed on the plant with both structure modes scaled by `r` (its
    /// `design_mode_scale` multiplied by `r`). An adaptive design becomes its fixed
    /// counterpart (`frozen_at(1.0)` is what it runs when not confident, and what the
    /// analysis judges); a design without a mode-dependent part (PID) is returned as is.
    pub fn frozen_at(&self, r: f64) -> CompensatorSpec {
        let notch_at = |n: &NotchParams| NotchParams {
            f_hz: n.f_hz * r,
            ..*n
        };
        let shaper_at = |s: &ShaperParams| ShaperParams {
            modes: s
                .modes
                .iter()
                .map(|m| Mode {
                    f_hz: m.f_hz * r,
                    ..*m
                })
                .collect(),
            ..s.clone()
        };
        let lqr_at = |l: &LqrParams| LqrParams {
            design_mode_scale: l.design_mode_scale * r,
            ..*l
        };
        match self {
            Self::Pid { pid } => Self::Pid { pid: *pid },
            Self::PidNotch { pid, notch } | Self::PidNotchAdaptive { pid, notch, .. } => {
                Self::PidNotch {
                    pid: *pid,
                    notch: notch_at(notch),
                }
            }
            Self::PidShaper { pid, shaper } | Self::PidShaperAdaptive { pid, shaper, .. } => {
                Self::PidShaper {
                    pid: *pid,
                    shaper: shaper_at(shaper),
                }
            }
            Self::Lqr { lqr } => Self::Lqr { lqr: lqr_at(lqr) },
            Self::LqrCabvel { lqr } | Self::LqrCabvelScheduled { lqr, .. } => {
                Self::LqrCabvel { lqr: lqr_at(lqr) }
            }
            Self::LqrCabacc { lqr } => Self::LqrCabacc { lqr: lqr_at(lqr) },
        }
    }
}

/// PID gains in the standard (ISA) form V = Kp·(e + (1/Ti)∫e + Td·de/dt), the derivative
/// low-passed at N/Td.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct PidParams {
    pub kp: f64,
    /// Integral time (s).
    pub ti: f64,
    /// Derivative time (s); 0 disables the derivative.
    pub td: f64,
    /// Derivative filter ratio N.
    pub n: f64,
}

impl PidParams {
    pub fn validate(&self) -> Result<(), ParamError> {
        check("pid.kp", self.kp, 1e-6, 1e3)?;
        check("pid.ti", self.ti, 1e-3, 1e4)?;
        check("pid.td", self.td, 0.0, 100.0)?;
        check("pid.n", self.n, 1.0, 1e3)
    }
}

/// Notch on the cylinder reference, inside the feedthrough loop and outside the position
/// loop: D_N(s) = (s² + 2ζ_Nω_N s + ω_N²)/(s + ω_N)². Zeros midway between the structure
/// modes, critically damped poles at the same frequency; the gain at ω_N is exactly ζ_N.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct NotchParams {
    pub f_hz: f64,
    pub zeta: f64,
}

impl Default for NotchParams {
    fn default() -> Self {
        Self {
            f_hz: 5.1,
            zeta: 0.3,
        }
    }
}

impl NotchParams {
    pub fn validate(&self) -> Result<(), ParamError> {
        check("notch.f_hz", self.f_hz, 0.1, 100.0)?;
        check("notch.zeta", self.zeta, 0.0, 1.0)
    }
}

/// One structural mode to suppress.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Mode {
    pub f_hz: f64,
    pub zeta: f64,
}

impl Mode {
    /// (ω, ω_d) in rad/s.
    pub fn omegas(&self) -> (f64, f64) {
        let w = 2.0 * std::f64::consts::PI * self.f_hz;
        (w, w * (1.0 - self.zeta * self.zeta).sqrt())
    }
}

/// The impulse sequence shaped for each mode. `zv` cancels the mode exactly and is the
/// shortest; the robust ones trade delay for insensitivity to the mode's frequency: `zvd`
/// (three impulses over one damped period, zero slope of the residual at the mode), `ei`
/// (extra-insensitive: residual `tolerance` at the mode, zero on both sides, one period) and
/// `two-hump-ei` (four impulses over 1.5 periods, the widest band within `tolerance`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum ShaperMethod {
    #[default]
    Zv,
    Zvd,
    Ei,
    TwoHumpEi,
}

impl ShaperMethod {
    fn is_zv(&self) -> bool {
        *self == Self::Zv
    }
}

/// EI shapers' residual vibration allowed at the mode, relative to no shaping.
pub const DEFAULT_SHAPER_TOLERANCE: f64 = 0.05;

fn is_default_tolerance(v: &f64) -> bool {
    *v == DEFAULT_SHAPER_TOLERANCE
}

/// The shaper: its method and the modes it is designed for (default: the two identified
/// structure modes, one shaper each, convolved). One mode between the two structure modes
/// gives a single robust shaper for both. `method` and `tolerance` are left out of the JSON
/// at their defaults, so a ZV shaper reads as it always did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct ShaperParams {
    pub modes: Vec<Mode>,
    #[serde(skip_serializing_if = "ShaperMethod::is_zv")]
    pub method: ShaperMethod,
    /// Residual vibration allowed by the EI methods (fraction, default 0.05); unused by zv
    /// and zvd.
    #[serde(skip_serializing_if = "is_default_tolerance")]
    pub tolerance: f64,
}

impl Default for ShaperParams {
    fn default() -> Self {
        Self {
            modes: vec![
                Mode {
                    f_hz: 4.0,
                    zeta: 0.06,
                },
                Mode {
                    f_hz: 6.2,
                    zeta: 0.04,
                },
            ],
            method: ShaperMethod::Zv,
            tolerance: DEFAULT_SHAPER_TOLERANCE,
        }
    }
}

impl ShaperParams {
    /// A `method` shaper at one mode midway between the two structure modes (5.1 Hz, the
    /// notch's centre; damping the modes' mean, 0.05): the robust shaper's band covers both.
    pub fn between_modes(method: ShaperMethod) -> Self {
        Self {
            modes: vec![Mode {
                f_hz: 5.1,
                zeta: 0.05,
            }],
            method,
            tolerance: DEFAULT_SHAPER_TOLERANCE,
        }
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        if self.modes.is_empty() || self.modes.len() > 4 {
            return Err(ParamError::Invalid {
                name: "shaper.modes",
                message: format!("{} modes given; allowed: 1 to 4", self.modes.len()),
            });
        }
        for m in &self.modes {
            check("shaper.modes.f_hz", m.f_hz, 0.1, 100.0)?;
            check("shaper.modes.zeta", m.zeta, 0.0, 0.7)?;
        }
        check("shaper.tolerance", self.tolerance, 1e-3, 0.3)
    }
}

/// Which cab signal the observer measures besides the cylinder position.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum CabOutput {
    /// ẋ_c, from the accelerometer high-passed then leakily integrated.
    Velocity,
    /// ẍ_c, the accelerometer itself (noisy, hence a small weight).
    Acceleration,
}

/// How the LQR's observer gain is designed.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ObserverDesign {
    /// Luenberger observer with the `observer_poles` placed.
    #[default]
    Placed,
    /// Steady-state Kalman filter: the gain from the dual Riccati equation for white noise
    /// of these intensities (power spectral densities, two-sided).
    Kalman {
        /// Disturbance on the velocity reference u ((mm/s)²·s).
        input_noise: f64,
        /// Disturbance on the structure's highest derivative, forcing the cab
        /// ((mm/s⁴)²·s).
        structure_noise: f64,
        /// Noise of the cylinder position measurement (mm²·s).
        position_noise: f64,
        /// Noise of the cab measurement (its unit squared · s).
        cab_noise: f64,
    },
}

impl ObserverDesign {
    fn is_placed(&self) -> bool {
        *self == Self::Placed
    }

    /// The Kalman design for a cab measurement `cab` from an accelerometer with white noise
    /// of `accel_noise_std` per sample at period `dt`: the accelerometer's intensity σ²·dt,
    /// for cab velocity divided by ω₁² (the leaky integrator at the first mode, `w1`).
    pub fn kalman_for(cab: CabOutput, accel_noise_std: f64, dt: f64, w1: f64) -> Self {
        let accel = accel_noise_std * accel_noise_std * dt;
        Self::Kalman {
            input_noise: 1.0,
            structure_noise: 1e6,
            position_noise: 1e-4,
            cab_noise: match cab {
                CabOutput::Acceleration => accel,
                CabOutput::Velocity => accel / (w1 * w1),
            },
        }
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        if let Self::Kalman {
            input_noise,
            structure_noise,
            position_noise,
            cab_noise,
        } = *self
        {
            check("lqr.observer.input_noise", input_noise, 0.0, 1e12)?;
            check("lqr.observer.structure_noise", structure_noise, 0.0, 1e12)?;
            check("lqr.observer.position_noise", position_noise, 1e-12, 1e12)?;
            check("lqr.observer.cab_noise", cab_noise, 1e-12, 1e12)?;
        }
        Ok(())
    }
}

/// LQR design and implementation parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct LqrParams {
    /// Inner velocity-loop gain K_P·K_VC (V = K_P(u − ẏ)).
    pub inner_loop_gain: f64,
    /// Output weights Λ = diag(α, β) in Q = (ΛC)ᵀ(ΛC), C = [y; cab output]; R = 1.
    pub alpha: f64,
    pub beta: f64,
    pub cab_output: CabOutput,
    /// Observer poles (rad/s), real, one per state (the placed observer's).
    pub observer_poles: [f64; 7],
    /// Placed poles (default, left out of the JSON) or a Kalman filter.
    #[serde(default, skip_serializing_if = "ObserverDesign::is_placed")]
    pub observer: ObserverDesign,
    /// Corner (rad/s) of the low-pass on the differentiated cylinder position giving ẏ.
    pub rate_filter_w: f64,
    /// Corner (rad/s) of the high-pass removing the accelerometer offset.
    pub cab_highpass_w: f64,
    /// Leak (rad/s) of the integrator turning acceleration into velocity; far below the
    /// structure modes (25 and 39 rad/s) so that it integrates there, yet cannot drift.
    pub cab_leak_w: f64,
    /// The design is made on the plant with both structure mode frequencies scaled by this
    /// (1 = the identified modes; left out of the JSON at 1): how a scheduled LQR holds its
    /// designs for modes that moved.
    #[serde(default = "unit_scale", skip_serializing_if = "is_unit_scale")]
    pub design_mode_scale: f64,
}

fn unit_scale() -> f64 {
    1.0
}

fn is_unit_scale(v: &f64) -> bool {
    *v == 1.0
}

impl LqrParams {
    pub fn for_output(cab_output: CabOutput, beta: f64) -> Self {
        Self {
            inner_loop_gain: 0.25,
            alpha: 40.0,
            beta,
            cab_output,
            observer_poles: [-175.0, -176.0, -180.0, -190.0, -191.0, -195.0, -196.0],
            observer: ObserverDesign::Placed,
            rate_filter_w: 2.0 * std::f64::consts::PI * 50.0,
            cab_highpass_w: 0.5,
            cab_leak_w: 0.5,
            design_mode_scale: 1.0,
        }
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        check("lqr.inner_loop_gain", self.inner_loop_gain, 1e-3, 100.0)?;
        check("lqr.alpha", self.alpha, 1e-3, 1e4)?;
        check("lqr.beta", self.beta, 0.0, 1e4)?;
        check("lqr.rate_filter_w", self.rate_filter_w, 1.0, 1e4)?;
        check("lqr.cab_highpass_w", self.cab_highpass_w, 1e-3, 100.0)?;
        check("lqr.cab_leak_w", self.cab_leak_w, 1e-3, 100.0)?;
        check("lqr.design_mode_scale", self.design_mode_scale, 0.2, 5.0)?;
        self.observer.validate()?;
        for p in self.observer_poles {
            check("lqr.observer_poles", p, -1e4, -1e-3)?;
        }
        let mut sorted = self.observer_poles;
        sorted.sort_by(f64::total_cmp);
        if sorted.windows(2).any(|w| w[1] - w[0] < 1e-6) {
            return Err(ParamError::Invalid {
                name: "lqr.observer_poles",
                message: "the seven observer poles must be distinct".into(),
            });
        }
        Ok(())
    }
}
