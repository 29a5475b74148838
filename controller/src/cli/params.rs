//! What the analysis and simulation commands read: the parameter file (`--params`) and the
//! workbench's design names.

use std::path::PathBuf;

use anyhow::Context;
use bdft_controller::compensator::variants::variant;
use bdft_controller::compensator::{CompensatorKind, CompensatorSpec};
use bdft_controller::param_set::ParamSet;

/// The design a workbench name stands for: a compensator's name is the parameter file's
/// design of it (its default when the file lists none), a name with an option that variant
/// of the default design.
pub(super) fn design(params: &ParamSet, name: &str) -> anyhow::Result<CompensatorSpec> {
    Ok(match name.parse::<CompensatorKind>() {
        Ok(kind) => params.compensator(kind),
        Err(_) => variant(name, &params.plant, params.dt)?,
    })
}

pub(super) fn load_params(path: Option<&PathBuf>) -> anyhow::Result<ParamSet> {
    let Some(path) = path else {
        return Ok(ParamSet::default());
    };
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let params: ParamSet = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a valid parameter file", path.display()))?;
    params
        .validate()
        .with_context(|| format!("in {}", path.display()))?;
    Ok(params)
}
