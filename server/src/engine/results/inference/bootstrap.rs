//! Percentile bootstrap interval of the median of paired differences: resample the
//! subjects' differences with replacement, seeded, so the same data and seed always give
//! the same interval.

use bdft_controller::rng::Rng;

use super::quantile::{median, quantile};

/// A median and its bootstrap interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    pub median: f64,
    pub low: f64,
    pub high: f64,
}

/// The `level` (e.g. 0.95) percentile interval of the median of `diffs` from `resamples`
/// bootstrap resamples drawn with `seed`. `None` for no data.
pub fn median_interval(diffs: &[f64], level: f64, resamples: usize, seed: u64) -> Option<Interval> {
    if diffs.is_empty() || resamples == 0 {
        return None;
    }
    let mut rng = Rng::new(seed);
    let mut draw = vec![0.0; diffs.len()];
    let mut medians: Vec<f64> = (0..resamples)
        .map(|_| {
            for d in draw.iter_mut() {
                let i = ((rng.next_f64() * diffs.len() as f64) as usize).min(diffs.len() - 1);
                *d = diffs[i];
            }
            median(&draw)
        })
        .collect();
    medians.sort_by(f64::total_cmp);
    let tail = (1.0 - level) / 2.0;
    Some(Interval {
        median: median(diffs),
        low: quantile(&medians, tail),
        high: quantile(&medians, 1.0 - tail),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_interval_holds_the_median_is_reproducible_and_narrows_with_n() {
        let mut rng = Rng::new(3);
        let small: Vec<f64> = (0..8).map(|_| rng.next_f64() - 0.3).collect();
        let large: Vec<f64> = (0..200).map(|_| rng.next_f64() - 0.3).collect();
        let a = median_interval(&small, 0.95, 2000, 1).unwrap();
        assert!(a.low <= a.median && a.median <= a.high);
        assert_eq!(a, median_interval(&small, 0.95, 2000, 1).unwrap());
        let b = median_interval(&large, 0.95, 2000, 1).unwrap();
        assert!(b.high - b.low < (a.high - a.low) / 2.0);
        // Uniform(−0.3, 0.7): median 0.2.
        assert!(b.low < 0.2 && 0.2 < b.high, "{b:?}");
        // No spread, no width.
        let c = median_interval(&[1.5; 6], 0.95, 500, 2).unwrap();
        assert_eq!((c.low, c.high), (1.5, 1.5));
    }
}
