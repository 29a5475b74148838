//! The states the server keeps of a study's records, as the API and exports name them.

use serde::{Deserialize, Serialize};

/// Defines a wire enum with its names, `as_str`, `Display`, `FromStr` and `TryFrom<String>`
/// (the error lists the allowed names), so no state travels as a bare string.
macro_rules! wire_enum {
    ($(#[$meta:meta])* $name:ident, $what:literal { $($(#[$vmeta:meta])* $variant:ident = $text:literal),+ $(,)? }) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        #[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
        #[serde(rename_all = "lowercase")]
        pub enum $name {
            $($(#[$vmeta])* $variant),+
        }

        impl $name {
            pub const ALL: &'static [Self] = &[$(Self::$variant),+];

            pub fn as_str(self) -> &'static str {
                match self {
                    $(Self::$variant => $text),+
                }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.as_str())
            }
        }

        impl std::str::FromStr for $name {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                Self::ALL
                    .iter()
                    .copied()
                    .find(|v| v.as_str() == s)
                    .ok_or_else(|| {
                        let allowed: Vec<&str> = Self::ALL.iter().map(|v| v.as_str()).collect();
                        format!("unknown {} {s:?}; allowed: {}", $what, allowed.join(", "))
                    })
            }
        }

        impl TryFrom<String> for $name {
            type Error = String;
            fn try_from(s: String) -> Result<Self, String> {
                s.parse()
            }
        }
    };
}

wire_enum!(
    /// Where one attempt of a test stands.
    TrialStatus, "trial status" {
        /// Waiting to be started.
        Scheduled = "scheduled",
        Running = "running",
        /// Ran to its end: it counts.
        Complete = "complete",
        /// Stopped by the experimenter or the E-stop.
        Aborted = "aborted",
        /// Stopped by a fault, a lost link or a restart, or filed so by the experimenter.
        Incomplete = "incomplete",
        /// Stopped because the subject could not see the display (hidden or stalled beyond
        /// the study's limits): never counts.
        Invalid = "invalid",
    }
);

wire_enum!(
    /// The subject's answer to the consent form.
    ConsentDecision, "consent decision" {
        Agreed = "agreed",
        Declined = "declined",
    }
);

wire_enum!(
    /// Which seats a station serves: on the machine, off it at the desk, or both (one
    /// computer for a simulated study).
    StationRole, "station role" {
        On = "on",
        Off = "off",
        Both = "both",
    }
);

wire_enum!(
    /// What a test of the schedule is for: the unscored warm-up, a scored test of a
    /// compensator, or an identification test (the cab moved by a multisine while the
    /// person holds the device, to measure their feedthrough; unscored, no survey).
    TestPhase, "test phase" {
        Practice = "practice",
        Test = "test",
        Identification = "identification",
    }
);

impl TestPhase {
    /// Whether the test is a measurement the comparison of compensators counts (and asks
    /// a survey about).
    pub fn scored(self) -> bool {
        self == Self::Test
    }
}

wire_enum!(
    /// Why a station has nothing more for its subject.
    DoneReason, "reason" {
        Withdrawn = "withdrawn",
        Declined = "declined",
        /// Every test is complete or accepted as incomplete by the experimenter.
        Finished = "finished",
    }
);

impl TrialStatus {
    /// Whether the attempt ended without counting: stopped, faulted or invalid (it is
    /// repeated unless the experimenter accepts it as incomplete).
    pub fn failed(self) -> bool {
        matches!(self, Self::Aborted | Self::Incomplete | Self::Invalid)
    }
}

impl StationRole {
    /// Whether a station of this role runs the tests of `seat`.
    pub fn serves(self, seat: crate::params::Seat) -> bool {
        use crate::params::Seat;
        matches!(
            (self, seat),
            (Self::Both, _) | (Self::On, Seat::On) | (Self::Off, Seat::Off)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Seat;

    #[test]
    fn names_round_trip_and_unknown_names_list_the_allowed_ones() {
        for s in TrialStatus::ALL {
            assert_eq!(s.as_str().parse::<TrialStatus>(), Ok(*s));
            assert_eq!(serde_json::to_string(s).unwrap(), format!("\"{s}\""));
        }
        assert_eq!(
            "done".parse::<TrialStatus>(),
            Err("unknown trial status \"done\"; allowed: scheduled, running, complete, aborted, incomplete, invalid".into())
        );
        assert_eq!(
            ConsentDecision::try_from("maybe".to_string()),
            Err("unknown consent decision \"maybe\"; allowed: agreed, declined".into())
        );
    }

    #[test]
    fn a_role_serves_its_seats_only() {
        assert!(StationRole::On.serves(Seat::On) && !StationRole::On.serves(Seat::Off));
        assert!(StationRole::Off.serves(Seat::Off) && !StationRole::Off.serves(Seat::On));
        assert!(StationRole::Both.serves(Seat::On) && StationRole::Both.serves(Seat::Off));
    }
}
