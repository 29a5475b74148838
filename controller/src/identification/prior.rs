//! The population's spread of the seated body: a prior on the resonances, and the yardstick
//! for whether a test told a person's body from the population's.
//!
//! The default identification test pins k_h (the band's top) but reaches a resonance only as
//! far as the remnant lets it: a torso damping the data cannot tell within a factor of 10
//! leaves the fit free to trade it against k_h, and k_h then comes out with it by up to a
//! third (issue 42: seed 6's S06, k_h 0.52 against a drawn 0.40). People's resonances are not
//! anywhere in the plausible box: they scatter about the literature's medians by about
//! ±20 % in frequency and ±30 % in damping (`PopulationParams`). Taken as a prior —
//! ln f and ln ζ normal with the population's median and log-sd — the fit's resonances stay
//! where bodies have them when the data are silent, and k_h is estimated with them there.
//! k_h itself has no prior: it is what the test measures, and it is always the data's.
//!
//! What a parameter's precision is judged against: the population's spread. A parameter
//! known to more than 1/√2 of it (`fit`'s `POPULATION_SHARE_MAX`) is one the data weigh less
//! in than the population, and is named not identified — for a resonance, its value is then
//! the prior's more than the data's; for k_h, the test could not place the person within the
//! population.

use bdft_protocol::params::{PopulationParams, Spread};

/// ln of each of the body's parameters (`BodyFit::PARAMETERS`' order) across the population:
/// normal with these means and standard deviations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyPrior {
    pub mean: [f64; 5],
    pub sd: [f64; 5],
}

impl BodyPrior {
    /// The study's population. None when it does not spread a parameter of the body (cv 0:
    /// everyone the median — a prior of no width says nothing a test could check).
    pub fn of(population: &PopulationParams) -> Option<Self> {
        let spreads: [Spread; 5] = [
            population.body_k_h,
            population.torso_f_hz,
            population.torso_zeta,
            population.arm_f_hz,
            population.arm_zeta,
        ];
        spreads
            .iter()
            .all(|s| s.median > 0.0 && s.cv > 0.0)
            .then(|| Self {
                mean: spreads.map(|s| s.median.ln()),
                sd: spreads.map(|s| s.log_sd()),
            })
    }

    /// The prior's residuals at θ = ln(parameters), one per resonance parameter (θ[1..]):
    /// (θ − mean)/sd. k_h has none.
    pub(super) fn residuals(&self, theta: &[f64; 5]) -> [f64; 4] {
        std::array::from_fn(|i| (theta[i + 1] - self.mean[i + 1]) / self.sd[i + 1])
    }

    /// The cost the prior adds at the resonances `shape` = ln(f_t, ζ_t, f_a, ζ_a).
    pub(super) fn cost(&self, shape: [f64; 4]) -> f64 {
        let mut theta = [0.0; 5];
        theta[1..].copy_from_slice(&shape);
        self.residuals(&theta).iter().map(|r| r * r).sum()
    }
}
