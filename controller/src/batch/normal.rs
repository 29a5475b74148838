//! Standard normal deviates for every lane at once, for the batched simulation.
//!
//! The scalar path draws with Marsaglia's polar method: a rejection loop around a library
//! logarithm, which no compiler vectorizes and which cost about half of a planner trial's
//! time. Here each lane has its own xoshiro256++ stream (the generator of `rng`, stepped
//! lane-parallel) and deviates come in pairs by the Box–Muller transform, branch-free:
//!
//! - r = √(−2 ln u₁) with u₁ uniform in (0, 1] (52 random bits: |z| ≤ 8.49);
//! - the angle θ uniform on the circle, as a quarter turn k·π/2 (two random bits) plus
//!   φ uniform in [−π/4, π/4) (52 more): (cos θ, sin θ) is (cos φ, sin φ) rotated by k;
//! - z₀ = r·cos θ, z₁ = r·sin θ, two independent standard normals.
//!
//! `ln`, `sin` and `cos` are written here as polynomials on a reduced range, accurate to a
//! few units in the last place (tested against the standard library): the library's are
//! calls the vectorizer cannot see into. They also make the stream the same on every
//! platform, as the seeds' reproducibility needs.

use std::f64::consts::{FRAC_PI_2, LN_2, SQRT_2};

use super::{LANES, Lanes};

/// Deviates generated per lane at a time: a refill is a long vectorizable loop.
const BLOCK: usize = 64;

/// Uniform in [0, 1) from the top 52 bits of `x`: the bits become the mantissa of a number
/// in [1, 2) (integer operations only, which vectorize where u64 → f64 conversion does not).
#[inline(always)]
fn unit(x: u64) -> f64 {
    f64::from_bits((x >> 12) | 0x3FF0_0000_0000_0000) - 1.0
}

/// Natural logarithm of a positive, normal `u`: u = m·2ᵉ with m in [√½, √2), and
/// ln m = 2·atanh(f), f = (m − 1)/(m + 1), |f| ≤ 0.1716, by its series to f²¹ (the next term
/// is below 10⁻¹⁷).
#[inline(always)]
pub(crate) fn ln(u: f64) -> f64 {
    let bits = u.to_bits();
    // The biased exponent as a float, exactly: 2⁵² + e − (2⁵² + 1023).
    let e =
        f64::from_bits((bits >> 52) | 0x4330_0000_0000_0000) - (4_503_599_627_370_496.0 + 1023.0);
    let m = f64::from_bits((bits & 0x000F_FFFF_FFFF_FFFF) | 0x3FF0_0000_0000_0000);
    let big = m > SQRT_2;
    let m = if big { 0.5 * m } else { m };
    let e = if big { e + 1.0 } else { e };
    let f = (m - 1.0) / (m + 1.0);
    let s = f * f;
    let mut p = 1.0 / 21.0;
    for k in (0..10).rev() {
        p = p * s + 1.0 / (2 * k + 1) as f64;
    }
    e * LN_2 + 2.0 * f * p
}

/// (sin φ, cos φ) for |φ| ≤ π/4 by their Taylor series to φ¹⁵ and φ¹⁶ (the next terms are
/// below 10⁻¹⁶).
#[inline(always)]
pub(crate) fn sin_cos(phi: f64) -> (f64, f64) {
    let s = phi * phi;
    // 1/n! for the odd (sine) and even (cosine) n, highest first.
    const SIN: [f64; 8] = [
        -1.0 / 1_307_674_368_000.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 39_916_800.0,
        1.0 / 362_880.0,
        -1.0 / 5040.0,
        1.0 / 120.0,
        -1.0 / 6.0,
        1.0,
    ];
    const COS: [f64; 9] = [
        1.0 / 20_922_789_888_000.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 479_001_600.0,
        -1.0 / 3_628_800.0,
        1.0 / 40_320.0,
        -1.0 / 720.0,
        1.0 / 24.0,
        -1.0 / 2.0,
        1.0,
    ];
    let mut sp = SIN[0];
    for c in &SIN[1..] {
        sp = sp * s + c;
    }
    let mut cp = COS[0];
    for c in &COS[1..] {
        cp = cp * s + c;
    }
    (phi * sp, cp)
}

/// One xoshiro256++ stream per lane, stepped together (the same generator as `rng::Rng`).
#[derive(Debug, Clone)]
struct Xoshiro {
    s: [[u64; LANES]; 4],
}

impl Xoshiro {
    #[inline(always)]
    fn next(&mut self) -> [u64; LANES] {
        let mut out = [0u64; LANES];
        let [s0, s1, s2, s3] = &mut self.s;
        for l in 0..LANES {
            out[l] = s0[l]
                .wrapping_add(s3[l])
                .rotate_left(23)
                .wrapping_add(s0[l]);
            let t = s1[l] << 17;
            s2[l] ^= s0[l];
            s3[l] ^= s1[l];
            s1[l] ^= s2[l];
            s0[l] ^= s3[l];
            s2[l] ^= t;
            s3[l] = s3[l].rotate_left(45);
        }
        out
    }
}

/// A stream of standard normal deviates per lane.
#[derive(Debug, Clone)]
pub(crate) struct NormalLanes {
    rng: Xoshiro,
    block: Box<[Lanes; BLOCK]>,
    next: usize,
}

impl NormalLanes {
    /// Lane l's stream is xoshiro256++ from `states[l]`.
    pub(crate) fn new(states: [[u64; 4]; LANES]) -> Self {
        let mut s = [[0u64; LANES]; 4];
        for (l, st) in states.iter().enumerate() {
            for w in 0..4 {
                s[w][l] = st[w];
            }
        }
        Self {
            rng: Xoshiro { s },
            block: Box::new([[0.0; LANES]; BLOCK]),
            next: BLOCK,
        }
    }

    /// One deviate for every lane.
    #[inline(always)]
    pub(crate) fn next(&mut self) -> Lanes {
        if self.next == BLOCK {
            self.refill();
            self.next = 0;
        }
        let z = self.block[self.next];
        self.next += 1;
        z
    }

    #[inline(always)]
    fn refill(&mut self) {
        // The generator on a local copy: its state in `self` next to stores into the block
        // (heap) would be reloaded and stored around every pair.
        let mut rng = self.rng.clone();
        for pair in self.block.chunks_exact_mut(2) {
            let radius_bits = rng.next();
            let angle_bits = rng.next();
            let (mut z0, mut z1) = ([0.0; LANES], [0.0; LANES]);
            for l in 0..LANES {
                let u = 1.0 - unit(radius_bits[l]);
                let r = (-2.0 * ln(u)).sqrt();
                let a = angle_bits[l];
                let (s, c) = sin_cos((unit(a) - 0.5) * FRAC_PI_2);
                // A quarter turn swaps and negates one; a half turn negates both.
                let odd = a & 1 != 0;
                let (x, y) = if odd { (-s, c) } else { (c, s) };
                let r = if a & 2 != 0 { -r } else { r };
                z0[l] = r * x;
                z1[l] = r * y;
            }
            pair[0] = z0;
            pair[1] = z1;
        }
        self.rng = rng;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ln_matches_the_standard_library_across_the_unit_interval() {
        let mut worst = 0.0f64;
        let mut x = 2f64.powi(-52);
        while x <= 1.0 {
            for k in 0..64 {
                let u = (x * (1.0 + k as f64 / 64.0)).min(1.0);
                let (got, want) = (ln(u), u.ln());
                worst = worst.max((got - want).abs() / want.abs().max(1.0));
            }
            x *= 2.0;
        }
        assert_eq!(ln(1.0), 0.0);
        assert!(worst < 4e-16, "worst error {worst:e}");
    }

    #[test]
    fn sine_and_cosine_match_the_standard_library_on_the_octant() {
        let mut worst = 0.0f64;
        for i in -10_000..=10_000 {
            let phi = i as f64 / 10_000.0 * std::f64::consts::FRAC_PI_4;
            let (s, c) = sin_cos(phi);
            worst = worst.max((s - phi.sin()).abs()).max((c - phi.cos()).abs());
        }
        assert!(worst < 4e-16, "worst error {worst:e}");
    }

    #[test]
    fn deviates_are_standard_normal_in_every_lane_and_independent_between_lanes() {
        let states = std::array::from_fn(|l| crate::rng::Rng::new(l as u64 + 11).s);
        let mut g = NormalLanes::new(states);
        let n = 200_000;
        let draws: Vec<Lanes> = (0..n).map(|_| g.next()).collect();
        // Standard normal deciles (Φ⁻¹(0.1·k), k = 1..9).
        const DECILES: [f64; 9] = [
            -1.2815515655446004,
            -0.8416212335729143,
            -0.5244005127080407,
            -0.2533471031357997,
            0.0,
            0.2533471031357997,
            0.5244005127080407,
            0.8416212335729143,
            1.2815515655446004,
        ];
        for l in 0..LANES {
            let xs: Vec<f64> = draws.iter().map(|d| d[l]).collect();
            let nf = n as f64;
            let mean = xs.iter().sum::<f64>() / nf;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / nf;
            let skew = xs.iter().map(|x| (x - mean).powi(3)).sum::<f64>() / nf / var.powf(1.5);
            let kurt = xs.iter().map(|x| (x - mean).powi(4)).sum::<f64>() / nf / var.powi(2);
            // Standard errors at n = 200,000: mean 0.0022, variance 0.0032, skewness 0.0055,
            // kurtosis 0.011; bounds at about 4.5 of them.
            assert!(mean.abs() < 0.01, "lane {l}: mean {mean}");
            assert!((var - 1.0).abs() < 0.015, "lane {l}: variance {var}");
            assert!(skew.abs() < 0.025, "lane {l}: skewness {skew}");
            assert!((kurt - 3.0).abs() < 0.05, "lane {l}: kurtosis {kurt}");
            // Chi-square over the ten decile bins: 9 degrees of freedom, 99.99th percentile
            // 33.7.
            let mut bins = [0usize; 10];
            for &x in &xs {
                bins[DECILES.iter().filter(|&&d| x >= d).count()] += 1;
            }
            let expected = nf / 10.0;
            let chi2: f64 = bins
                .iter()
                .map(|&b| (b as f64 - expected).powi(2) / expected)
                .sum();
            assert!(chi2 < 33.7, "lane {l}: chi-square {chi2} over {bins:?}");
        }
        // Lanes are independent streams: correlations near 0 (standard error 0.0022).
        for l in 1..LANES {
            let r = draws.iter().map(|d| d[0] * d[l]).sum::<f64>() / n as f64;
            assert!(r.abs() < 0.012, "lanes 0 and {l}: correlation {r}");
        }
        // Consecutive deviates of a lane (the two of a Box–Muller pair among them) too.
        let lag: f64 = draws.windows(2).map(|w| w[0][3] * w[1][3]).sum::<f64>() / n as f64;
        assert!(lag.abs() < 0.012, "lag-1 correlation {lag}");
    }
}
