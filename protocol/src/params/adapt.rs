//! The adaptive designs' parameters and what they report (issue 41): the structure's modes
//! move in the field by up to ±30 % (load, tires or outriggers, arm configuration, wear), and a
//! fixed notch or zero-vibration shaper loses most of its reduction when its mode moves by a
//! fraction of its frequency. An adaptive design estimates the mode online and retunes.

use serde::{Deserialize, Serialize};

use super::{CompensatorKind, ParamError, check};

/// How an adaptive design follows the cab mode: the range its estimate may move over, the
/// estimator's memory, when the estimate is trusted, and how often and how gently the
/// design is changed. A field left out of the JSON takes its default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct AdaptParams {
    /// Half-width of the range of the mode-frequency ratio r (estimate / design frequency)
    /// the estimator covers, [1 − range, 1 + range], and the design's downward limit: a
    /// design is retuned down to 1 − range. Default 0.3: the ±30 % the modes move in the
    /// field.
    pub range: f64,
    /// How far above the design (r ≤ 1 + range_up) the design is retuned; an estimate above
    /// keeps the design at 1 + range_up. Absent (the default): the kind's
    /// (`default_range_up`) — 0 for the notch and the shaper, `range` for the scheduled LQR.
    /// Why (docs/machine-conditions.md): the feedthrough loop's critical frequency sits
    /// below the first mode, where it is set by the position loop, and does not rise with
    /// the modes; a notch or shaper retuned upward passes more there and leaves the loop
    /// less stable than the fixed design, which already keeps its reduction above.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range_up: Option<f64>,
    /// The estimator's memory (s): the time constant of its exponential forgetting.
    pub memory_s: f64,
    /// The estimate is confident while the relative standard deviation of its frequency
    /// (from the estimator's covariance) is at most this.
    pub max_rel_std: f64,
    /// The design is changed at most once per this period (s).
    pub retune_period_s: f64,
    /// A change crossfades the old design's output into the new one's over this time (s);
    /// at most the retune period.
    pub blend_s: f64,
}

impl Default for AdaptParams {
    fn default() -> Self {
        Self {
            range: 0.3,
            range_up: None,
            memory_s: 4.0,
            max_rel_std: 0.05,
            retune_period_s: 1.0,
            blend_s: 0.5,
        }
    }
}

impl AdaptParams {
    pub fn validate(&self) -> Result<(), ParamError> {
        check("adapt.range", self.range, 0.01, 0.5)?;
        if let Some(up) = self.range_up {
            // The estimator covers ±range: a design above it would never be chosen.
            check("adapt.range_up", up, 0.0, self.range)?;
        }
        check("adapt.memory_s", self.memory_s, 0.2, 120.0)?;
        check("adapt.max_rel_std", self.max_rel_std, 1e-4, 0.5)?;
        check("adapt.retune_period_s", self.retune_period_s, 0.01, 600.0)?;
        check("adapt.blend_s", self.blend_s, 0.001, self.retune_period_s)
    }

    /// The lowest and highest mode-frequency ratio the estimator reports.
    pub fn ratio_bounds(&self) -> (f64, f64) {
        (1.0 - self.range, 1.0 + self.range)
    }

    /// The upward limit of an adaptive design of `kind` when `range_up` is absent: 0 for
    /// the notch and the shaper (measured: above the design their fixed filters keep their
    /// reduction, and every upward retune costs margin with the body), `range` for the
    /// scheduled LQR (its fixed design loses 40 % of its reduction with the modes 30 %
    /// high, and its designs above keep the nominal damping of the mode and more margin).
    pub fn default_range_up(&self, kind: CompensatorKind) -> f64 {
        match kind {
            CompensatorKind::PidNotchAdaptive | CompensatorKind::PidShaperAdaptive => 0.0,
            _ => self.range,
        }
    }

    /// The lowest and highest ratio an adaptive design of `kind` is retuned to:
    /// [1 − range, 1 + range_up (or the kind's default)].
    pub fn retune_bounds(&self, kind: CompensatorKind) -> (f64, f64) {
        let up = self.range_up.unwrap_or_else(|| self.default_range_up(kind));
        (1.0 - self.range, 1.0 + up)
    }
}

/// What an adaptive compensator reports with a trial's result: its estimate of the dominant
/// (first) cab mode, whether it trusted it, and how often it changed its design.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct AdaptationStatus {
    /// The estimated mode frequency (Hz); absent before the estimator has seen a mode.
    pub f_hz: Option<f64>,
    /// The mode's damping ratio as the estimator models it (the controller's bank of
    /// structure models keeps the design's); absent with `f_hz`.
    pub zeta: Option<f64>,
    /// The estimate is trusted now.
    pub confident: bool,
    /// When the estimate first became trusted (s from the start of the trial).
    pub confident_since_s: Option<f64>,
    /// The mode-frequency ratio of the design running now (1 = the fixed design).
    pub ratio: f64,
    /// Changes of design applied.
    pub retunes: u32,
    /// Retune decisions taken without a confident estimate: each kept or restored the
    /// fixed design.
    pub fallbacks: u32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{
        CabOutput, CompensatorKind, CompensatorSpec, LqrParams, NotchParams, PidParams,
        ShaperParams,
    };

    const PID: PidParams = PidParams {
        kp: 0.5,
        ti: 0.15,
        td: 0.04,
        n: 10.0,
    };

    fn adaptive_specs() -> [CompensatorSpec; 3] {
        let adapt = AdaptParams::default();
        [
            CompensatorSpec::PidNotchAdaptive {
                pid: PID,
                notch: NotchParams::default(),
                adapt,
            },
            CompensatorSpec::PidShaperAdaptive {
                pid: PID,
                shaper: ShaperParams::default(),
                adapt,
            },
            CompensatorSpec::LqrCabvelScheduled {
                lqr: LqrParams::for_output(CabOutput::Velocity, 2.0),
                adapt,
            },
        ]
    }

    #[test]
    fn adaptive_specs_round_trip_and_name_their_fixed_counterpart() {
        for spec in adaptive_specs() {
            let kind = spec.kind();
            assert!(kind.is_adaptive() && !kind.is_lqr(), "{kind}");
            let json = serde_json::to_value(&spec).unwrap();
            assert_eq!(json["kind"], kind.name());
            assert_eq!(json["adapt"]["range"], 0.3);
            assert_eq!(
                serde_json::from_value::<CompensatorSpec>(json).unwrap(),
                spec
            );
            // Frozen at 1 it is its fixed counterpart with the same parameters.
            let fixed = spec.frozen_at(1.0);
            assert_eq!(Some(fixed.kind()), kind.fixed_counterpart());
            assert!(fixed.adapt().is_none() && spec.adapt().is_some());
        }
        for kind in CompensatorKind::ALL {
            assert_eq!(
                kind.is_adaptive(),
                CompensatorKind::ALL[6..].contains(&kind)
            );
        }
        // Omitted adaptation fields take their defaults.
        let spec: CompensatorSpec = serde_json::from_value(serde_json::json!({
            "kind": "pid-notch-adaptive", "pid": PID, "notch": {}, "adapt": {"range": 0.2}
        }))
        .unwrap();
        assert_eq!(
            spec.adapt(),
            Some(&AdaptParams {
                range: 0.2,
                ..AdaptParams::default()
            })
        );
    }

    #[test]
    fn the_upward_limit_round_trips_and_defaults_per_kind() {
        // Absent: left out of the JSON (older specs and their hashes read as before), and the
        // kind's default applies — the prefilters are not retuned upward, the LQR is.
        let json = serde_json::to_value(AdaptParams::default()).unwrap();
        assert!(json.get("range_up").is_none(), "{json}");
        let [notch, shaper, lqr] = adaptive_specs();
        assert_eq!(notch.retune_bounds(), Some((0.7, 1.0)));
        assert_eq!(shaper.retune_bounds(), Some((0.7, 1.0)));
        assert_eq!(lqr.retune_bounds(), Some((0.7, 1.3)));
        assert_eq!(CompensatorSpec::Pid { pid: PID }.retune_bounds(), None);
        // Set: it round-trips and overrides the kind's default.
        let spec = CompensatorSpec::PidNotchAdaptive {
            pid: PID,
            notch: NotchParams::default(),
            adapt: AdaptParams {
                range_up: Some(0.1),
                ..AdaptParams::default()
            },
        };
        spec.validate().unwrap();
        let json = serde_json::to_value(&spec).unwrap();
        assert_eq!(json["adapt"]["range_up"], 0.1);
        let back: CompensatorSpec = serde_json::from_value(json).unwrap();
        assert_eq!(back, spec);
        let (lo, hi) = back.retune_bounds().unwrap();
        assert!((lo - 0.7).abs() < 1e-12 && (hi - 1.1).abs() < 1e-12);
        // The estimator's range stays symmetric.
        assert_eq!(back.adapt().unwrap().ratio_bounds(), (0.7, 1.3));
    }

    #[test]
    fn frozen_at_scales_every_mode_dependent_frequency() {
        let [notch, shaper, lqr] = adaptive_specs().map(|s| s.frozen_at(1.3));
        let CompensatorSpec::PidNotch { notch, .. } = notch else {
            unreachable!()
        };
        assert!((notch.f_hz - 5.1 * 1.3).abs() < 1e-12);
        let CompensatorSpec::PidShaper { shaper, .. } = shaper else {
            unreachable!()
        };
        for (m, d) in shaper.modes.iter().zip(ShaperParams::default().modes) {
            assert!((m.f_hz - d.f_hz * 1.3).abs() < 1e-12 && m.zeta == d.zeta);
        }
        let CompensatorSpec::LqrCabvel { lqr } = lqr else {
            unreachable!()
        };
        assert!((lqr.design_mode_scale - 1.3).abs() < 1e-12);
        // The scale is in the JSON only when it is not 1, so existing designs (and the hashes
        // of the studies that hold them) read as before.
        assert_eq!(serde_json::to_value(lqr).unwrap()["design_mode_scale"], 1.3);
        let plain = LqrParams::for_output(CabOutput::Velocity, 2.0);
        assert!(
            serde_json::to_value(plain)
                .unwrap()
                .get("design_mode_scale")
                .is_none()
        );
    }

    #[test]
    fn validation_names_the_field_and_its_range() {
        for (bad, field) in [
            (
                AdaptParams {
                    range: 0.9,
                    ..AdaptParams::default()
                },
                "adapt.range",
            ),
            (
                AdaptParams {
                    range_up: Some(0.31),
                    ..AdaptParams::default()
                },
                "adapt.range_up",
            ),
            (
                AdaptParams {
                    range_up: Some(-0.01),
                    ..AdaptParams::default()
                },
                "adapt.range_up",
            ),
            (
                AdaptParams {
                    memory_s: 0.0,
                    ..AdaptParams::default()
                },
                "adapt.memory_s",
            ),
            (
                AdaptParams {
                    max_rel_std: f64::NAN,
                    ..AdaptParams::default()
                },
                "adapt.max_rel_std",
            ),
            (
                AdaptParams {
                    retune_period_s: 0.0,
                    ..AdaptParams::default()
                },
                "adapt.retune_period_s",
            ),
            (
                AdaptParams {
                    blend_s: 2.0,
                    ..AdaptParams::default()
                },
                "adapt.blend_s",
            ),
        ] {
            let spec = CompensatorSpec::LqrCabvelScheduled {
                lqr: LqrParams::for_output(CabOutput::Velocity, 2.0),
                adapt: bad,
            };
            let err = spec.validate().unwrap_err().to_string();
            assert!(err.contains(field) && err.contains("in ["), "{err}");
        }
        let err = serde_json::from_value::<AdaptParams>(serde_json::json!({"rangee": 0.3}))
            .unwrap_err()
            .to_string();
        assert!(err.contains("rangee"), "{err}");
    }

    #[test]
    fn the_status_serializes_with_absent_estimates_as_null() {
        let status = AdaptationStatus {
            f_hz: None,
            zeta: None,
            confident: false,
            confident_since_s: None,
            ratio: 1.0,
            retunes: 0,
            fallbacks: 3,
        };
        let json = serde_json::to_string(&status).unwrap();
        assert_eq!(
            json,
            r#"{"f_hz":null,"zeta":null,"confident":false,"confident_since_s":null,"ratio":1.0,"retunes":0,"fallbacks":3}"#
        );
        assert_eq!(
            serde_json::from_str::<AdaptationStatus>(&json).unwrap(),
            status
        );
    }
}
