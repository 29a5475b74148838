//! Observer pole placement for several outputs.
//!
//! The gain that places n poles with p outputs is not unique. We use the parametric
//! (Sylvester-equation) construction on the dual system, which is well conditioned when the
//! free parameter vectors are spread out: for each pole λᵢ pick hᵢ ∈ ℝᵖ, solve
//! (Aᵀ − λᵢI) vᵢ = Cᵀhᵢ, and set Lᵀ = H V⁻¹. Then (Aᵀ − CᵀLᵀ)vᵢ = λᵢvᵢ by construction.

use nalgebra::{DMatrix, DVector, linalg::balancing::balance_parlett_reinsch};
use std::f64::consts::PI;

use crate::error::DesignError;

/// Observer gain L (n × p) such that the eigenvalues of A − LC are the given real `poles`.
pub fn place_observer(
    a: &DMatrix<f64>,
    c: &DMatrix<f64>,
    poles: &[f64],
) -> Result<DMatrix<f64>, DesignError> {
    let n = a.nrows();
    let p = c.nrows();
    if poles.len() != n {
        return Err(DesignError::Placement(format!(
            "{} poles given for {n} states",
            poles.len()
        )));
    }
    if poles.iter().any(|p| !p.is_finite()) {
        return Err(DesignError::Placement("poles must be finite".into()));
    }
    // Balanced coordinates x = D x̃: Ã = D⁻¹AD, C̃ = CD, and L = D L̃.
    let mut ab = a.clone();
    let d = balance_parlett_reinsch(&mut ab);
    let cb = c * DMatrix::from_diagonal(&d);

    let f = ab.transpose();
    let g = cb.transpose();
    let mut v = DMatrix::zeros(n, n);
    let mut h = DMatrix::zeros(p, n);
    for (i, &lambda) in poles.iter().enumerate() {
        let hi = DVector::from_fn(p, |j, _| {
            (PI * (i as f64 + 0.5) * j as f64 / n as f64).cos()
        });
        let shifted = &f - DMatrix::identity(n, n) * lambda;
        let vi = shifted.lu().solve(&(&g * &hi)).ok_or_else(|| {
            DesignError::Placement(format!("pole {lambda} coincides with an open-loop pole"))
        })?;
        let norm = vi.norm();
        v.set_column(i, &(vi / norm));
        h.set_column(i, &(hi / norm));
    }
    let v_inv = v.clone().try_inverse().ok_or_else(|| {
        DesignError::Placement("the eigenvectors are dependent (is (A, C) observable?)".into())
    })?;
    let mut lt = &h * &v_inv;
    // V is ill-conditioned for clustered poles, and the poles are as sensitive to L as V is
    // ill-conditioned: refine the solve LᵀV = H on its residual (two steps reach rounding).
    for _ in 0..2 {
        let residual = &h - &lt * &v;
        lt += residual * &v_inv;
    }
    Ok(DMatrix::from_diagonal(&d) * lt.transpose())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn places_the_poles_of_a_two_output_system() {
        // Two coupled oscillators, measuring the first position and the second velocity.
        let a = DMatrix::from_row_slice(
            4,
            4,
            &[
                0.0, 1.0, 0.0, 0.0, -4.0, -0.1, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, -9.0, -0.2,
            ],
        );
        let c = DMatrix::from_row_slice(2, 4, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        let poles = [-5.0, -6.0, -7.0, -8.0];
        let l = place_observer(&a, &c, &poles).unwrap();
        let mut ev: Vec<f64> = crate::linalg::eigenvalues(&(&a - &l * &c))
            .unwrap()
            .iter()
            .map(|z| {
                assert!(z.im.abs() < 1e-9);
                z.re
            })
            .collect();
        ev.sort_by(|x, y| y.partial_cmp(x).unwrap());
        for (got, want) in ev.iter().zip(poles) {
            assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        }
    }
}
