//! Seeded pseudo-random numbers that reproduce bit for bit forever.
//!
//! Research integrity needs a seed recorded today to regenerate the same target and the same
//! noise years later, whatever crate versions exist then. So the generator is written here
//! (xoshiro256++ seeded by SplitMix64, Blackman & Vigna, public domain) and checked against
//! the C reference in `tools/fixtures`, rather than taken from a crate whose value stream may
//! change between major versions.

/// xoshiro256++ generator. Copy, fixed-size, never allocates: usable inside the 1 kHz tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rng {
    pub(crate) s: [u64; 4],
    /// Second normal deviate of the last polar-method pair, if unused.
    spare_normal: Option<u64>,
}

fn splitmix64(x: &mut u64) -> u64 {
    *x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator whose whole stream is determined by `seed`.
    pub fn new(seed: u64) -> Self {
        let mut x = seed;
        let s = [
            splitmix64(&mut x),
            splitmix64(&mut x),
            splitmix64(&mut x),
            splitmix64(&mut x),
        ];
        Self {
            s,
            spare_normal: None,
        }
    }

    /// Purpose tags for [`Rng::derive`]: one independent stream per use of a trial's seed.
    pub const TARGET: u64 = 1;
    pub const ACCEL_NOISE: u64 = 2;
    pub const OPERATOR: u64 = 3;
    pub const POPULATION: u64 = 4;
    pub const SURVEY: u64 = 5;
    /// The identification test's multisine phases.
    pub const MULTISINE: u64 = 6;

    /// An independent stream for a sub-purpose (e.g. "accelerometer noise" vs "target"), so
    /// that adding draws to one purpose never shifts another's values.
    pub fn derive(seed: u64, purpose: u64) -> Self {
        let mut x = seed ^ purpose.wrapping_mul(0xd134_2543_de82_ef95);
        Self::new(splitmix64(&mut x))
    }

    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }

    /// Standard normal deviate (Marsaglia's polar method; the rejection loop ends with
    /// probability 1 - (1 - pi/4)^n, in practice within a few draws).
    pub fn normal(&mut self) -> f64 {
        if let Some(bits) = self.spare_normal.take() {
            return f64::from_bits(bits);
        }
        loop {
            let u = 2.0 * self.next_f64() - 1.0;
            let v = 2.0 * self.next_f64() - 1.0;
            let s = u * u + v * v;
            if s > 0.0 && s < 1.0 {
                let m = (-2.0 * s.ln() / s).sqrt();
                self.spare_normal = Some((v * m).to_bits());
                return u * m;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::reference;

    #[test]
    fn matches_the_c_reference_implementation() {
        let cases = reference()["xoshiro256pp"]["cases"]
            .as_array()
            .expect("cases");
        assert!(cases.len() >= 3);
        for case in cases {
            let seed = case["seed"].as_u64().unwrap();
            let mut rng = Rng::new(seed);
            for want in case["u64"].as_array().unwrap() {
                let want: u64 = want.as_str().unwrap().parse().unwrap();
                assert_eq!(rng.next_u64(), want, "seed {seed}");
            }
            let mut rng = Rng::new(seed);
            for want in case["f64"].as_array().unwrap() {
                assert_eq!(rng.next_f64(), want.as_f64().unwrap(), "seed {seed}");
            }
        }
    }

    #[test]
    fn normal_deviates_have_unit_variance() {
        let mut rng = Rng::new(7);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        // Standard errors: mean 1/sqrt(n) = 0.0022, variance sqrt(2/n) = 0.0032.
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.015, "variance {var}");
    }

    #[test]
    fn derived_streams_differ_and_repeat() {
        let a: Vec<u64> = (0..4).map(|_| Rng::derive(1, 1).next_u64()).collect();
        assert_eq!(a[0], a[1]);
        assert_ne!(Rng::derive(1, 1).next_u64(), Rng::derive(1, 2).next_u64());
    }
}
