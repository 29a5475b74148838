use nalgebra::DMatrix;

/// Zero-order-hold discretization of ẋ = A x + B u at period `dt`, exact for piecewise-constant
/// inputs: exp([[A, B], [0, 0]]·dt) = [[Ad, Bd], [0, I]] (Van Loan's block form, which needs
/// no inverse of A and so works for the integrating plants we have).
pub fn zoh(a: &DMatrix<f64>, b: &DMatrix<f64>, dt: f64) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = a.nrows();
    let m = b.ncols();
    let mut block = DMatrix::zeros(n + m, n + m);
    block.view_mut((0, 0), (n, n)).copy_from(&(a * dt));
    block.view_mut((0, n), (n, m)).copy_from(&(b * dt));
    let e = block.exp();
    (
        e.view((0, 0), (n, n)).into_owned(),
        e.view((0, n), (n, m)).into_owned(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalar_integrator_and_lag_match_closed_forms() {
        // ẋ = -a x + u: Ad = e^{-a dt}, Bd = (1 - e^{-a dt})/a.
        let a = 3.0;
        let dt = 0.01;
        let (ad, bd) = zoh(
            &DMatrix::from_element(1, 1, -a),
            &DMatrix::from_element(1, 1, 1.0),
            dt,
        );
        assert!((ad[(0, 0)] - (-a * dt).exp()).abs() < 1e-15);
        assert!((bd[(0, 0)] - (1.0 - (-a * dt).exp()) / a).abs() < 1e-15);
        // Double integrator: Ad = [[1, dt], [0, 1]], Bd = [dt²/2, dt].
        let a2 = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
        let b2 = DMatrix::from_row_slice(2, 1, &[0.0, 1.0]);
        let (ad, bd) = zoh(&a2, &b2, dt);
        assert!((ad[(0, 1)] - dt).abs() < 1e-15 && (ad[(0, 0)] - 1.0).abs() < 1e-15);
        assert!((bd[(0, 0)] - dt * dt / 2.0).abs() < 1e-15 && (bd[(1, 0)] - dt).abs() < 1e-15);
    }
}
