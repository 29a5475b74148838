//! The loop's hand-over of every tick's signals to the LSL publisher: a bounded SPSC ring
//! (rtrb) of plain rows, written by the loop, read by the publisher's thread. A full ring
//! (a publisher that fell behind) drops the row and counts it; the loop never waits,
//! allocates or locks here.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use bdft_protocol::trial::TrialId;
use rtrb::{Consumer, Producer, RingBuffer};

use super::streams::{SIGNAL_CHANNELS, signal_columns};
use crate::runtime::slot::RecordRow;

/// One tick of one trial, as the stream carries it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TapRow {
    pub trial_id: TrialId,
    /// The tick's wake-up time on CLOCK_MONOTONIC (ns).
    pub stamp_ns: u64,
    pub values: [f32; SIGNAL_CHANNELS.len()],
}

/// Rows the ring holds: two seconds of 16 trials at once.
pub const CAPACITY: usize = 1 << 15;

/// The loop's end.
#[derive(Debug)]
pub struct SampleTap {
    ring: Producer<TapRow>,
    columns: [usize; SIGNAL_CHANNELS.len()],
    dropped: Arc<AtomicU64>,
}

/// The publisher's end.
#[derive(Debug)]
pub struct TapReader {
    pub(crate) ring: Consumer<TapRow>,
    pub(super) dropped: Arc<AtomicU64>,
}

/// A ring of `capacity` rows, every page of it touched now (so that without locked memory
/// the loop takes no page fault on fresh pages).
pub fn tap(capacity: usize) -> (SampleTap, TapReader) {
    let (mut tx, mut rx) = RingBuffer::new(capacity);
    let blank = TapRow {
        trial_id: 0,
        stamp_ns: 0,
        values: [0.0; SIGNAL_CHANNELS.len()],
    };
    while tx.push(blank).is_ok() {}
    while rx.pop().is_ok() {}
    let dropped = Arc::new(AtomicU64::new(0));
    (
        SampleTap {
            ring: tx,
            columns: signal_columns(),
            dropped: Arc::clone(&dropped),
        },
        TapReader { ring: rx, dropped },
    )
}

impl SampleTap {
    /// Offers a tick's record row; dropped and counted when the ring is full.
    #[inline]
    pub fn offer(&mut self, trial_id: TrialId, stamp_ns: u64, row: &RecordRow) {
        let row = TapRow {
            trial_id,
            stamp_ns,
            values: self.columns.map(|c| row[c]),
        };
        if self.ring.push(row).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl TapReader {
    /// Rows dropped so far because the ring was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::alloc_check::allocations_during;

    #[test]
    fn a_full_ring_drops_and_counts_without_allocating() {
        let (mut tap, mut reader) = tap(4);
        let mut row: RecordRow = [0.0; bdft_protocol::trial::RECORD_CHANNELS.len()];
        let n = allocations_during(|| {
            for k in 0..10u64 {
                row[0] = k as f32;
                tap.offer(7, k, &row);
            }
        });
        assert_eq!(n, 0);
        assert_eq!(reader.dropped(), 6, "4 rows kept, 6 dropped");
        let kept: Vec<u64> = std::iter::from_fn(|| reader.ring.pop().ok())
            .map(|r| r.stamp_ns)
            .collect();
        assert_eq!(kept, [0, 1, 2, 3], "the oldest rows are kept, in order");
    }
}
