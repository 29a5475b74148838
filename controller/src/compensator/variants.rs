//! Named design variants for the workbench commands (`robustness`): a compensator name, or
//! a name and an option after a colon — `pid-shaper:zvd`, `pid-shaper:ei-per-mode`, … —
//! `lqr-cabacc:kalman` — each the default design with that option set.

use super::{CompensatorKind, CompensatorSpec, ObserverDesign, default_spec};
use crate::error::ParamError;
use crate::params::PlantParams;
use crate::shaper::{ShaperMethod, ShaperParams};

/// Every option a name can carry, with the compensator it applies to.
pub const OPTIONS: [(CompensatorKind, &str); 9] = [
    (CompensatorKind::PidShaper, "zvd"),
    (CompensatorKind::PidShaper, "ei"),
    (CompensatorKind::PidShaper, "two-hump-ei"),
    (CompensatorKind::PidShaper, "zvd-per-mode"),
    (CompensatorKind::PidShaper, "ei-per-mode"),
    (CompensatorKind::PidShaper, "two-hump-ei-per-mode"),
    (CompensatorKind::Lqr, "kalman"),
    (CompensatorKind::LqrCabvel, "kalman"),
    (CompensatorKind::LqrCabacc, "kalman"),
];

/// Every variant name: every compensator (`CompensatorKind::ALL`), then each option.
pub fn names() -> Vec<String> {
    CompensatorKind::ALL
        .iter()
        .map(|k| k.name().to_string())
        .chain(OPTIONS.iter().map(|(k, o)| format!("{k}:{o}")))
        .collect()
}

/// The design a variant name stands for, on this plant at loop period `dt`.
pub fn variant(name: &str, plant: &PlantParams, dt: f64) -> Result<CompensatorSpec, ParamError> {
    let (kind, option) = match name.split_once(':') {
        Some((k, o)) => (k.parse::<CompensatorKind>()?, Some(o)),
        None => (name.parse::<CompensatorKind>()?, None),
    };
    let mut spec = default_spec(kind, plant);
    let Some(option) = option else {
        return Ok(spec);
    };
    if !OPTIONS.contains(&(kind, option)) {
        return Err(ParamError::Invalid {
            name: "design",
            message: format!("unknown design {name:?}; valid: {}", names().join(", ")),
        });
    }
    match &mut spec {
        CompensatorSpec::PidShaper { shaper, .. } => {
            let (method, per_mode) = match option.strip_suffix("-per-mode") {
                Some(m) => (m, true),
                None => (option, false),
            };
            let method = match method {
                "zvd" => ShaperMethod::Zvd,
                "ei" => ShaperMethod::Ei,
                _ => ShaperMethod::TwoHumpEi,
            };
            *shaper = if per_mode {
                ShaperParams {
                    method,
                    ..ShaperParams::default()
                }
            } else {
                ShaperParams::between_modes(method)
            };
        }
        CompensatorSpec::Lqr { lqr }
        | CompensatorSpec::LqrCabvel { lqr }
        | CompensatorSpec::LqrCabacc { lqr } => {
            lqr.observer = ObserverDesign::kalman_for(
                lqr.cab_output,
                plant.accel_noise_std,
                dt,
                plant.mode_omegas()[0],
            );
        }
        _ => unreachable!("options exist only for the shaper and the LQR designs"),
    }
    Ok(spec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_builds_and_unknown_ones_list_the_valid_ones() {
        let plant = PlantParams::default();
        for n in names() {
            let spec = variant(&n, &plant, 1e-3).unwrap();
            spec.validate().unwrap();
        }
        let err = variant("pid-shaper:zzz", &plant, 1e-3)
            .unwrap_err()
            .to_string();
        assert!(err.contains("pid-shaper:two-hump-ei-per-mode"), "{err}");
        assert!(variant("pidd", &plant, 1e-3).is_err());
    }
}
