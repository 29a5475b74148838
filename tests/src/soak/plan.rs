//! The seeded schedule of a soak: a warm-up, the server restarts, the baseline quiet point,
//! then every other fault kind in a seeded order, repeated while the run lasts. The first
//! round holds every kind, so even the shortest run injects each at least once.

use std::time::Duration;

use bdft_controller::rng::Rng;

/// What the soak breaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FaultKind {
    /// The server killed (SIGKILL) or stopped (SIGTERM) during a test, and started again.
    ServerRestart,
    /// The database cannot grow (its page cap is filled) for a while, then has room again.
    DiskFull,
    /// Another client holds the store's write lock for 5–12 s (past the server's busy
    /// timeout at the long end), as a long erasure or backup would.
    StoreHeld,
    /// The controller process killed (SIGKILL).
    ControllerKill,
    /// The controller process frozen (SIGSTOP): hung.
    ControllerStop,
    /// A station's page reloaded during its test.
    StationReload,
    /// A station's network gone for a while: its socket closed without a close frame.
    StationOffline,
    /// A station's page hidden (another window in front) during its test.
    StationHidden,
    /// A station's page sending input as fast as it can.
    StationFlood,
    /// Another client address holding slow request bodies and idle connections.
    SlowClients,
}

impl FaultKind {
    pub const ALL: [Self; 10] = [
        Self::ServerRestart,
        Self::DiskFull,
        Self::StoreHeld,
        Self::ControllerKill,
        Self::ControllerStop,
        Self::StationReload,
        Self::StationOffline,
        Self::StationHidden,
        Self::StationFlood,
        Self::SlowClients,
    ];

    /// About how long injecting the fault and its recovery take (s): the plan leaves this
    /// much room for each.
    pub fn typical_s(self) -> f64 {
        match self {
            Self::ServerRestart | Self::DiskFull => 8.0,
            Self::StoreHeld => 10.0,
            Self::SlowClients => 14.0,
            Self::ControllerKill | Self::ControllerStop => 3.0,
            _ => 4.0,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::ServerRestart => "server-restart",
            Self::DiskFull => "disk-full",
            Self::StoreHeld => "store-held",
            Self::ControllerKill => "controller-kill",
            Self::ControllerStop => "controller-stop",
            Self::StationReload => "station-reload",
            Self::StationOffline => "station-offline",
            Self::StationHidden => "station-hidden",
            Self::StationFlood => "station-flood",
            Self::SlowClients => "slow-clients",
        }
    }
}

/// One fault to inject: its kind and a seeded number its choices come from (which station,
/// which signal, how long).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fault {
    pub kind: FaultKind,
    pub choice: u64,
}

/// A step of the schedule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    Fault(Fault),
    /// The quiet point whose memory and descriptors the end is compared with: after the last
    /// server restart, so that one server process lives through every later fault.
    Baseline,
}

/// A step and how long after the previous one ended it comes, at the earliest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Planned {
    pub gap: Duration,
    pub step: Step,
}

/// The schedule of a run of `length`.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Tests run without faults first.
    pub warmup: Duration,
    pub steps: Vec<Planned>,
    /// The first round: the steps that run whatever the run's length (every kind once).
    pub first_round: usize,
}

/// Mean time between faults once the first round is done (long runs).
const MEAN_GAP: Duration = Duration::from_secs(40);
/// Server restarts: one, and one more per hour of run (all before the baseline).
const RESTARTS_PER_HOUR: f64 = 1.0;

/// About how long the baseline quiet point takes (s): the tests running finish, the pages
/// close, the server closes their connections.
const BASELINE_S: f64 = 8.0;

/// The time the faults of `kinds` take, about (s).
fn typical(kinds: &[FaultKind]) -> f64 {
    kinds.iter().map(|k| k.typical_s()).sum()
}

/// The schedule of a run of `length` from `seed`.
pub fn plan(seed: u64, length: Duration) -> Plan {
    let mut rng = Rng::derive(seed, 0x5eed_f417);
    let secs = length.as_secs_f64();
    let warmup = Duration::from_secs_f64((0.12 * secs).clamp(15.0, 120.0));
    let restarts = 1 + (secs / 3600.0 * RESTARTS_PER_HOUR) as usize;
    let others: Vec<FaultKind> = FaultKind::ALL
        .into_iter()
        .filter(|k| *k != FaultKind::ServerRestart)
        .collect();
    // The fault window: from the warm-up to 15 s before the end (the tests left then finish).
    let window = (secs - warmup.as_secs_f64() - 15.0).max(0.0);
    let rounds = ((window / MEAN_GAP.as_secs_f64()) / others.len() as f64).floor() as usize;
    let rounds = rounds.max(1);
    let count = restarts + 1 + others.len() * rounds;
    let busy = restarts as f64 * FaultKind::ServerRestart.typical_s()
        + rounds as f64 * typical(&others)
        + BASELINE_S;
    let gap = (window - busy).max(count as f64) / count as f64;
    let jitter = |rng: &mut Rng| Duration::from_secs_f64(gap * rng.uniform(0.7, 1.3));
    let mut steps = Vec::with_capacity(count);
    for _ in 0..restarts {
        let choice = rng.next_u64();
        steps.push(Planned {
            gap: jitter(&mut rng),
            step: Step::Fault(Fault {
                kind: FaultKind::ServerRestart,
                choice,
            }),
        });
    }
    steps.push(Planned {
        gap: jitter(&mut rng),
        step: Step::Baseline,
    });
    for _ in 0..rounds {
        let mut round = others.clone();
        // Fisher–Yates from the seed.
        for i in (1..round.len()).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            round.swap(i, j);
        }
        for kind in round {
            let choice = rng.next_u64();
            steps.push(Planned {
                gap: jitter(&mut rng),
                step: Step::Fault(Fault { kind, choice }),
            });
        }
    }
    Plan {
        warmup,
        steps,
        first_round: restarts + 1 + others.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinds(p: &Plan) -> Vec<FaultKind> {
        p.steps
            .iter()
            .filter_map(|s| match s.step {
                Step::Fault(f) => Some(f.kind),
                Step::Baseline => None,
            })
            .collect()
    }

    #[test]
    fn a_two_minute_plan_holds_every_kind_once_and_restarts_before_the_baseline() {
        let p = plan(1, Duration::from_secs(120));
        let mut k = kinds(&p);
        k.sort();
        assert_eq!(k, FaultKind::ALL.to_vec());
        let baseline = p
            .steps
            .iter()
            .position(|s| s.step == Step::Baseline)
            .unwrap();
        assert!(p.steps[..baseline].iter().all(|s| matches!(
            s.step,
            Step::Fault(Fault {
                kind: FaultKind::ServerRestart,
                ..
            })
        )));
        // The gaps leave room for the faults themselves within the fault window.
        let gaps: f64 = p.steps.iter().map(|s| s.gap.as_secs_f64()).sum();
        assert!(gaps < 1.3 * (120.0 - 15.0 - 15.0 - typical(&k)), "{gaps}");
    }

    #[test]
    fn a_long_plan_repeats_the_faults_and_is_a_function_of_its_seed() {
        let p = plan(7, Duration::from_secs(2 * 3600));
        let k = kinds(&p);
        assert_eq!(
            k.iter().filter(|k| **k == FaultKind::ServerRestart).count(),
            3
        );
        for kind in FaultKind::ALL {
            assert!(k.iter().filter(|k| **k == kind).count() >= 2, "{kind:?}");
        }
        assert_eq!(p, plan(7, Duration::from_secs(2 * 3600)));
        assert_ne!(p, plan(8, Duration::from_secs(2 * 3600)));
    }
}
