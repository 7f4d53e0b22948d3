//! Validation of user-supplied numbers.
//!
//! Every parameter a user can set (scene files, command line, viewer panels) passes through
//! [`check_range`] or one of its siblings, so a bad value is rejected with its name, the value
//! and the valid range, instead of turning into NaN somewhere downstream.

use std::fmt;

/// A parameter outside its valid range (or not finite).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{name} = {value} is out of range: expected {range}")]
pub struct ParamError {
    /// The parameter's name as the user knows it (e.g. `beta_r_deg`).
    pub name: String,
    /// The offending value, printed as given.
    pub value: String,
    /// The valid range in words (e.g. `0.5 <= beta_r_deg <= 45`).
    pub range: String,
}

impl ParamError {
    pub fn new(name: impl Into<String>, value: impl fmt::Display, range: impl Into<String>) -> Self {
        Self { name: name.into(), value: value.to_string(), range: range.into() }
    }
}

/// Checks `lo <= value <= hi` and finiteness; returns the value.
pub fn check_range(name: &str, value: f64, lo: f64, hi: f64) -> Result<f64, ParamError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(value)
    } else {
        Err(ParamError::new(name, value, format!("{lo} <= {name} <= {hi}")))
    }
}

/// Checks `value > 0` (strictly) and finiteness; returns the value.
pub fn check_positive(name: &str, value: f64) -> Result<f64, ParamError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(ParamError::new(name, value, format!("0 < {name} < infinity")))
    }
}

/// Checks an integer count `lo <= value <= hi`; returns the value.
pub fn check_count(name: &str, value: usize, lo: usize, hi: usize) -> Result<usize, ParamError> {
    if (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(ParamError::new(name, value, format!("{lo} <= {name} <= {hi}")))
    }
}

/// Checks every channel of an RGB value lies in `[lo, hi]`.
pub fn check_rgb(name: &str, value: crate::Rgb, lo: f64, hi: f64) -> Result<crate::Rgb, ParamError> {
    for c in value.to_array() {
        if !(c.is_finite() && c >= lo && c <= hi) {
            return Err(ParamError::new(
                name,
                format!("[{}, {}, {}]", value.x, value.y, value.z),
                format!("each channel in [{lo}, {hi}]"),
            ));
        }
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_nan_and_out_of_range_with_the_range_in_the_message() {
        let err = check_range("beta_r_deg", f64::NAN, 0.5, 45.0).unwrap_err();
        assert_eq!(err.to_string(), "beta_r_deg = NaN is out of range: expected 0.5 <= beta_r_deg <= 45");
        assert!(check_range("x", 46.0, 0.5, 45.0).is_err());
        assert!(check_range("x", 45.0, 0.5, 45.0).is_ok());
        assert!(check_positive("r", 0.0).is_err());
        assert!(check_positive("r", f64::INFINITY).is_err());
        assert!(check_count("n", 0, 1, 8).is_err());
        assert!(check_rgb("c", crate::Rgb::new(0.5, -0.1, 0.2), 0.0, 1.0).is_err());
    }
}
