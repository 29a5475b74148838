//! A block's linear map read off its own `step`, and its response on the unit circle.
//!
//! [`probe_matrices`] steps the block from each state and each input in turn, so the
//! matrices are of the code that runs (the plant's zero-order hold, the Tustin filters, the
//! shaper's delays); [`StateSpace`] keeps A in Hessenberg form so G(e^{jωT}) =
//! C(zI − A)⁻¹B + D costs O(n²) a frequency even for the shaper's ~210-state delay line.
//! The frequency responses, the Nyquist view and the stability analysis all read their
//! matrices here.

use nalgebra::{Complex, DMatrix};

use crate::state::LinearState;

/// Probe size: small enough that nothing saturates (valve, stroke, PID output), large enough
/// to stay far above rounding.
const EPS: f64 = 1e-6;

/// A linear block x⁺ = Ax + Bu, y = Cx + Du, with A in Hessenberg form for fast evaluation.
#[derive(Debug, Clone)]
pub struct StateSpace {
    a: DMatrix<f64>,
    /// Upper Hessenberg H = QᵀAQ, with B and C carried into its basis.
    h: DMatrix<f64>,
    qb: DMatrix<f64>,
    cq: DMatrix<f64>,
    d: DMatrix<f64>,
}

impl StateSpace {
    pub fn new(a: DMatrix<f64>, b: DMatrix<f64>, c: DMatrix<f64>, d: DMatrix<f64>) -> Self {
        let (q, h) = if a.nrows() == 0 {
            (a.clone(), a.clone())
        } else {
            a.clone().hessenberg().unpack()
        };
        Self {
            qb: q.transpose() * b,
            cq: c * q,
            h,
            a,
            d,
        }
    }

    /// The one-step state matrix.
    pub fn a(&self) -> &DMatrix<f64> {
        &self.a
    }

    /// Response from input `input` to output `output` at z = e^{jθ} (θ = ωT).
    pub fn response(&self, output: usize, input: usize, theta: f64) -> Complex<f64> {
        let n = self.h.nrows();
        let d = Complex::new(self.d[(output, input)], 0.0);
        if n == 0 {
            return d;
        }
        let z = Complex::from_polar(1.0, theta);
        // (zI − H)x = QᵀB by Gaussian elimination with partial pivoting between neighbouring
        // rows: H has one subdiagonal, so each step touches two rows (O(n²) in all).
        let mut m: Vec<Complex<f64>> = self
            .h
            .transpose()
            .iter()
            .map(|&v| -v)
            .map(Complex::from)
            .collect();
        for i in 0..n {
            m[i * n + i] += z;
        }
        let mut x: Vec<Complex<f64>> = (0..n).map(|i| Complex::from(self.qb[(i, input)])).collect();
        for k in 0..n - 1 {
            if m[(k + 1) * n + k].norm_sqr() > m[k * n + k].norm_sqr() {
                for j in k..n {
                    m.swap(k * n + j, (k + 1) * n + j);
                }
                x.swap(k, k + 1);
            }
            let pivot = m[k * n + k];
            if pivot == Complex::from(0.0) {
                continue;
            }
            let l = m[(k + 1) * n + k] / pivot;
            for j in k..n {
                let v = m[k * n + j];
                m[(k + 1) * n + j] -= l * v;
            }
            let v = x[k];
            x[k + 1] -= l * v;
        }
        for k in (0..n).rev() {
            let mut s = x[k];
            for j in k + 1..n {
                s -= m[k * n + j] * x[j];
            }
            x[k] = s / m[k * n + k];
        }
        (0..n)
            .map(|i| x[i] * self.cq[(output, i)])
            .sum::<Complex<f64>>()
            + d
    }
}

/// Reads a block's linear map off its `step`, ready for evaluation on the unit circle.
pub fn probe<S: LinearState>(
    block: &mut S,
    inputs: usize,
    outputs: usize,
    step: impl FnMut(&mut S, &[f64], &mut [f64]),
) -> StateSpace {
    let (a, b, c, d) = probe_matrices(block, inputs, outputs, step);
    StateSpace::new(a, b, c, d)
}

/// (A, B, C, D) of a block read off its `step`: column i of A and C from a step of εeᵢ with
/// no input, column j of B and D from a step of input εeⱼ from rest. `step` applies the
/// inputs and writes the outputs (measured before or after the update, as the block defines
/// them). The block is left at rest.
pub fn probe_matrices<S: LinearState>(
    block: &mut S,
    inputs: usize,
    outputs: usize,
    mut step: impl FnMut(&mut S, &[f64], &mut [f64]),
) -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
    let n = block.state_len();
    let (mut a, mut b) = (DMatrix::zeros(n, n), DMatrix::zeros(n, inputs));
    let (mut c, mut d) = (DMatrix::zeros(outputs, n), DMatrix::zeros(outputs, inputs));
    let mut x = vec![0.0; n];
    let mut next = vec![0.0; n];
    let mut u = vec![0.0; inputs];
    let mut y = vec![0.0; outputs];
    for col in 0..n + inputs {
        x.fill(0.0);
        u.fill(0.0);
        if col < n {
            x[col] = EPS;
        } else {
            u[col - n] = EPS;
        }
        block.write_state(&x);
        step(block, &u, &mut y);
        block.read_state(&mut next);
        let (m, o, j) = if col < n {
            (&mut a, &mut c, col)
        } else {
            (&mut b, &mut d, col - n)
        };
        for (r, v) in next.iter().enumerate() {
            m[(r, j)] = v / EPS;
        }
        for (r, v) in y.iter().enumerate() {
            o[(r, j)] = v / EPS;
        }
    }
    block.write_state(&vec![0.0; n]);
    (a, b, c, d)
}
