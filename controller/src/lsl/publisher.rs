//! The thread that sends the loop's rows to the stations' signal streams, and the streams
//! themselves: published (or re-published when the station's subject or study changes) by
//! the I/O side when the server names a station, each trial routed to its station's stream.
//! The loop is not involved: it only fills the ring ([`super::tap`]). This thread and the
//! I/O side share the station table behind a mutex, which the loop never touches.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use bdft_protocol::trial::TrialId;
use labstream_net::Outlet;
use labstream_wire::{Sample, Value};

use super::streams::{StreamTags, lsl_seconds, signal_stream};
use super::tap::TapReader;

/// Trials remembered per process: routes of trials long ended are forgotten oldest first
/// (a trial's last rows are sent within milliseconds of its end).
const ROUTES_KEPT: usize = 256;

/// How long the thread sleeps when the ring is empty: a millisecond, one tick's worth.
const IDLE: Duration = Duration::from_millis(1);

struct Station {
    tags: StreamTags,
    outlet: Outlet,
}

#[derive(Default)]
struct Table {
    stations: HashMap<i64, Station>,
    /// Which station's stream each trial goes to, oldest first. A trial no station named
    /// (a workbench bench run) is not streamed.
    routes: VecDeque<(TrialId, i64)>,
}

impl Table {
    fn outlet_of(&self, trial: TrialId) -> Option<&Outlet> {
        let (_, station) = self.routes.iter().rev().find(|(t, _)| *t == trial)?;
        self.stations.get(station).map(|s| &s.outlet)
    }
}

/// The running publisher: its thread stops when this is dropped.
pub struct Publisher {
    table: Arc<Mutex<Table>>,
    stop: Arc<AtomicBool>,
    dropped: Arc<std::sync::atomic::AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Publisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publisher")
            .field("dropped", &self.dropped())
            .finish_non_exhaustive()
    }
}

fn lock(table: &Mutex<Table>) -> MutexGuard<'_, Table> {
    table.lock().unwrap_or_else(|p| p.into_inner())
}

impl Publisher {
    /// Starts the thread reading `reader`.
    pub fn start(reader: TapReader) -> std::io::Result<Publisher> {
        let table = Arc::new(Mutex::new(Table::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let dropped = Arc::clone(&reader.dropped);
        let thread = std::thread::Builder::new().name("bdft-lsl".into()).spawn({
            let (table, stop) = (Arc::clone(&table), Arc::clone(&stop));
            move || send_rows(reader, &table, &stop)
        })?;
        Ok(Publisher {
            table,
            stop,
            dropped,
            thread: Some(thread),
        })
    }

    /// Publishes the station's signal stream described by `tags`, replacing the one it had
    /// when the subject or study changed (same source id, so a recorder finds it again);
    /// an unchanged station keeps its stream and its readers.
    pub fn station(&self, tags: StreamTags) -> std::io::Result<()> {
        let mut t = lock(&self.table);
        if t.stations
            .get(&tags.station_id)
            .is_some_and(|s| s.tags == tags)
        {
            return Ok(());
        }
        let outlet = Outlet::new(signal_stream(&tags))?;
        tracing::info!(station = %tags.station, subject = %tags.subject, "LSL signal stream published");
        t.stations.insert(tags.station_id, Station { tags, outlet });
        Ok(())
    }

    /// Sends `trial`'s rows to `station`'s stream.
    pub fn route(&self, trial: TrialId, station: i64) {
        let mut t = lock(&self.table);
        if t.routes.len() == ROUTES_KEPT {
            t.routes.pop_front();
        }
        t.routes.push_back((trial, station));
    }

    /// Rows the loop dropped because this thread fell behind.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

impl Drop for Publisher {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn send_rows(mut reader: TapReader, table: &Mutex<Table>, stop: &AtomicBool) {
    let mut last_dropped = 0;
    while !stop.load(Ordering::Relaxed) {
        if reader.ring.is_empty() {
            std::thread::sleep(IDLE);
            continue;
        }
        let t = lock(table);
        while let Ok(row) = reader.ring.pop() {
            if let Some(outlet) = t.outlet_of(row.trial_id) {
                outlet.push(&Sample {
                    timestamp: lsl_seconds(row.stamp_ns),
                    values: row.values.iter().map(|&v| Value::F32(v)).collect(),
                });
            }
        }
        drop(t);
        let dropped = reader.dropped();
        if dropped != last_dropped {
            tracing::warn!(
                dropped,
                "the LSL publisher fell behind the loop: rows dropped"
            );
            last_dropped = dropped;
        }
    }
}
