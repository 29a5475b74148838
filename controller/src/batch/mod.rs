//! Simulated trials in batches, one trial per SIMD lane: the power planner's engine.
//!
//! A planner runs thousands of whole studies (1,000 studies of 8 subjects are 1.1·10¹⁰ loop
//! ticks), and one scalar trial at a time spends most of each tick on things a vector unit
//! does for several trials at once: the plant, body, operator filters and compensators are
//! fixed-size linear maps with a saturation or two. Here `LANES` trials of one design at one
//! seat — different subjects, targets and seeds — run together: every quantity of the
//! scalar trial becomes an array over the lanes, every operation a loop over them that the
//! compiler turns into vector instructions.
//!
//! Trustworthy by construction and by test: a batch is built from the scalar trials' own
//! parts (`runtime::setup::build_runner`: validation, designs, subjects), and its tick is
//! the scalar tick's operations in the scalar order, so on the scalar trials' own deviates
//! a batch reproduces them bit for bit (tested for every compensator, body kind and seat,
//! with an interlock trip among the lanes). The one difference is where the deviates come
//! from: the batch draws its own, vectorized (`normal`), from streams seeded by each trial's
//! seeds — the same model and the same distributions, another realization of the noise.
//!
//! Files: `rig` (plant, body, compensators, interlock), `operator`, `trial` (the tick, and `Build`:
//! the run-time choice of the AVX-512, AVX2 or baseline build — one of the crate's three places
//! with `unsafe`, a call after the CPU check), `normal` (vectorized xoshiro256++ streams and
//! Box–Muller with polynomial ln/sin/cos).
//!
//! *Invariant:* on the scalar trials' deviates a batch reproduces `runtime::local::metrics` bit for
//! bit (every compensator, body kind and seat), and every build gives the same bits; a long update
//! is one loop over the lanes with each lane's arithmetic inside, the form the loop vectorizer
//! takes reliably.

// Every quantity is an array over the lanes and every operation a `for l in 0..LANES` over
// several such arrays at once: the form the vectorizer turns into straight vector code.
#![allow(clippy::needless_range_loop)]
// A batch holds one of each part for its whole life; boxing the larger variants would add a
// pointer chase to every tick.
#![allow(clippy::large_enum_variant)]

mod normal;
mod operator;
mod rig;
#[cfg(test)]
mod tests;
mod trial;

use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::Metrics;

pub use trial::Build;

/// Trials per batch: two AVX2 vectors of f64 per quantity, enough independent work per
/// operation to keep the vector units busy.
pub const LANES: usize = 8;

pub(crate) type Lanes = [f64; LANES];
pub(crate) const ZERO: Lanes = [0.0; LANES];

/// Runs the trials `starts` describe (synthetic operators on the simulated rig; trials of
/// one batch — consecutive runs of `LANES` — must share design, plant, seat, K_BF, length
/// and interlock limit) without records, and returns each one's metrics in order: None
/// where the cab-vibration interlock stopped it, as `runtime::local::metrics`. Runs the
/// widest build this CPU has. Trials of an adaptive design run one at a time (each
/// trial's estimate retunes its own design, so the lanes would not share one).
pub fn metrics(starts: &[StartTrial], dt: f64) -> Result<Vec<Option<Metrics>>, String> {
    Ok(metrics_with(Build::widest(), starts, dt)?.unwrap_or_default())
}

/// `metrics` with the given build (the benchmark compares them); None where this CPU lacks
/// it. Every build gives the same bits.
pub fn metrics_with(
    build: Build,
    starts: &[StartTrial],
    dt: f64,
) -> Result<Option<Vec<Option<Metrics>>>, String> {
    if !build.available() {
        return Ok(None);
    }
    let mut out = Vec::with_capacity(starts.len());
    for chunk in starts.chunks(LANES) {
        if chunk[0].compensator.kind().is_adaptive() {
            for st in chunk {
                out.push(crate::runtime::local::metrics(st, dt)?);
            }
            continue;
        }
        // A short last batch fills its spare lanes with its last trial and drops them.
        let lanes = std::array::from_fn(|l| &chunk[l.min(chunk.len() - 1)]);
        let (mut batch, mut deviates) = trial::BatchTrial::build(&lanes, dt)?;
        trial::run_with(build, &mut batch, &mut deviates);
        out.extend(batch.results().into_iter().take(chunk.len()));
    }
    Ok(Some(out))
}
