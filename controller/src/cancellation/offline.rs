//! The offline bound (Venrooij's "optimal signal cancellation"): a recorded test's device
//! reading cancelled after the fact, the model run over the recorded cab acceleration. It is
//! an upper bound on what cancellation can do online: offline the cab moves as it did, while
//! online the cancelled input changes the commands and so the cab's motion.

use bdft_protocol::cancellation::CancellationModel;
use bdft_protocol::params::ParamError;

use super::Canceller;

/// The band the bound reports (Hz): where feedthrough hurts tracking (as the check's).
pub const BAND_HZ: (f64, f64) = super::check::BAND_HZ;

/// A signal's power in `BAND_HZ` before and after the offline cancellation (its mean square
/// in the band, mm²).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BandPower {
    pub before_mm2: f64,
    pub after_mm2: f64,
}

impl BandPower {
    /// The share of the band's power the cancellation removed (negative: it added).
    pub fn removed(&self) -> f64 {
        1.0 - self.after_mm2 / self.before_mm2
    }
}

/// What the offline cancellation did to the device reading and to the feedthrough in it;
/// when the model's guard turned it off (s), if it did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OfflineBound {
    pub device: BandPower,
    pub feedthrough: BandPower,
    pub off_at_s: Option<f64>,
}

/// `model` run over the recorded `cab` acceleration (mm/s²) every `dt`, subtracted from the
/// recorded `device` reading (mm); `feedthrough` is the record's feedthrough channel (the
/// device reads hand − feedthrough: the simulated rig's record tells the two apart).
pub fn offline_bound(
    model: &CancellationModel,
    dt: f64,
    device: &[f32],
    cab: &[f32],
    feedthrough: &[f32],
) -> Result<OfflineBound, ParamError> {
    let mut canceller = Canceller::new(model, dt)?;
    let mut off_at_s = None;
    let output: Vec<f64> = cab
        .iter()
        .enumerate()
        .map(|(k, &a)| {
            let c = canceller.step(f64::from(a));
            if c.tripped_now {
                off_at_s = Some(k as f64 * dt);
            }
            c.output_mm
        })
        .collect();
    // What the device carries of `x` before, and after the output is subtracted.
    let powers = |x: &[f32], sign: f64| {
        let before: Vec<f64> = x.iter().map(|v| sign * f64::from(*v)).collect();
        let after: Vec<f64> = before.iter().zip(&output).map(|(b, o)| b - o).collect();
        BandPower {
            before_mm2: band_power(&before, dt, BAND_HZ.0, BAND_HZ.1),
            after_mm2: band_power(&after, dt, BAND_HZ.0, BAND_HZ.1),
        }
    };
    Ok(OfflineBound {
        device: powers(device, 1.0),
        feedthrough: powers(feedthrough, -1.0),
        off_at_s,
    })
}

/// Power of `x` (sampled every `dt`) in [lo, hi] Hz: its mean square there, from its DFT at
/// the band's bins only (one-sided: 2·Σ|X_k|²/N², Parseval).
pub fn band_power(x: &[f64], dt: f64, lo: f64, hi: f64) -> f64 {
    use std::f64::consts::PI;
    let n = x.len();
    let df = 1.0 / (n as f64 * dt);
    let (k_lo, k_hi) = ((lo / df).ceil() as usize, (hi / df).floor() as usize);
    (k_lo..=k_hi)
        .map(|k| {
            // The bin's phasor advanced by multiplication: one rotation per sample.
            let w = 2.0 * PI * k as f64 / n as f64;
            let step = nalgebra::Complex::new(w.cos(), -w.sin());
            let mut p = nalgebra::Complex::new(1.0, 0.0);
            let mut sum = nalgebra::Complex::new(0.0, 0.0);
            for (i, v) in x.iter().enumerate() {
                sum += p * *v;
                p *= step;
                // Renormalize now and then: the product drifts off the unit circle.
                if i % 1024 == 1023 {
                    p /= p.norm();
                }
            }
            2.0 * sum.norm_sqr() / (n as f64 * n as f64)
        })
        .sum()
}
