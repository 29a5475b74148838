//! The stations' LSL streams as the protocol drives them (`serve --lsl`): each station's
//! marker stream, published here in the server — which knows the protocol's events — and
//! its 1 kHz signal stream, published by the controller (whose loop has the samples) when
//! told who is at the station (`ServerToController::LslStation`). Both are (re)published
//! when a subject is assigned to a station, whenever its site's controller link comes up
//! (a new controller holds none) and checked before each of its tests, so a reader can
//! connect before the first sample.
//!
//! The streams belong to the process, as LSL's configuration does (read once, before the
//! first stream): they are on when [`enable`] was called at start, and every function here
//! returns at once otherwise — no LSL socket is opened without `--lsl`.

use std::collections::HashMap;
use std::sync::{Mutex, OnceLock};

use bdft_controller::lsl::streams::{Scope, StreamTags, marker_stream};
use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::params::Seat;
use bdft_protocol::records::TestPhase;
use bdft_protocol::server_to_controller::{LslStation, ServerToController};
use bdft_protocol::trial::{FaultKind, Outcome};
use labstream_net::Outlet;
use labstream_wire::{Sample, Value};
use serde::Serialize;
use sqlx::AnyPool;
use tokio::sync::broadcast::error::RecvError;

use crate::engine::machine::controller_link::{ControllerEvent, ControllerLink};
use crate::engine::machine::sites::Sites;
use crate::error::Result;
use crate::store;
use crate::store::trials::Trial;

/// One event on a station's marker stream, sent as a JSON string.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Marker<'a> {
    /// A test started on the machine or at the desk: its trial (attempt), phase and the
    /// label the subject sees (never the compensator).
    TestStart {
        trial_id: i64,
        phase: TestPhase,
        seat: Seat,
        block: i64,
        attempt: i64,
        label: &'a str,
    },
    /// A test ended and was filed.
    TestEnd {
        trial_id: i64,
        status: &'a str,
        #[serde(skip_serializing_if = "Option::is_none")]
        reason: Option<&'a str>,
    },
    /// The subject answered the test's survey.
    Survey { trial_id: i64 },
    /// The experimenter queued the test again as `new_trial_id`.
    Redo { trial_id: i64, new_trial_id: i64 },
    /// The E-stop was pressed (every station's stream carries it).
    EStop {},
    /// The cab-vibration interlock stopped the test.
    Interlock { trial_id: i64 },
}

struct Markers {
    stations: Mutex<HashMap<i64, (StreamTags, Outlet)>>,
}

static MARKERS: OnceLock<Markers> = OnceLock::new();

/// Turns the streams on for this process, discoverable within `scope`.
pub fn enable(scope: Scope) {
    scope.configure();
    let _ = MARKERS.set(Markers {
        stations: Mutex::new(HashMap::new()),
    });
}

/// Whether `--lsl` is on.
fn enabled() -> bool {
    MARKERS.get().is_some()
}

fn markers() -> Option<&'static Markers> {
    MARKERS.get()
}

impl Markers {
    fn stations(&self) -> std::sync::MutexGuard<'_, HashMap<i64, (StreamTags, Outlet)>> {
        self.stations.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Publishes the station's marker stream, replacing it when its tags changed.
    fn publish(&self, tags: &StreamTags) {
        let mut stations = self.stations();
        if stations
            .get(&tags.station_id)
            .is_some_and(|(t, _)| t == tags)
        {
            return;
        }
        match Outlet::new(marker_stream(tags)) {
            Ok(outlet) => {
                stations.insert(tags.station_id, (tags.clone(), outlet));
            }
            Err(e) => {
                tracing::warn!(station = %tags.station, "the LSL marker stream could not be published: {e}")
            }
        }
    }

    fn push(&self, station: Option<i64>, marker: &Marker) {
        let text = match serde_json::to_string(marker) {
            Ok(t) => t,
            Err(e) => return tracing::warn!("an LSL marker could not be written: {e}"),
        };
        let sample = Sample {
            timestamp: labstream_net::clock(),
            values: vec![Value::Str(text.into_bytes())],
        };
        for (id, (_, outlet)) in self.stations().iter() {
            if station.is_none_or(|s| s == *id) {
                outlet.push(&sample);
            }
        }
    }
}

/// The tags of station `station_id` with the subject now assigned to it; None without one.
async fn tags_of(pool: &AnyPool, station_id: i64) -> Result<Option<StreamTags>> {
    let station = store::stations::get(pool, station_id).await?;
    let Some(subject_id) = station.subject_id else {
        return Ok(None);
    };
    let subject = store::subjects::get(pool, subject_id).await?;
    let study = store::studies::get(pool, station.study_id).await?;
    Ok(Some(StreamTags {
        station_id: station.id,
        station: station.name,
        study_id: study.id,
        study: study.name,
        subject: subject.code,
    }))
}

/// Publishes station `station_id`'s streams (markers here, signals on the controller) for
/// the subject assigned to it, and names `trial` as the one about to start there.
async fn publish(
    pool: &AnyPool,
    link: &ControllerLink,
    station_id: i64,
    trial: Option<i64>,
) -> Result<()> {
    let Some(m) = markers() else { return Ok(()) };
    let Some(tags) = tags_of(pool, station_id).await? else {
        return Ok(());
    };
    m.publish(&tags);
    let msg = ServerToController::LslStation(Box::new(LslStation {
        station_id: tags.station_id,
        station: tags.station,
        study_id: tags.study_id,
        study: tags.study,
        subject: tags.subject,
        trial_id: trial.map(|t| t as u64),
    }));
    if let Err(e) = link.send(&msg) {
        // The test itself does not depend on its stream: it runs, unstreamed.
        tracing::warn!(
            station_id,
            "the controller was not told of the LSL stream: {e}"
        );
    }
    Ok(())
}

/// A subject was assigned to the station (or unassigned: then nothing changes); its
/// streams come from its site's controller.
pub async fn station_assigned(pool: &AnyPool, sites: &Sites, station_id: i64) {
    if !enabled() {
        return;
    }
    let station = match store::stations::get(pool, station_id).await {
        Ok(s) => s,
        Err(e) => return logged(Err(e)),
    };
    if let Some(link) = sites.stored(station.site.as_deref()) {
        logged(publish(pool, link, station_id, None).await);
    }
}

/// Tells a site's controller again of its stations' streams whenever its link comes up. A
/// controller that started, restarted or reconnected after a subject was assigned (a link
/// dropped for a moment on a loaded machine) holds none of their signal streams, and a
/// reader that connected at the assignment would wait for them until the next test. Runs
/// for the server's life (`serve --lsl`).
pub async fn republish_on_reconnect(pool: AnyPool, sites: Sites) {
    if !enabled() {
        return;
    }
    let mut events = sites.subscribe();
    loop {
        let up: Vec<&ControllerLink> = match events.recv().await {
            Ok(ControllerEvent::Link {
                site,
                connected: true,
            }) => sites.all().iter().filter(|l| l.site() == &*site).collect(),
            // Missed events may have held a link coming up: every connected site, again
            // (publishing is idempotent).
            Err(RecvError::Lagged(_)) => sites.all().iter().filter(|l| l.is_connected()).collect(),
            Ok(_) => continue,
            Err(RecvError::Closed) => return,
        };
        let stations = match store::stations::assigned(&pool).await {
            Ok(s) => s,
            Err(e) => {
                logged(Err(e));
                continue;
            }
        };
        for link in up {
            for station in &stations {
                if sites
                    .stored(station.site.as_deref())
                    .is_some_and(|l| l.site() == link.site())
                {
                    logged(publish(&pool, link, station.id, None).await);
                }
            }
        }
    }
}

/// The streams never hold up the protocol: what they could not say is logged.
fn logged(r: Result<()>) {
    if let Err(e) = r {
        tracing::warn!("LSL: {e}");
    }
}

/// The station `trial` runs at: its subject's station that serves its seat.
async fn station_of(pool: &AnyPool, trial: &Trial) -> Result<Option<i64>> {
    let stations = store::stations::of_subject(pool, trial.subject_id).await?;
    Ok(stations
        .iter()
        .find(|s| s.role.serves(trial.seat))
        .map(|s| s.id))
}

/// Before `trial` starts: its station's streams are up and its ticks go to them. Sent
/// before the start on the same link, so the controller routes the trial before its first
/// tick.
pub async fn trial_starting(pool: &AnyPool, link: &ControllerLink, trial: &Trial) {
    if !enabled() {
        return;
    }
    logged(match station_of(pool, trial).await {
        Ok(Some(station)) => publish(pool, link, station, Some(trial.id)).await,
        Ok(None) => Ok(()),
        Err(e) => Err(e),
    });
}

/// Puts `marker` on the stream of the station `trial` runs at.
pub async fn mark_trial(pool: &AnyPool, trial_id: i64, marker: Marker<'_>) {
    logged(try_mark_trial(pool, trial_id, marker).await);
}

async fn try_mark_trial(pool: &AnyPool, trial_id: i64, marker: Marker<'_>) -> Result<()> {
    let Some(m) = markers() else { return Ok(()) };
    let trial = store::trials::get(pool, trial_id).await?;
    if let Some(station) = station_of(pool, &trial).await? {
        m.push(Some(station), &marker);
    }
    Ok(())
}

/// The test-start marker of `trial`.
pub async fn test_started(pool: &AnyPool, trial: &Trial) {
    let marker = Marker::TestStart {
        trial_id: trial.id,
        phase: trial.phase,
        seat: trial.seat,
        block: trial.block,
        attempt: trial.attempt,
        label: &trial.blinded_label,
    };
    mark_trial(pool, trial.id, marker).await
}

/// The markers of a filed result: the interlock when it stopped the test, then the end.
pub async fn test_filed(pool: &AnyPool, result: &TrialResult, status: &str) {
    if !enabled() {
        return;
    }
    for marker in markers_of_result(result, status) {
        mark_trial(pool, result.trial_id as i64, marker).await;
    }
}

/// What a filed result puts on its station's stream, in order.
fn markers_of_result<'a>(result: &'a TrialResult, status: &'a str) -> Vec<Marker<'a>> {
    let trial_id = result.trial_id as i64;
    let mut out = Vec::with_capacity(2);
    let reason = match &result.outcome {
        Outcome::Complete => None,
        Outcome::Aborted { reason } => Some(reason.as_str()),
        Outcome::Faulted { fault, message } => {
            if *fault == FaultKind::CabVibration {
                out.push(Marker::Interlock { trial_id });
            }
            Some(message.as_str())
        }
    };
    out.push(Marker::TestEnd {
        trial_id,
        status,
        reason,
    });
    out
}

/// The E-stop, on every station's stream.
pub fn estop() {
    if let Some(m) = markers() {
        m.push(None, &Marker::EStop {});
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(outcome: Outcome) -> TrialResult {
        TrialResult {
            trial_id: 12,
            outcome,
            metrics: bdft_protocol::trial::Metrics {
                ticks: 0,
                mse_tracking_mm2: 0.0,
                ms_cab_accel: 0.0,
            },
            timing: Default::default(),
            dt: 1e-3,
            record_chunks: 0,
            exposure: None,
            cancellation_off_at_s: None,
            adaptation: None,
        }
    }

    fn texts(result: &TrialResult, status: &str) -> Vec<String> {
        markers_of_result(result, status)
            .iter()
            .map(|m| serde_json::to_string(m).unwrap())
            .collect()
    }

    #[test]
    fn the_interlock_is_marked_before_the_end_of_the_test_it_stopped() {
        let tripped = result(Outcome::Faulted {
            fault: FaultKind::CabVibration,
            message: "cab vibration 7.1 m/s² RMS".into(),
        });
        assert_eq!(
            texts(&tripped, "incomplete"),
            [
                r#"{"event":"interlock","trial_id":12}"#,
                r#"{"event":"test_end","trial_id":12,"status":"incomplete","reason":"cab vibration 7.1 m/s² RMS"}"#,
            ]
        );
        let stale = result(Outcome::Faulted {
            fault: FaultKind::StaleInput,
            message: "no input".into(),
        });
        assert_eq!(
            texts(&stale, "incomplete").len(),
            1,
            "only the interlock adds one"
        );
        assert_eq!(
            texts(&result(Outcome::Complete), "complete"),
            [r#"{"event":"test_end","trial_id":12,"status":"complete"}"#]
        );
    }
}
