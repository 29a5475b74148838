use nalgebra::{Complex, DMatrix, linalg::balancing::balance_parlett_reinsch};

use crate::error::DesignError;

/// Eigenvalues of a real square matrix. The matrix is balanced first: our state spaces mix
/// positions (mm) with third derivatives (mm/s³), entries spanning ten decades, and the QR
/// iteration loses accuracy badly on such matrices without it.
pub fn eigenvalues(m: &DMatrix<f64>) -> Result<Vec<Complex<f64>>, DesignError> {
    let mut b = m.clone();
    balance_parlett_reinsch(&mut b);
    let schur = b.try_schur(1e-14, 10_000).ok_or(DesignError::Eigen)?;
    Ok(schur.complex_eigenvalues().iter().copied().collect())
}

/// Largest eigenvalue magnitude (the discrete-time stability measure: < 1 is stable).
pub fn spectral_radius(m: &DMatrix<f64>) -> Result<f64, DesignError> {
    Ok(eigenvalues(m)?.iter().map(|z| z.norm()).fold(0.0, f64::max))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn companion_matrix_has_the_polynomial_roots() {
        // (s + 1)(s² + 2s + 5): roots -1, -1 ± 2j. s³ + 3s² + 7s + 5.
        let m = DMatrix::from_row_slice(3, 3, &[0.0, 1.0, 0.0, 0.0, 0.0, 1.0, -5.0, -7.0, -3.0]);
        let mut ev = eigenvalues(&m).unwrap();
        ev.sort_by(|a, b| a.im.partial_cmp(&b.im).unwrap());
        let want = [(-1.0, -2.0), (-1.0, 0.0), (-1.0, 2.0)];
        for (z, (re, im)) in ev.iter().zip(want) {
            assert!(
                (z.re - re).abs() < 1e-10 && (z.im - im).abs() < 1e-10,
                "{z}"
            );
        }
    }
}
