//! Every parameter of a simulated rig and its compensators in one document: what
//! `bdft-controller defaults` prints and `--params FILE` reads back, so a researcher can
//! start from the identified values, change what the study varies, and keep the file with
//! the results.

use serde::{Deserialize, Serialize};

use crate::closed_loop::LoopSetup;
use crate::compensator::{CompensatorKind, CompensatorSpec, default_spec};
use crate::error::ParamError;
use crate::operator::OperatorParams;
use crate::params::{BodyModel, LoopParams, PlantParams, Seat, check};
use crate::signals::StepParams;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ParamSet {
    /// Loop sample period (s).
    pub dt: f64,
    pub plant: PlantParams,
    pub body: BodyModel,
    pub operator: OperatorParams,
    pub steps: StepParams,
    /// Compensator designs; a kind not listed gets its default design for `plant`.
    pub compensators: Vec<CompensatorSpec>,
}

impl Default for ParamSet {
    fn default() -> Self {
        let plant = PlantParams::default();
        Self {
            dt: LoopParams::default().dt,
            compensators: CompensatorKind::ALL
                .iter()
                .map(|&k| default_spec(k, &plant))
                .collect(),
            plant,
            body: BodyModel::default(),
            operator: OperatorParams::default(),
            steps: StepParams::default(),
        }
    }
}

impl ParamSet {
    pub fn validate(&self) -> Result<(), ParamError> {
        check("dt", self.dt, 1e-5, 0.02)?;
        self.plant.validate()?;
        self.body.validate()?;
        self.operator.validate()?;
        self.steps.validate()?;
        for (i, c) in self.compensators.iter().enumerate() {
            c.validate()?;
            if self.compensators[..i].iter().any(|o| o.kind() == c.kind()) {
                return Err(ParamError::Invalid {
                    name: "compensators",
                    message: format!("{} is listed twice", c.kind()),
                });
            }
        }
        Ok(())
    }

    /// The design of `kind`: the listed one, else the default for this plant.
    pub fn compensator(&self, kind: CompensatorKind) -> CompensatorSpec {
        self.compensators
            .iter()
            .find(|c| c.kind() == kind)
            .cloned()
            .unwrap_or_else(|| default_spec(kind, &self.plant))
    }

    pub fn setup(&self, kind: CompensatorKind, seat: Seat, k_bf: f64) -> LoopSetup {
        LoopSetup {
            plant: self.plant,
            body: self.body,
            loop_params: LoopParams { dt: self.dt, k_bf },
            seat,
            compensator: self.compensator(kind),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_round_trip_and_partial_documents_fill_in_defaults() {
        let d = ParamSet::default();
        let text = serde_json::to_string_pretty(&d).unwrap();
        assert_eq!(serde_json::from_str::<ParamSet>(&text).unwrap(), d);
        let partial: ParamSet = serde_json::from_str(
            r#"{"plant": {"k_s": 0.3}, "body": {"kind": "rigid-mass", "k_h": 0.4}}"#,
        )
        .unwrap();
        assert_eq!(partial.plant.k_s, 0.3);
        assert_eq!(partial.plant.k_vc, 22.0);
        assert_eq!(partial.body, BodyModel::RigidMass { k_h: 0.4 });
        assert_eq!(partial.compensators.len(), CompensatorKind::ALL.len());
    }

    #[test]
    fn unknown_fields_and_out_of_range_values_are_rejected() {
        let err = serde_json::from_str::<ParamSet>(r#"{"plant": {"kvc": 3}}"#)
            .unwrap_err()
            .to_string();
        assert!(err.contains("kvc"), "{err}");
        let p: ParamSet = serde_json::from_str(r#"{"plant": {"z1": 1.5}}"#).unwrap();
        let err = p.validate().unwrap_err().to_string();
        assert!(err.contains("plant.z1") && err.contains("0.99"), "{err}");
        let mut twice = ParamSet::default();
        twice.compensators.push(twice.compensators[0].clone());
        assert!(twice.validate().unwrap_err().to_string().contains("twice"));
    }
}
