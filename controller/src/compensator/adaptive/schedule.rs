//! When an adaptive design changes and how: the grid of mode-frequency ratios its designs
//! were prepared for, the retune decision once per period from the estimate, the crossfade
//! from the old design to the new one, and the counts reported in `AdaptationStatus`.

use bdft_protocol::params::AdaptParams;

/// A switch that starts this tick: fade out `from`, fade in `to` (indices into the grid).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Switch {
    pub from: usize,
    pub to: usize,
}

#[derive(Debug, Clone)]
pub struct Schedule {
    /// Ratio of each prepared design, ascending; `nominal` is exactly 1.
    ratios: Vec<f64>,
    nominal: usize,
    active: usize,
    /// The design being faded out, and the blend ticks left.
    fading: Option<(usize, u64)>,
    blend_ticks: u64,
    period_ticks: u64,
    until_decision: u64,
    retunes: u32,
    fallbacks: u32,
}

impl Schedule {
    /// Designs over the retune range [`lo`, `hi`] (lo ≤ 1 ≤ hi) of loop period `dt`:
    /// `half` evenly below r = 1, r = 1, and above it as many as the same step needs to
    /// reach `hi` (none when `hi` is 1: a design not retuned upward), decided every retune
    /// period of `adapt`.
    pub fn new(adapt: &AdaptParams, (lo, hi): (f64, f64), half: usize, dt: f64) -> Self {
        let step = (1.0 - lo) / half as f64;
        let up = ((hi - 1.0) / step - 1e-9).ceil().max(0.0) as usize;
        let ratios = (0..half)
            .map(|i| 1.0 - (half - i) as f64 * step)
            .chain([1.0])
            .chain((1..=up).map(|j| 1.0 + (hi - 1.0) * j as f64 / up as f64))
            .collect();
        let period_ticks = ((adapt.retune_period_s / dt).round() as u64).max(1);
        Self {
            ratios,
            nominal: half,
            active: half,
            fading: None,
            blend_ticks: ((adapt.blend_s / dt).round() as u64).clamp(1, period_ticks),
            period_ticks,
            until_decision: period_ticks,
            retunes: 0,
            fallbacks: 0,
        }
    }

    pub fn ratios(&self) -> &[f64] {
        &self.ratios
    }

    pub fn active(&self) -> usize {
        self.active
    }

    pub fn ratio(&self) -> f64 {
        self.ratios[self.active]
    }

    pub fn retunes(&self) -> u32 {
        self.retunes
    }

    pub fn fallbacks(&self) -> u32 {
        self.fallbacks
    }

    /// The design nearest `r` (clamped to the range; the lower of two equally near).
    pub fn nearest(&self, r: f64) -> usize {
        let mut best = 0;
        for (i, q) in self.ratios.iter().enumerate() {
            if (q - r).abs() < (self.ratios[best] - r).abs() {
                best = i;
            }
        }
        best
    }

    /// One tick: `ratio` is the confident estimate's ratio, or None. Decides once a period
    /// (a not-confident decision is a fallback to the nominal design, counted) and returns
    /// the switch to start now, if any. A new decision waits for the blend to finish.
    pub fn tick(&mut self, ratio: Option<f64>) -> Option<Switch> {
        if let Some((from, left)) = self.fading {
            self.fading = (left > 1).then_some((from, left - 1));
        }
        self.until_decision -= 1;
        if self.until_decision > 0 {
            return None;
        }
        self.until_decision = self.period_ticks;
        if self.fading.is_some() {
            return None;
        }
        let to = match ratio {
            // Hysteresis: stay unless the estimate is clearly nearer another design (3/4 of
            // the grid step towards it from the active one), so noise at a midpoint does not
            // toggle. At an end of the range the estimate is clamped there.
            Some(r) => {
                let last = self.ratios.len() - 1;
                let r = r.clamp(self.ratios[0], self.ratios[last]);
                let at = self.ratios[self.active];
                let step = if r > at {
                    self.ratios[(self.active + 1).min(last)] - at
                } else {
                    at - self.ratios[self.active.saturating_sub(1)]
                };
                if (r - at).abs() > 0.75 * step {
                    self.nearest(r)
                } else {
                    self.active
                }
            }
            None => {
                self.fallbacks += 1;
                self.nominal
            }
        };
        self.switch_to(to)
    }

    /// Starts the crossfade to design `to` now (unless it is the active one).
    pub fn switch_to(&mut self, to: usize) -> Option<Switch> {
        if to == self.active {
            return None;
        }
        let from = self.active;
        self.active = to;
        self.fading = Some((from, self.blend_ticks));
        self.retunes += 1;
        Some(Switch { from, to })
    }

    /// The design being faded out and the weight of the active one (0 → 1 over the blend,
    /// a smoothstep so the weight's rate starts and ends at zero); None when not blending.
    #[inline]
    pub fn blend(&self) -> Option<(usize, f64)> {
        self.fading.map(|(from, left)| {
            let x = 1.0 - left as f64 / self.blend_ticks as f64;
            (from, x * x * (3.0 - 2.0 * x))
        })
    }

    pub fn reset(&mut self) {
        self.active = self.nominal;
        self.fading = None;
        self.until_decision = self.period_ticks;
        self.retunes = 0;
        self.fallbacks = 0;
    }
}
