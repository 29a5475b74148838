//! A stored test run again (`bdft-server replay --trial ID`, issue 38): the study's start
//! message for it rebuilt from its trial row, run through the controller's own slot code on
//! the simulated rig — a synthetic subject's from its operator's seed, a person's tick by
//! tick from the recorded hand — and the record compared with the stored one bit for bit.
//! With it, the offline bound: the test's device reading cancelled after the fact with a
//! model (the test's own, or the subject's identified body), its power in 0.5–5 Hz before
//! and after, an upper bound on what cancellation can do online.

use bdft_controller::cancellation::offline::{BAND_HZ, BandPower, band_power, offline_bound};
use bdft_protocol::cancellation::CancellationModel;
use bdft_protocol::params::Seat;
use bdft_protocol::study::RigKind;
use bdft_protocol::trial::{RECORD_CHANNELS, record_channel};
use serde::Serialize;
use sqlx::AnyPool;

use crate::engine::procedure::orchestrator::{Operator, start_message};
use crate::error::{AppError, Result};
use crate::store;

/// One record channel of the replay against the stored one.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelCheck {
    pub name: &'static str,
    /// Every sample equal, bit for bit.
    pub identical: bool,
    /// The first tick whose samples differ (none when identical).
    pub first_difference_tick: Option<usize>,
}

/// The offline bound of an uncancelled test on the machine: its record cancelled after the
/// fact with the subject's identified body.
#[derive(Debug, Clone, Serialize)]
pub struct Offline {
    pub band_hz: (f64, f64),
    /// The device reading's mean square in the band before and after (mm²). It holds the
    /// person's own input too, so cancelling can raise it: the cab follows their commands.
    pub device: BandPower,
    /// The feedthrough in the device reading before, and what the model leaves of it.
    pub feedthrough: BandPower,
    /// The share of the feedthrough removed.
    pub removed_share: f64,
    /// When the model's guard turned it off (s), if it did.
    pub off_at_s: Option<f64>,
    pub note: &'static str,
}

/// What a replay found.
#[derive(Debug, Clone, Serialize)]
pub struct Replayed {
    pub trial_id: i64,
    /// "synthetic" (from the operator's seed) or "person" (from the recorded hand).
    pub input: &'static str,
    pub ticks_stored: usize,
    pub ticks_replayed: usize,
    /// Every channel identical over every stored tick, and as many ticks.
    pub identical: bool,
    pub channels: Vec<ChannelCheck>,
    /// An uncancelled test on the machine: the offline bound.
    pub offline: Option<Offline>,
    /// A cancelled test: the feedthrough in its device reading, and what was left of it in
    /// the cancelled signal as it ran (the record's `feedthrough_mm`, `cancellation_mm`).
    pub online: Option<BandPower>,
    /// Why there is neither, when there is neither.
    pub why_no_bound: Option<String>,
}

const UPPER_BOUND: &str = "an upper bound: offline the cab moves as it did; online the cancelled \
                           input changes the commands, and with them the cab's motion";

/// Replays `trial_id` and computes its offline bound.
pub async fn replay(pool: &AnyPool, trial_id: i64) -> Result<Replayed> {
    let trial = store::trials::get(pool, trial_id).await?;
    let subject = store::subjects::get(pool, trial.subject_id).await?;
    let study = store::studies::get(pool, subject.study_id).await?;
    if study.params.rig == RigKind::Real {
        return Err(AppError::Conflict(format!(
            "trial {trial_id} ran on the real machine, whose motion a replay cannot simulate: \
             only a test on the simulated rig replays"
        )));
    }
    if store::exports::recorded_trials(pool, study.id, None, Some(trial_id))
        .await?
        .is_empty()
    {
        return Err(AppError::Conflict(format!(
            "trial {trial_id} has no record (status {}): nothing to replay",
            trial.status.as_str()
        )));
    }
    let record = store::records::get(pool, trial_id).await?;
    let operator = if subject.synthetic {
        Operator::Synthetic(subject.drawn)
    } else {
        Operator::Person
    };
    let start = start_message(&study, &trial, operator)?;
    let cancelled = trial.cancellation_json.is_some();
    let body = store::identifications::latest_fit(pool, subject.id)
        .await?
        .and_then(|fit| fit.identified_body().ok())
        .and_then(|body| CancellationModel::of_seated(&body));
    let why_no_bound = if trial.seat == Seat::Off {
        Some("at the desk no body rides: nothing to cancel".to_string())
    } else if !cancelled && body.is_none() {
        Some("the subject has no identified body to cancel with".to_string())
    } else {
        None
    };
    let channel = |name| record.channels[record_channel(name).expect("a record channel")].clone();
    let (device, cab, feedthrough, done) = (
        channel("device_mm"),
        channel("cab_accel_mm_s2"),
        channel("feedthrough_mm"),
        channel("cancellation_mm"),
    );
    let stored = record.channels.clone();
    let dt = record.dt;
    let synthetic = subject.synthetic;
    tokio::task::spawn_blocking(move || {
        use bdft_controller::runtime::local;
        let run = if synthetic {
            local::run(&start, dt)
        } else {
            local::replay(
                &start,
                dt,
                &stored[record_channel("hand_mm").expect("a record channel")],
                &stored[record_channel("tick_latency_us").expect("a record channel")],
            )
        };
        let (_, replayed) =
            run.map_err(|e| AppError::Conflict(format!("trial {trial_id}: {e}")))?;
        let ticks_stored = stored[0].len();
        let ticks_replayed = replayed[0].len();
        let channels: Vec<ChannelCheck> = RECORD_CHANNELS
            .iter()
            .zip(stored.iter().zip(&replayed))
            .map(|(c, (a, b))| {
                let first = (0..ticks_stored)
                    .find(|&k| b.get(k).is_none_or(|v| v.to_bits() != a[k].to_bits()));
                ChannelCheck {
                    name: c.name,
                    identical: first.is_none(),
                    first_difference_tick: first,
                }
            })
            .collect();
        let ft: Vec<f64> = feedthrough.iter().map(|v| -f64::from(*v)).collect();
        let band = |x: &[f64]| band_power(x, dt, BAND_HZ.0, BAND_HZ.1);
        let online = (why_no_bound.is_none() && cancelled).then(|| {
            let left: Vec<f64> = ft
                .iter()
                .zip(&done)
                .map(|(f, c)| f - f64::from(*c))
                .collect();
            BandPower {
                before_mm2: band(&ft),
                after_mm2: band(&left),
            }
        });
        let offline = match body.filter(|_| why_no_bound.is_none() && !cancelled) {
            None => None,
            Some(model) => {
                let b = offline_bound(&model, dt, &device, &cab, &feedthrough).map_err(|e| {
                    AppError::Conflict(format!("the subject's model does not run: {e}"))
                })?;
                Some(Offline {
                    band_hz: BAND_HZ,
                    device: b.device,
                    feedthrough: b.feedthrough,
                    removed_share: b.feedthrough.removed(),
                    off_at_s: b.off_at_s,
                    note: UPPER_BOUND,
                })
            }
        };
        Ok(Replayed {
            trial_id,
            input: if synthetic { "synthetic" } else { "person" },
            ticks_stored,
            ticks_replayed,
            identical: ticks_replayed == ticks_stored && channels.iter().all(|c| c.identical),
            channels,
            offline,
            online,
            why_no_bound,
        })
    })
    .await
    .map_err(|e| AppError::Internal(anyhow::anyhow!("replay task: {e}")))?
}
