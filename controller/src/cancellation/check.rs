//! Before a cancelling test: what the model would do with the bodies the subject may have.
//! The tick's guard cannot tell a model wrong in phase from a right one (the cab follows the
//! person's own commands); this check can, because it knows the subject's identified body
//! and its 95 % interval. For the body as fitted and each parameter at either end of its
//! interval (11 bodies), it finds the feedthrough the model leaves, |1 − Ĥ/H|², over
//! 0.5–5 Hz — above 1 somewhere, cancelling is worse than none there — and whether the
//! cancelled loop is stable at the test's K_BF (the stability analysis reads the canceller
//! as part of the loop).

use bdft_protocol::identification::BodyFit;

use super::{CancellationModel, Canceller};
use crate::analysis::{LinearizedLoop, linear_setup};
use crate::closed_loop::{ClosedLoop, LoopSetup};
use crate::error::DesignError;
use crate::identification::fit::feedthrough;

/// The band the check looks at (Hz): where feedthrough hurts tracking and the cab's modes lie.
pub const BAND_HZ: (f64, f64) = (0.5, 5.0);

/// Points of the band, log-spaced.
const POINTS: u32 = 46;

/// What a cancelling design would do with one body.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyCheck {
    /// Which body: "as fitted", or a parameter at one end of its interval ("k_h at 0.41").
    pub body: String,
    /// The most of this body's feedthrough the model leaves anywhere in the band (1: as much
    /// as without cancellation), and where.
    pub worst_residual: f64,
    pub worst_at_hz: f64,
    /// The cancelled loop stable at the setup's K_BF with this body.
    pub stable: bool,
}

/// The check over the bodies the subject may have; `passes` when cancelling is nowhere
/// worse than none and the loop stable with each.
#[derive(Debug, Clone, PartialEq)]
pub struct Verdict {
    pub bodies: Vec<BodyCheck>,
}

impl Verdict {
    pub fn passes(&self) -> bool {
        self.bodies
            .iter()
            .all(|b| b.stable && b.worst_residual <= 1.0)
    }

    /// The first body it fails with, and why, for a refusal that names it.
    pub fn failure(&self) -> Option<String> {
        self.bodies.iter().find_map(|b| {
            if !b.stable {
                Some(format!(
                    "with the body {} the cancelled loop is unstable",
                    b.body
                ))
            } else if b.worst_residual > 1.0 {
                Some(format!(
                    "with the body {} cancelling leaves {:.2} times the feedthrough at {:.2} Hz: worse than none",
                    b.body, b.worst_residual, b.worst_at_hz
                ))
            } else {
                None
            }
        })
    }
}

/// The bodies of an identified fit: as fitted, then each parameter at either end of its
/// interval. An error when the fit has a parameter not identified (no body to check).
pub fn bodies_of(fit: &BodyFit) -> Result<Vec<(String, [f64; 5])>, String> {
    fit.identified_body()?;
    let e = [
        fit.k_h,
        fit.torso_f_hz,
        fit.torso_zeta,
        fit.arm_f_hz,
        fit.arm_zeta,
    ];
    let fitted = e.map(|p| p.value);
    let mut out = vec![("as fitted".to_string(), fitted)];
    for (i, name) in BodyFit::PARAMETERS.iter().enumerate() {
        for end in [e[i].lo, e[i].hi] {
            let mut b = fitted;
            b[i] = end;
            out.push((format!("{name} at {end:.3}"), b));
        }
    }
    Ok(out)
}

/// The model against each body: the residual over the band and the cancelled loop's
/// stability with `setup`'s plant, compensator and K_BF.
pub fn check(
    model: &CancellationModel,
    bodies: &[(String, [f64; 5])],
    setup: &LoopSetup,
) -> Result<Verdict, DesignError> {
    let dt = setup.loop_params.dt;
    let canceller = Canceller::new(model, dt)?;
    let analysed = CancellationModel {
        // The analysis perturbs states by whole units; the guard must not trip on them.
        limit_mm: 1000.0,
        ..*model
    };
    let mut checks = Vec::with_capacity(bodies.len());
    for (name, b) in bodies {
        let theta = b.map(f64::ln);
        let (mut worst, mut at) = (0.0, BAND_HZ.0);
        for i in 0..POINTS {
            let f = BAND_HZ.0 * (BAND_HZ.1 / BAND_HZ.0).powf(f64::from(i) / f64::from(POINTS - 1));
            // `feedthrough` is in mm per m/s², the canceller in mm per mm/s².
            let h = feedthrough(&theta, f) * 1e-3;
            let r = (nalgebra::Complex::from(1.0) - canceller.response(f, dt) / h).norm_sqr();
            if r > worst {
                (worst, at) = (r, f);
            }
        }
        let mut body_setup = setup.clone();
        body_setup.body = crate::params::BodyModel::Seated {
            k_h: b[0],
            torso_f_hz: b[1],
            torso_zeta: b[2],
            arm_f_hz: b[3],
            arm_zeta: b[4],
        };
        let mut lp = ClosedLoop::new(&linear_setup(&body_setup), 0)?;
        lp.set_canceller(Some(Canceller::new(&analysed, dt)?));
        let stable = LinearizedLoop::read_off(&mut lp, dt).is_stable(setup.loop_params.k_bf)?;
        checks.push(BodyCheck {
            body: name.clone(),
            worst_residual: worst,
            worst_at_hz: at,
            stable,
        });
    }
    Ok(Verdict { bodies: checks })
}
