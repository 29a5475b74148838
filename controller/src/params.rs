//! Named physical parameters of the rig and the loop, with the values identified on the
//! original backhoe (docs: system-model.md). Every model is built from these; no matrix is
//! ever typed in by hand. The types are wire data, so they live in the protocol crate.

pub use bdft_protocol::params::{
    BodyModel, LoopParams, MAX_KBF, MachineCondition, NOMINAL_KBF, ParamError, PlantParams, Seat,
    check,
};
