//! The one number format of every file analysts get (CSV exports, Parquet values, the
//! controller's record files): a value is rounded to its column's resolution (10^-decimals)
//! and to at most 12 significant digits, and written without trailing zeros. So float noise
//! such as a target mean of 4.7e-16 mm reads 0, never "4.7e-16", and a value never shows
//! digits finer than it was measured or computed (f64 carries 15–17).

/// Significant digits a value keeps at most, however many decimals its column allows.
pub const SIGNIFICANT_DIGITS: i32 = 12;

/// `x` as text: rounded to `decimals` decimals and to [`SIGNIFICANT_DIGITS`], trailing
/// zeros (and a trailing point) dropped, `-0` written `0`; NaN and infinities as `NaN`,
/// `inf`, `-inf` (what pandas and R read).
pub fn format_number(x: f64, decimals: u8) -> String {
    if !x.is_finite() {
        return match x {
            x if x.is_nan() => "NaN".into(),
            x if x > 0.0 => "inf".into(),
            _ => "-inf".into(),
        };
    }
    let magnitude = if x == 0.0 {
        0
    } else {
        x.abs().log10().floor() as i32
    };
    let places = i32::from(decimals)
        .min(SIGNIFICANT_DIGITS - 1 - magnitude)
        .max(0) as usize;
    let mut s = format!("{x:.places$}");
    if s.contains('.') {
        let kept = s.trim_end_matches('0').trim_end_matches('.').len();
        s.truncate(kept);
    }
    if s == "-0" {
        s.remove(0);
    }
    s
}

/// The value `format_number` writes, as a number (what a Parquet file stores, so that it
/// holds exactly what the CSV says).
pub fn round_number(x: f64, decimals: u8) -> f64 {
    if !x.is_finite() {
        return x;
    }
    format_number(x, decimals).parse().unwrap_or(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn float_noise_reads_zero_and_resolution_is_kept() {
        assert_eq!(format_number(4.7e-16, 6), "0");
        assert_eq!(format_number(-4.7e-16, 6), "0");
        assert_eq!(format_number(-0.0000004, 6), "0");
        assert_eq!(format_number(0.0000006, 6), "0.000001");
        assert_eq!(format_number(12.5, 4), "12.5");
        assert_eq!(format_number(-3.0, 4), "-3");
        assert_eq!(format_number(0.1 + 0.2, 6), "0.3");
        assert_eq!(
            format_number(f32::from_bits(0x42c8_3f7d) as f64, 4),
            "100.124"
        );
        assert_eq!(format_number(139.999, 3), "139.999");
        assert_eq!(format_number(f64::NAN, 3), "NaN");
        assert_eq!(format_number(f64::NEG_INFINITY, 3), "-inf");
    }

    #[test]
    fn at_most_twelve_significant_digits() {
        assert_eq!(format_number(1234567.123456789, 6), "1234567.12346");
        assert_eq!(format_number(123456789012345.0, 3), "123456789012345");
        assert_eq!(format_number(0.000123456789012345, 15), "0.000123456789012");
    }

    #[test]
    fn rounding_is_idempotent_so_parquet_matches_csv() {
        for &(x, d) in &[
            (4.7e-16, 6),
            (1.0 / 3.0, 6),
            (98765.4321987, 3),
            (-2.5e-5, 4),
        ] {
            let r = round_number(x, d);
            assert_eq!(format_number(r, d), format_number(x, d));
            assert_eq!(round_number(r, d), r);
        }
    }
}
