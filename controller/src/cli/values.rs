//! The option values that are numbers, parsed with their allowed ranges: a value out of
//! range is refused by the parser with the range it must be in.

use bdft_controller::analysis::robustness::Range;
use bdft_controller::params::MAX_KBF;

fn parse_finite(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s} is not a finite number"))
    }
}

pub(super) fn parse_kbf(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if (0.0..=MAX_KBF).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{v} is out of range: K_BF must be in [0, {MAX_KBF}]"
        ))
    }
}

pub(super) fn parse_range(s: &str) -> Result<Range, String> {
    let (lo, hi) = s
        .split_once(',')
        .ok_or_else(|| format!("{s:?} is not a range: write LO,HI in percent, e.g. -20,20"))?;
    let (lo, hi) = (parse_finite(lo.trim())?, parse_finite(hi.trim())?);
    if lo <= hi {
        Ok(Range::pct(lo, hi))
    } else {
        Err(format!("{s}: LO must not exceed HI"))
    }
}

pub(super) fn parse_kbf_positive(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if v > 0.0 && v <= MAX_KBF {
        Ok(v)
    } else {
        Err(format!(
            "{v} is out of range: K_BF must be in (0, {MAX_KBF}]"
        ))
    }
}

pub(super) fn parse_duration(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if v > 0.0 && v <= 3600.0 {
        Ok(v)
    } else {
        Err(format!(
            "{v} is out of range: the duration must be in (0, 3600] seconds"
        ))
    }
}
