//! Models of the rig and the operator's body: the valve/cylinder, the two-mode tractor
//! structure, the accelerometer and the biodynamic feedthrough.
//!
//! `plant`: the 7-state valve/cylinder + two-mode structure (x_c, ẋ_c, ẍ_c, x⃛_c, y, ẏ, ÿ), its
//! design-model variant with the inner velocity loop, and the simulated rig (`Plant`:
//! ZOH-discretized, valve saturation and dead-band, stroke limits, seeded accelerometer noise).
//! `body`: the seat-to-hand model (rigid mass by default; the seated body h = k_h·(1 − T·A)·x_c of
//! torso transmissibility and arm admittance, its arm retuned by the operator's grip without a
//! jump).
//!
//! *Invariant:* `saturate` is the only way a valve command leaves the core; non-finite becomes 0.

mod body;
mod plant;

pub use body::Body;
#[cfg(test)]
pub(crate) use body::SEATED_FOR_TESTS;
pub(crate) use body::transmissibility;
pub use plant::{
    Measurement, Plant, continuous_plant, design_model, idx, saturate, structure_polynomials,
};
pub(crate) use plant::{engine, engine_advance};
