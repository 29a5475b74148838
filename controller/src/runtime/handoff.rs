//! Latest-value handoff of operator input from the I/O side to the real-time tick.
//!
//! A seqlock: the single writer bumps the sequence to odd, stores, bumps it to even; the
//! reader retries while it sees an odd or changed sequence. The reader never waits on the
//! writer (at worst it retries a few times, then keeps its previous value), and nothing
//! allocates or locks.

use std::sync::atomic::{AtomicU64, Ordering, fence};

/// One operator-input sample as the tick sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputSample {
    pub position_mm: f64,
    /// Sender's sequence number (echoed in live samples).
    pub seq: u64,
    /// Loop tick at which it arrived.
    pub arrival_tick: u64,
}

#[derive(Debug, Default)]
pub struct InputCell {
    version: AtomicU64,
    position_bits: AtomicU64,
    seq: AtomicU64,
    /// Tick of arrival + 1; 0 means nothing has arrived yet.
    arrival: AtomicU64,
}

impl InputCell {
    /// Publishes a sample. Only one thread may write a given cell.
    pub fn write(&self, s: InputSample) {
        let v = self.version.load(Ordering::Relaxed);
        self.version.store(v.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        self.position_bits
            .store(s.position_mm.to_bits(), Ordering::Relaxed);
        self.seq.store(s.seq, Ordering::Relaxed);
        self.arrival.store(s.arrival_tick + 1, Ordering::Relaxed);
        self.version.store(v.wrapping_add(2), Ordering::Release);
    }

    /// The newest sample, `None` if none has arrived (or the writer kept it busy for every
    /// retry, which a single short store cannot).
    #[inline]
    pub fn read(&self) -> Option<InputSample> {
        for _ in 0..8 {
            let v1 = self.version.load(Ordering::Acquire);
            if v1 % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let bits = self.position_bits.load(Ordering::Relaxed);
            let seq = self.seq.load(Ordering::Relaxed);
            let arrival = self.arrival.load(Ordering::Relaxed);
            fence(Ordering::Acquire);
            if self.version.load(Ordering::Relaxed) == v1 {
                return (arrival > 0).then(|| InputSample {
                    position_mm: f64::from_bits(bits),
                    seq,
                    arrival_tick: arrival - 1,
                });
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn reader_never_sees_a_torn_sample() {
        let cell = Arc::new(InputCell::default());
        assert_eq!(cell.read(), None);
        let w = Arc::clone(&cell);
        let writer = std::thread::spawn(move || {
            for i in 0..200_000u64 {
                // Position, seq and tick always agree, so a torn read is detectable.
                w.write(InputSample {
                    position_mm: i as f64,
                    seq: i,
                    arrival_tick: 2 * i,
                });
            }
        });
        let mut last = 0;
        while !writer.is_finished() {
            if let Some(s) = cell.read() {
                assert_eq!(s.position_mm, s.seq as f64);
                assert_eq!(s.arrival_tick, 2 * s.seq);
                assert!(s.seq >= last, "went backwards");
                last = s.seq;
            }
        }
        writer.join().unwrap();
        assert_eq!(cell.read().unwrap().seq, 199_999);
    }
}
