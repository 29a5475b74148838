//! Models of the rig and the operator's body: the valve/cylinder, the two-mode tractor
//! structure, the accelerometer and the biodynamic feedthrough.

mod body;
mod plant;

pub use body::Body;
#[cfg(test)]
pub(crate) use body::SEATED_FOR_TESTS;
pub(crate) use body::transmissibility;
pub use plant::{
    Measurement, Plant, continuous_plant, design_model, idx, saturate, structure_polynomials,
};
