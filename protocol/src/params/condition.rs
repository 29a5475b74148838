//! Machine conditions: the rig as it stands in the field rather than on the thesis's steel
//! stilts. A condition is a ground (`stilts`, `tires`, `outriggers`), a bucket (empty, or
//! `loaded` with a fill), and the arm driven (the boom, or the `stick`), written as its
//! parts joined by `+` (`tires+loaded`, `outriggers+loaded:0.6+stick`); the thesis's rig is
//! `stilts`, the default, and changes nothing. `modes:R` scales both modes by R on top (a
//! shift no rule names, or a robustness check: `modes:0.7`, `modes:1.3`).
//!
//! Each part changes the structure's modes and the valve/cylinder terms by a stated rule
//! (`RULES`): a factor per parameter with its physical reason, its source and the relative
//! uncertainty of the rule. Factors multiply, so a combination is the product of its parts.
//! The rules are scalings of the identified rig, not identifications of another machine: the
//! docs (`docs/machine-conditions.md`) say where each comes from and how far to trust it.
//!
//! *Why a design plant and a rig:* a study's compensators are designed for the rig the
//! thesis identified (`PlantParams`); the condition changes only the machine they run on
//! (`MachineCondition::apply`), which is what the field does to a fixed design.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{ParamError, PlantParams};

/// What the machine stands on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Ground {
    /// The thesis's rig: the backhoe on steel stilts (the identified model).
    #[default]
    Stilts,
    /// On its own tires, outriggers up.
    Tires,
    /// Outriggers down on soil, rear wheels lifted (how a backhoe digs).
    Outriggers,
}

/// The arm the valve drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Arm {
    /// The boom cylinder (the thesis's human-subject configuration).
    #[default]
    Boom,
    /// The stick cylinder (the other configuration the thesis modelled).
    Stick,
}

/// A machine condition; `Default` is the thesis's rig.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MachineCondition {
    pub ground: Ground,
    /// Bucket fill as a fraction of its rated (struck) load; 0 = empty.
    pub bucket_fill: f64,
    pub arm: Arm,
    /// Both structure modes' frequencies scaled by this on top of the rules (`modes:R`): a
    /// machine whose modes moved for a reason no rule names (wear, a ground not listed), or
    /// a robustness check; 1 = none.
    pub mode_scale: f64,
}

/// One part's rule: the factors it applies to the rig and why.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Rule {
    /// The part's name as written in a condition.
    pub name: &'static str,
    /// Factors on f1_hz, f2_hz, z1, z2, k_s, k_vc, w_vc (at a full bucket for `loaded`).
    pub factors: Factors,
    /// Relative uncertainty (one standard deviation) of the rule's frequency factors.
    pub uncertainty: f64,
    pub reason: &'static str,
    pub source: &'static str,
}

/// Multiplicative factors on the rig's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Factors {
    pub f1: f64,
    pub f2: f64,
    pub z1: f64,
    pub z2: f64,
    pub k_s: f64,
    pub k_vc: f64,
    pub w_vc: f64,
}

impl Factors {
    const ONE: Self = Self {
        f1: 1.0,
        f2: 1.0,
        z1: 1.0,
        z2: 1.0,
        k_s: 1.0,
        k_vc: 1.0,
        w_vc: 1.0,
    };

    fn times(self, o: Self) -> Self {
        Self {
            f1: self.f1 * o.f1,
            f2: self.f2 * o.f2,
            z1: self.z1 * o.z1,
            z2: self.z2 * o.z2,
            k_s: self.k_s * o.k_s,
            k_vc: self.k_vc * o.k_vc,
            w_vc: self.w_vc * o.w_vc,
        }
    }
}

/// The range of `modes:R`: a mode moved by more than half is another machine.
pub const MODE_SCALE_RANGE: (f64, f64) = (0.5, 1.5);

/// The largest bucket fill the load rule holds for: a heaped bucket (SAE J296 rates heaped
/// capacity at about 1.2 × struck); beyond it the load pressure nears relief.
pub const MAX_BUCKET_FILL: f64 = 1.2;

/// Supply pressure and the boom's load pressure empty and per rated load (bar): a backhoe's
/// open-centre circuit at 200 bar, the empty boom holding 60 bar, a rated load 35 bar more.
const SUPPLY_BAR: f64 = 200.0;
const EMPTY_LOAD_BAR: f64 = 60.0;
const RATED_LOAD_BAR: f64 = 35.0;
/// Share of each mode's modal mass a rated load adds, and of the cylinder's driven mass.
const LOAD_MASS_MODE: [f64; 2] = [0.2, 0.3];
const LOAD_MASS_CYLINDER: f64 = 0.25;

/// The rules, one per part; `loaded`'s factors are at a full (rated) bucket.
pub const RULES: [Rule; 5] = [
    Rule {
        name: "stilts",
        factors: Factors::ONE,
        uncertainty: 0.0,
        reason: "the rig the thesis identified: every parameter as measured",
        source: "the thesis's identification (docs: system-model)",
    },
    Rule {
        name: "tires",
        factors: Factors {
            f1: 0.75,
            f2: 0.85,
            z1: 1.3,
            z2: 1.1,
            k_s: 1.25,
            ..Factors::ONE
        },
        uncertainty: 0.10,
        reason: "the tires' vertical stiffness acts in series with the structure's: a mode's \
                 frequency falls as 1/sqrt(1 + k_mode/k_ground), k_mode/k_tire 0.78 for the \
                 machine's rocking (first) mode, 0.38 for the boom-local second; the tires' \
                 hysteresis adds damping; the softer support lets the cab rock further per mm \
                 of cylinder (K_S). The thesis: on tires the vibration is 'lower frequency and \
                 higher amplitude' than on its stiffer stilts",
        source: "thesis §7.2; a wheeled tractor's vibration system at 3-5 Hz (Sci. Rep. 2025, \
                 doi:10.1038/s41598-025-18736-x); series-stiffness rule",
    },
    Rule {
        name: "outriggers",
        factors: Factors {
            f1: 0.9,
            f2: 0.95,
            k_s: 1.08,
            ..Factors::ONE
        },
        uncertainty: 0.07,
        reason: "steel outrigger legs on soil pads: stiffer than tires, softer than the stilts; \
                 the soil's compliance in series (k_mode/k_ground 0.23 and 0.11)",
        source: "series-stiffness rule; soil compliance an engineering estimate",
    },
    Rule {
        name: "loaded",
        factors: Factors {
            // 1/sqrt(1 + share) at a rated load (LOAD_MASS_MODE).
            f1: 0.912_870_929_175_276_9,
            f2: 0.877_058_019_307_028_9,
            // 1.1 per rated load: the heavier boom's reaction rocks the cab further.
            k_s: 1.1,
            // sqrt((200 − 95)/(200 − 60)): the valve's flow at the same opening.
            k_vc: 0.866_025_403_784_438_6,
            // 1/sqrt(1 + 0.25): the cylinder's oil spring against a heavier boom.
            w_vc: 0.894_427_190_999_915_9,
            ..Factors::ONE
        },
        uncertainty: 0.05,
        reason: "the payload at the boom's tip adds modal mass (a mode's frequency as \
                 1/sqrt(1 + m_load/m_mode), 20 % and 30 % of the two modal masses per rated \
                 load) and load pressure: a valve's flow at a given opening goes as \
                 sqrt(p_supply − p_load), so K_VC falls, and the hydraulic natural frequency \
                 goes as 1/sqrt(driven mass)",
        source: "Merritt, Hydraulic Control Systems (1967), the orifice flow equation and the \
                 hydraulic natural frequency; SAE J296 bucket ratings",
    },
    Rule {
        name: "stick",
        factors: Factors {
            f1: 1.1,
            f2: 1.2,
            k_s: 0.6,
            k_vc: 1.3,
            w_vc: 1.15,
            ..Factors::ONE
        },
        uncertainty: 0.20,
        reason: "the stick cylinder moves a lighter link further from the cab: less reaction \
                 into the cab per mm (K_S), a smaller cylinder (more speed per valve unit, \
                 a stiffer oil spring) and stiffer effective modes",
        source: "an engineering estimate: the thesis modelled the stick-excited configuration, \
                 but its parameters are not in this project's reference; trust it least",
    },
];

fn rule(name: &str) -> &'static Rule {
    RULES
        .iter()
        .find(|r| r.name == name)
        .expect("every part has a rule")
}

impl Default for MachineCondition {
    fn default() -> Self {
        Self::STILTS
    }
}

impl MachineCondition {
    /// The thesis's rig.
    pub const STILTS: Self = Self {
        ground: Ground::Stilts,
        bucket_fill: 0.0,
        arm: Arm::Boom,
        mode_scale: 1.0,
    };

    pub fn is_default(&self) -> bool {
        *self == Self::STILTS
    }

    /// Every named condition with an empty or a rated bucket: each ground × bucket × arm.
    pub fn named() -> Vec<Self> {
        let mut out = Vec::new();
        for arm in [Arm::Boom, Arm::Stick] {
            for bucket_fill in [0.0, 1.0] {
                for ground in [Ground::Stilts, Ground::Tires, Ground::Outriggers] {
                    out.push(Self {
                        ground,
                        bucket_fill,
                        arm,
                        mode_scale: 1.0,
                    });
                }
            }
        }
        out
    }

    /// The combined factors of its parts.
    pub fn factors(&self) -> Factors {
        let ground = rule(match self.ground {
            Ground::Stilts => "stilts",
            Ground::Tires => "tires",
            Ground::Outriggers => "outriggers",
        })
        .factors;
        let phi = self.bucket_fill;
        let load_bar = EMPTY_LOAD_BAR + RATED_LOAD_BAR * phi;
        let load = Factors {
            f1: 1.0 / (1.0 + LOAD_MASS_MODE[0] * phi).sqrt(),
            f2: 1.0 / (1.0 + LOAD_MASS_MODE[1] * phi).sqrt(),
            k_s: 1.0 + 0.1 * phi,
            k_vc: ((SUPPLY_BAR - load_bar) / (SUPPLY_BAR - EMPTY_LOAD_BAR)).sqrt(),
            w_vc: 1.0 / (1.0 + LOAD_MASS_CYLINDER * phi).sqrt(),
            ..Factors::ONE
        };
        let arm = match self.arm {
            Arm::Boom => Factors::ONE,
            Arm::Stick => rule("stick").factors,
        };
        let moved = Factors {
            f1: self.mode_scale,
            f2: self.mode_scale,
            ..Factors::ONE
        };
        ground.times(load).times(arm).times(moved)
    }

    /// Relative uncertainty (one standard deviation) of the combined frequency factors: the
    /// parts' rules taken as independent.
    pub fn uncertainty(&self) -> f64 {
        let mut var = 0.0;
        for (on, name) in [
            (self.ground == Ground::Tires, "tires"),
            (self.ground == Ground::Outriggers, "outriggers"),
            (self.bucket_fill > 0.0, "loaded"),
            (self.arm == Arm::Stick, "stick"),
        ] {
            if on {
                var += rule(name).uncertainty.powi(2);
            }
        }
        var.sqrt()
    }

    /// Checks that the rules hold for this condition: the fill inside its rule, the modes'
    /// order and separation kept (the two-mode model and every design between them assume
    /// it), the load pressure below the supply's.
    pub fn validate(&self) -> Result<(), ParamError> {
        let bad = |message: String| {
            Err(ParamError::Invalid {
                name: "condition",
                message,
            })
        };
        if !(self.bucket_fill.is_finite() && (0.0..=MAX_BUCKET_FILL).contains(&self.bucket_fill)) {
            return bad(format!(
                "{self}: a bucket fill of {} is outside the load rule's validity, 0 to \
                 {MAX_BUCKET_FILL} of the rated load (a heaped bucket)",
                self.bucket_fill
            ));
        }
        let (lo, hi) = MODE_SCALE_RANGE;
        if !(self.mode_scale.is_finite() && (lo..=hi).contains(&self.mode_scale)) {
            return bad(format!(
                "{self}: modes scaled by {} is outside {lo} to {hi}: a mode moved by more than \
                 half is another machine",
                self.mode_scale
            ));
        }
        Ok(())
    }

    /// The rig under this condition: the design rig `plant` scaled by the rules. Refused
    /// (naming the condition and what broke) where the scaled rig leaves the rules' validity.
    pub fn apply(&self, plant: &PlantParams) -> Result<PlantParams, ParamError> {
        self.validate()?;
        let f = self.factors();
        let rig = PlantParams {
            f1_hz: plant.f1_hz * f.f1,
            f2_hz: plant.f2_hz * f.f2,
            z1: (plant.z1 * f.z1).min(0.99),
            z2: (plant.z2 * f.z2).min(0.99),
            k_s: plant.k_s * f.k_s,
            k_vc: plant.k_vc * f.k_vc,
            w_vc: plant.w_vc * f.w_vc,
            ..*plant
        };
        if rig.f2_hz < 1.2 * rig.f1_hz {
            return Err(ParamError::Invalid {
                name: "condition",
                message: format!(
                    "{self} brings the second mode ({:.2} Hz) within 20 % of the first \
                     ({:.2} Hz): the rules assume two separate modes; outside their validity",
                    rig.f2_hz, rig.f1_hz
                ),
            });
        }
        rig.validate()?;
        Ok(rig)
    }
}

impl fmt::Display for MachineCondition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts: Vec<String> = Vec::new();
        match self.ground {
            Ground::Stilts => {}
            Ground::Tires => parts.push("tires".into()),
            Ground::Outriggers => parts.push("outriggers".into()),
        }
        if self.bucket_fill == 1.0 {
            parts.push("loaded".into());
        } else if self.bucket_fill != 0.0 {
            parts.push(format!("loaded:{}", self.bucket_fill));
        }
        if self.arm == Arm::Stick {
            parts.push("stick".into());
        }
        if self.mode_scale != 1.0 {
            parts.push(format!("modes:{}", self.mode_scale));
        }
        if parts.is_empty() {
            return f.write_str("stilts");
        }
        f.write_str(&parts.join("+"))
    }
}

impl FromStr for MachineCondition {
    type Err = ParamError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |message: String| ParamError::Invalid {
            name: "condition",
            message,
        };
        const VALID: &str = "parts joined by '+': one ground (stilts, tires, outriggers), \
                             loaded or loaded:FILL, stick, modes:R";
        if s.len() > 64 {
            return Err(bad(format!("{} characters; at most 64", s.len())));
        }
        let mut c = Self::STILTS;
        let (mut ground, mut load, mut arm, mut moved) = (None::<&str>, false, false, false);
        for part in s.split('+') {
            let (name, value) = match part.split_once(':') {
                Some((n, v)) => (n, Some(v)),
                None => (part, None),
            };
            let dup = |what: &str| bad(format!("{s:?} names {what} twice"));
            match (name, value) {
                ("stilts" | "tires" | "outriggers", None) => {
                    if ground == Some(name) {
                        return Err(dup("the ground"));
                    }
                    if let Some(g) = ground {
                        return Err(bad(format!(
                            "{s:?}: the machine cannot stand on {g} and {name} at once; \
                             one ground is allowed"
                        )));
                    }
                    ground = Some(name);
                    c.ground = match name {
                        "stilts" => Ground::Stilts,
                        "tires" => Ground::Tires,
                        _ => Ground::Outriggers,
                    };
                }
                ("loaded", v) => {
                    if load {
                        return Err(dup("the bucket"));
                    }
                    load = true;
                    c.bucket_fill = match v {
                        None => 1.0,
                        Some(v) => v.parse().map_err(|_| {
                            bad(format!("{v:?} in {s:?} is not a bucket fill (a number)"))
                        })?,
                    };
                    if c.bucket_fill == 0.0 {
                        return Err(bad(format!(
                            "{s:?}: loaded:0 is an empty bucket; leave 'loaded' out"
                        )));
                    }
                }
                ("modes", Some(v)) => {
                    if moved {
                        return Err(dup("the modes' scale"));
                    }
                    moved = true;
                    c.mode_scale = v.parse().map_err(|_| {
                        bad(format!(
                            "{v:?} in {s:?} is not a scale of the modes (a number)"
                        ))
                    })?;
                }
                ("stick", None) => {
                    if arm {
                        return Err(dup("the stick"));
                    }
                    arm = true;
                    c.arm = Arm::Stick;
                }
                _ => return Err(bad(format!("unknown part {part:?} in {s:?}; {VALID}"))),
            }
        }
        c.validate()?;
        Ok(c)
    }
}

impl Serialize for MachineCondition {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for MachineCondition {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_the_default_changes_nothing() {
        let plant = PlantParams::default();
        assert_eq!(MachineCondition::STILTS.apply(&plant).unwrap(), plant);
        for c in MachineCondition::named() {
            let name = c.to_string();
            assert_eq!(name.parse::<MachineCondition>().unwrap(), c, "{name}");
            let json = serde_json::to_string(&c).unwrap();
            assert_eq!(serde_json::from_str::<MachineCondition>(&json).unwrap(), c);
            c.apply(&plant).unwrap();
        }
        assert_eq!(MachineCondition::named().len(), 12);
        let c: MachineCondition = "stick+loaded:0.5+outriggers".parse().unwrap();
        assert_eq!(c.to_string(), "outriggers+loaded:0.5+stick");
        let moved: MachineCondition = "modes:1.3".parse().unwrap();
        assert_eq!(moved.to_string(), "modes:1.3");
        let rig = moved.apply(&plant).unwrap();
        assert!((rig.f1_hz - 5.2).abs() < 1e-12 && (rig.f2_hz - 6.2 * 1.3).abs() < 1e-12);
    }

    #[test]
    fn the_load_rule_is_the_orifice_equation_and_the_mass_rule() {
        // The table's full-bucket factors are the formulas at a rated load.
        let f = "loaded".parse::<MachineCondition>().unwrap().factors();
        let r = rule("loaded").factors;
        for (got, want) in [
            (f.f1, r.f1),
            (f.f2, r.f2),
            (f.k_vc, r.k_vc),
            (f.w_vc, r.w_vc),
        ] {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
        // sqrt(Δp): a half-full bucket loses less than half the full one's valve gain.
        let half = "loaded:0.5".parse::<MachineCondition>().unwrap().factors();
        assert!((half.k_vc - (122.5f64 / 140.0).sqrt()).abs() < 1e-12);
        // On tires the first mode falls most, as the thesis says the field does.
        let tires = "tires".parse::<MachineCondition>().unwrap();
        let rig = tires.apply(&PlantParams::default()).unwrap();
        assert!((rig.f1_hz - 3.0).abs() < 1e-12 && rig.k_s > 0.45);
    }

    #[test]
    fn bad_conditions_are_refused_naming_what_is_wrong() {
        for (s, says) in [
            ("stilts+tires", "one ground"),
            ("tires+tires", "twice"),
            ("tires+outriggers", "one ground"),
            ("loaded+loaded", "twice"),
            ("loaded:1.5", "validity"),
            ("loaded:-0.2", "validity"),
            ("loaded:x", "not a bucket fill"),
            ("loaded:0", "empty bucket"),
            ("modes:2", "another machine"),
            ("modes:x", "not a scale"),
            ("modes:0.8+modes:0.9", "twice"),
            ("mud", "unknown part"),
            ("", "unknown part"),
        ] {
            let err = s.parse::<MachineCondition>().unwrap_err().to_string();
            assert!(
                err.contains(says) && err.starts_with("condition"),
                "{s}: {err}"
            );
        }
        // A design rig whose modes are already close leaves the rules' validity when the
        // load pulls the second mode down onto the first.
        let close = PlantParams {
            f2_hz: 4.9,
            ..PlantParams::default()
        };
        let err = "loaded"
            .parse::<MachineCondition>()
            .unwrap()
            .apply(&close)
            .unwrap_err()
            .to_string();
        assert!(err.contains("within 20 %"), "{err}");
    }
}
