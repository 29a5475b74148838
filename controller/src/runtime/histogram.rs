//! Allocation-free latency histogram for the real-time loop.
//!
//! Log-linear buckets with about 1 % resolution from 10 ns to 10 s: each power-of-two range
//! of nanoseconds is split into 64 linear sub-buckets (as HdrHistogram does), so recording is
//! a few integer operations on a fixed array.

use bdft_protocol::trial::Percentiles;

const SUB_BITS: u32 = 6;
const SUB: usize = 1 << SUB_BITS;
/// Covers values below 2^(RANGES + SUB_BITS − 1) ns ≈ 34 s.
const RANGES: usize = 30;
const BUCKETS: usize = RANGES * SUB;

#[derive(Clone)]
pub struct Histogram {
    counts: [u64; BUCKETS],
    total: u64,
    max_ns: u64,
}

impl std::fmt::Debug for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Histogram")
            .field("total", &self.total)
            .field("max_ns", &self.max_ns)
            .finish()
    }
}

impl Default for Histogram {
    fn default() -> Self {
        Self {
            counts: [0; BUCKETS],
            total: 0,
            max_ns: 0,
        }
    }
}

fn index(ns: u64) -> usize {
    if ns < SUB as u64 {
        return ns as usize;
    }
    let range = (63 - ns.leading_zeros()) - SUB_BITS + 1; // ≥ 1
    let sub = (ns >> (range - 1)) as usize - SUB; // top SUB_BITS+1 bits, less the leading one
    ((range as usize) * SUB + sub).min(BUCKETS - 1)
}

/// Upper edge (ns) of a bucket.
fn upper(i: usize) -> u64 {
    let (range, sub) = (i / SUB, (i % SUB) as u64);
    if range == 0 {
        sub + 1
    } else {
        (SUB as u64 + sub + 1) << (range - 1)
    }
}

impl Histogram {
    #[inline]
    pub fn record(&mut self, ns: u64) {
        self.counts[index(ns)] += 1;
        self.total += 1;
        self.max_ns = self.max_ns.max(ns);
    }

    pub fn count(&self) -> u64 {
        self.total
    }

    /// Value (ns) below which a fraction `q` of the recorded values lie (bucket upper edge,
    /// so never an underestimate; clamped to the exact maximum).
    pub fn quantile_ns(&self, q: f64) -> u64 {
        if self.total == 0 {
            return 0;
        }
        let rank = ((q * self.total as f64).ceil() as u64).clamp(1, self.total);
        let mut seen = 0;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return upper(i).min(self.max_ns);
            }
        }
        self.max_ns
    }

    pub fn percentiles_us(&self) -> Percentiles {
        Percentiles {
            p50: self.quantile_ns(0.5) as f64 / 1e3,
            p99: self.quantile_ns(0.99) as f64 / 1e3,
            max: self.max_ns as f64 / 1e3,
        }
    }

    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.counts.iter_mut().zip(other.counts.iter()) {
            *a += b;
        }
        self.total += other.total;
        self.max_ns = self.max_ns.max(other.max_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_are_contiguous_and_within_two_percent() {
        let mut prev = 0;
        for i in 0..BUCKETS - 1 {
            let u = upper(i);
            assert!(u > prev, "bucket {i}");
            prev = u;
        }
        for ns in [
            0u64,
            1,
            63,
            64,
            65,
            127,
            128,
            1_000,
            12_345,
            999_999,
            5_000_000_000,
        ] {
            let i = index(ns);
            assert!(
                upper(i) > ns,
                "{ns} above its bucket's upper edge {}",
                upper(i)
            );
            let lower = if i == 0 { 0 } else { upper(i - 1) };
            assert!(lower <= ns, "{ns} below its bucket {i}");
            assert!(
                (upper(i) - lower) as f64 <= 0.02 * ns.max(64) as f64 + 1.0,
                "{ns}"
            );
        }
    }

    #[test]
    fn quantiles_of_a_uniform_sample() {
        let mut h = Histogram::default();
        for ns in 1..=100_000u64 {
            h.record(ns);
        }
        let p50 = h.quantile_ns(0.5) as f64;
        let p99 = h.quantile_ns(0.99) as f64;
        assert!((p50 / 50_000.0 - 1.0).abs() < 0.02, "{p50}");
        assert!((p99 / 99_000.0 - 1.0).abs() < 0.02, "{p99}");
        assert_eq!(h.quantile_ns(1.0), 100_000);
        assert_eq!(h.percentiles_us().max, 100.0);
        let mut g = Histogram::default();
        g.record(1_000_000);
        h.merge(&g);
        assert_eq!(h.count(), 100_001);
        assert_eq!(h.percentiles_us().max, 1000.0);
    }
}
