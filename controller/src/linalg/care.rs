//! Continuous algebraic Riccati equation AᵀX + XA − XBR⁻¹BᵀX + Q = 0.
//!
//! No maintained Rust crate solves it, so it is solved here by the matrix sign function of
//! the Hamiltonian (Roberts; Byers' determinant scaling), which needs nothing but inverses,
//! followed by Newton–Kleinman refinement, which polishes the solution to the accuracy the
//! Lyapunov solver allows. Both run in balanced coordinates because our models mix mm with
//! mm/s³.

use nalgebra::{DMatrix, DVector, linalg::balancing::balance_parlett_reinsch};

use crate::error::DesignError;

/// Stabilizing solution X and the LQR gain K = R⁻¹BᵀX.
#[derive(Debug, Clone)]
pub struct CareSolution {
    pub x: DMatrix<f64>,
    pub k: DMatrix<f64>,
    /// Relative residual of the equation at X (see [`care_residual`]).
    pub residual: f64,
}

/// Solves the CARE for the stabilizing X.
pub fn care(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<CareSolution, DesignError> {
    let n = a.nrows();
    let r_inv = r.clone().try_inverse().ok_or(DesignError::Singular("R"))?;

    // Balance A: x = D x̃, Ã = D⁻¹AD, B̃ = D⁻¹B, Q̃ = DQD; then X = D⁻¹X̃D⁻¹.
    let mut ab = a.clone();
    let d: DVector<f64> = balance_parlett_reinsch(&mut ab);
    let d_inv = d.map(|v| 1.0 / v);
    let bb = DMatrix::from_diagonal(&d_inv) * b;
    let qb = DMatrix::from_diagonal(&d) * q * DMatrix::from_diagonal(&d);
    let g = &bb * &r_inv * bb.transpose();

    let mut h = DMatrix::zeros(2 * n, 2 * n);
    h.view_mut((0, 0), (n, n)).copy_from(&ab);
    h.view_mut((0, n), (n, n)).copy_from(&(-&g));
    h.view_mut((n, 0), (n, n)).copy_from(&(-&qb));
    h.view_mut((n, n), (n, n)).copy_from(&(-ab.transpose()));

    let w = matrix_sign(h)?;
    let eye = DMatrix::<f64>::identity(n, n);
    // [W12; W22 + I] X = -[W11 + I; W21]
    let mut lhs = DMatrix::zeros(2 * n, n);
    lhs.view_mut((0, 0), (n, n))
        .copy_from(&w.view((0, n), (n, n)));
    lhs.view_mut((n, 0), (n, n))
        .copy_from(&(w.view((n, n), (n, n)) + &eye));
    let mut rhs = DMatrix::zeros(2 * n, n);
    rhs.view_mut((0, 0), (n, n))
        .copy_from(&(-(w.view((0, 0), (n, n)) + &eye)));
    rhs.view_mut((n, 0), (n, n))
        .copy_from(&(-w.view((n, 0), (n, n))));
    let xb = lhs
        .svd(true, true)
        .solve(&rhs, 1e-14)
        .map_err(|e| DesignError::Riccati(e.to_string()))?;
    let mut xb = (&xb + xb.transpose()) * 0.5;

    // Newton–Kleinman: X_{k+1} solves (A − G X_k)ᵀX + X(A − G X_k) = −(Q + X_k G X_k).
    for _ in 0..20 {
        let ak = &ab - &g * &xb;
        let rhs = &qb + &xb * &g * &xb;
        let next = lyapunov(&ak, &rhs)?;
        let change = (&next - &xb).norm() / next.norm().max(f64::MIN_POSITIVE);
        xb = (&next + next.transpose()) * 0.5;
        if change < 1e-14 {
            break;
        }
    }

    let x = DMatrix::from_diagonal(&d_inv) * &xb * DMatrix::from_diagonal(&d_inv);
    let k = &r_inv * b.transpose() * &x;
    let closed = a - b * &k;
    if super::eigenvalues(&closed)?.iter().any(|z| z.re >= 0.0) {
        return Err(DesignError::Riccati(
            "the solution found does not stabilize A − BK (is (A, B) stabilizable and (Q, A) detectable?)"
                .into(),
        ));
    }
    let residual = care_residual(a, b, q, r, &x);
    if !residual.is_finite() || residual > 1e-8 {
        return Err(DesignError::Riccati(format!(
            "relative residual {residual:e} too large"
        )));
    }
    Ok(CareSolution { x, k, residual })
}

/// ‖AᵀX + XA − XBR⁻¹BᵀX + Q‖ relative to the size of its terms.
pub fn care_residual(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
    x: &DMatrix<f64>,
) -> f64 {
    let Some(r_inv) = r.clone().try_inverse() else {
        return f64::INFINITY;
    };
    let atx = a.transpose() * x;
    let xa = x * a;
    let xgx = x * b * r_inv * b.transpose() * x;
    let res = &atx + &xa - &xgx + q;
    res.norm() / (atx.norm() + xa.norm() + xgx.norm() + q.norm())
}

/// sign(H) by the scaled Newton iteration Z ← (cZ + (cZ)⁻¹)/2, c = |det Z|^(−1/N).
fn matrix_sign(mut z: DMatrix<f64>) -> Result<DMatrix<f64>, DesignError> {
    let size = z.nrows() as f64;
    for _ in 0..100 {
        let lu = z.clone().lu();
        let det = lu.determinant().abs();
        let inv = lu.try_inverse().ok_or_else(|| {
            DesignError::Riccati("the Hamiltonian has eigenvalues on the imaginary axis".into())
        })?;
        let c = if det.is_finite() && det > 0.0 {
            det.powf(-1.0 / size)
        } else {
            1.0
        };
        let next = (&z * c + inv / c) * 0.5;
        let change = (&next - &z).norm() / next.norm();
        z = next;
        if change < 1e-13 {
            return Ok(z);
        }
    }
    Err(DesignError::Riccati(
        "the matrix-sign iteration did not converge".into(),
    ))
}

/// Solves the Lyapunov equation AᵀX + XA + C = 0 through its Kronecker form
/// (Iₙ ⊗ Aᵀ + Aᵀ ⊗ Iₙ) vec X = −vec C; fine for the n ≤ 20 of our designs.
pub fn lyapunov(a: &DMatrix<f64>, c: &DMatrix<f64>) -> Result<DMatrix<f64>, DesignError> {
    let n = a.nrows();
    let at = a.transpose();
    let mut big = DMatrix::zeros(n * n, n * n);
    for i in 0..n {
        for j in 0..n {
            // Column-major vec: X[(r, s)] sits at s*n + r.
            // (Aᵀ X)[(r, s)] = Σ_k Aᵀ[(r, k)] X[(k, s)]
            // (X A)[(r, s)] = Σ_k X[(r, k)] A[(k, s)]
            for k in 0..n {
                big[(j * n + i, j * n + k)] += at[(i, k)];
                big[(j * n + i, k * n + i)] += a[(k, j)];
            }
        }
    }
    let rhs = DVector::from_iterator(n * n, c.iter().map(|v| -v));
    let sol = big.lu().solve(&rhs).ok_or(DesignError::Singular(
        "Lyapunov operator (A has eigenvalues λ, −λ)",
    ))?;
    Ok(DMatrix::from_column_slice(n, n, sol.as_slice()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalar_riccati_matches_the_quadratic_formula() {
        // 2aX − b²X²/r + q = 0 → X = r(a + √(a² + b²q/r))/b².
        let (a, b, q, r) = (1.5, 2.0, 3.0, 0.5);
        let sol = care(
            &DMatrix::from_element(1, 1, a),
            &DMatrix::from_element(1, 1, b),
            &DMatrix::from_element(1, 1, q),
            &DMatrix::from_element(1, 1, r),
        )
        .unwrap();
        let want = r * (a + (a * a + b * b * q / r).sqrt()) / (b * b);
        assert!((sol.x[(0, 0)] - want).abs() < 1e-12 * want);
    }

    #[test]
    fn double_integrator_lqr_has_the_textbook_gain() {
        // ẍ = u, Q = diag(1, 0), R = 1: K = [1, √2].
        let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
        let b = DMatrix::from_row_slice(2, 1, &[0.0, 1.0]);
        let q = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, 0.0]);
        let r = DMatrix::from_element(1, 1, 1.0);
        let sol = care(&a, &b, &q, &r).unwrap();
        assert!((sol.k[(0, 0)] - 1.0).abs() < 1e-12);
        assert!((sol.k[(0, 1)] - 2f64.sqrt()).abs() < 1e-12);
        assert!(sol.residual < 1e-14);
    }

    #[test]
    fn lyapunov_solution_satisfies_the_equation() {
        let a = DMatrix::from_row_slice(3, 3, &[-1.0, 2.0, 0.0, 0.0, -3.0, 1.0, 0.5, 0.0, -2.0]);
        let c = DMatrix::from_row_slice(3, 3, &[2.0, 1.0, 0.0, 1.0, 3.0, 0.5, 0.0, 0.5, 1.0]);
        let x = lyapunov(&a, &c).unwrap();
        let res = a.transpose() * &x + &x * &a + &c;
        assert!(res.norm() < 1e-12, "{res}");
    }
}
