//! Access to the internal state of the per-tick blocks.
//!
//! Every block that runs in the loop (plant, filters, compensators, body) exposes its state
//! as a flat vector. The analysis uses this to read the exact linear map one tick performs —
//! by probing the very `step` code the real-time loop runs — so the stability verdict cannot
//! drift away from what is executed.

/// A block whose state can be read and overwritten as a flat slice of `state_len()` numbers.
pub trait LinearState {
    fn state_len(&self) -> usize;
    /// Writes the state into `out[..state_len()]`.
    fn read_state(&self, out: &mut [f64]);
    /// Sets the state from `s[..state_len()]`.
    fn write_state(&mut self, s: &[f64]);
}
