//! Order statistics: the quantile rule every figure and interval of the analyses uses, so a
//! box plot's quartiles, a learning curve's medians and a bootstrap interval's ends agree
//! with numpy and R.

/// Quantile by linear interpolation between order statistics (R's type 7, numpy's default).
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q;
    let (lo, hi) = (h.floor() as usize, h.ceil() as usize);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// Median of `values` (not empty).
pub fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    quantile(&v, 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_numpy_linear() {
        // numpy.quantile([1, 2, 3, 4, 10], [0.25, 0.5, 0.75]) = [2, 3, 4]
        let xs = [1.0, 2.0, 3.0, 4.0, 10.0];
        assert_eq!(
            (quantile(&xs, 0.25), quantile(&xs, 0.5), quantile(&xs, 0.75)),
            (2.0, 3.0, 4.0)
        );
        // numpy.quantile([1, 2, 3, 4], [0.25, 0.5]) = [1.75, 2.5]
        let ys = [1.0, 2.0, 3.0, 4.0];
        assert_eq!((quantile(&ys, 0.25), quantile(&ys, 0.5)), (1.75, 2.5));
    }
}
