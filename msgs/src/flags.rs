//! Parsers of the binaries' numeric command-line flags, for clap's `value_parser`: a number is
//! finite and inside the flag's documented range, or it is refused when the flags are parsed
//! (clap's message naming the flag, exit status 2), so that a launch file's parameter check
//! refuses it too, before any node starts. `nan`, `inf`, `-1` and `1e308` never reach a node.
//!
//! ```
//! let max_hz = msgs::flags::f64_in(0.0, 10_000.0);
//! assert_eq!(max_hz("30"), Ok(30.0));
//! assert!(max_hz("nan").is_err() && max_hz("-1").is_err() && max_hz("1e308").is_err());
//! ```

/// The error of a number outside its range (`closed`: `[min, max]`, else `(min, max]`).
fn outside(min: f64, max: f64, closed: bool) -> String {
    format!("must be a finite number in {}{min}, {max}]", if closed { '[' } else { '(' })
}

/// A number `ok` accepts, or an error saying what it `must` be (`must be a finite number > 0,
/// got -1`): the one parser behind every range below and the simulator's own ranges.
pub fn number_where<T>(s: &str, ok: impl Fn(T) -> bool, must: &str) -> Result<T, String>
where
    T: std::str::FromStr + Copy + std::fmt::Display,
    T::Err: std::fmt::Display,
{
    match s.parse::<T>() {
        Ok(v) if ok(v) => Ok(v),
        Ok(v) => Err(format!("must be {must}, got {v}")),
        Err(e) => Err(e.to_string()),
    }
}

/// A finite number in `[min, max]` (`closed`) or `(min, max]`.
fn check<T>(s: &str, min: T, max: T, closed: bool) -> Result<T, String>
where
    T: std::str::FromStr + Copy + PartialOrd + Into<f64> + std::fmt::Display,
{
    match s.trim().parse::<T>() {
        Ok(v) if v.into().is_finite() && (v > min || (closed && v == min)) && v <= max => Ok(v),
        Ok(_) => Err(outside(min.into(), max.into(), closed)),
        Err(_) => Err(format!("not a number; {}", outside(min.into(), max.into(), closed))),
    }
}

/// A finite `f64` in `[min, max]`.
pub fn f64_in(min: f64, max: f64) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| check(s, min, max, true)
}

/// A finite `f64` in `(min, max]` (above `min`: `f64_above(0.0, ...)` is a positive number).
pub fn f64_above(min: f64, max: f64) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| check(s, min, max, false)
}

/// A finite `f32` in `[min, max]`.
pub fn f32_in(min: f32, max: f32) -> impl Fn(&str) -> Result<f32, String> + Clone + Send + Sync + 'static {
    move |s: &str| check(s, min, max, true)
}

/// A finite `f32` in `(min, max]`.
pub fn f32_above(min: f32, max: f32) -> impl Fn(&str) -> Result<f32, String> + Clone + Send + Sync + 'static {
    move |s: &str| check(s, min, max, false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_outside_their_range_or_not_finite_are_refused() {
        let positive = f64_above(0.0, 100.0);
        assert_eq!(positive("0.5"), Ok(0.5));
        assert_eq!(positive("100"), Ok(100.0));
        for bad in ["0", "-1", "nan", "NaN", "inf", "-inf", "1e308", "100.5", "abc", ""] {
            assert!(positive(bad).is_err(), "{bad}");
        }
        assert_eq!(positive("-1").unwrap_err(), "must be a finite number in (0, 100]");
        let share = f64_in(0.0, 0.5);
        assert_eq!(share("0"), Ok(0.0));
        assert_eq!(share("1e308").unwrap_err(), "must be a finite number in [0, 0.5]");
        let scale = f32_above(0.0, 1000.0);
        assert_eq!(scale("2"), Ok(2.0));
        // Beyond f32: infinite, refused.
        assert!(scale("1e39").is_err() && scale("nan").is_err());
        assert_eq!(f32_in(0.0, 1.0)("0"), Ok(0.0));
        assert!(f32_in(0.0, 1.0)("-0.1").is_err());
        assert_eq!(number_where::<f32>("-1", |v| v > 0.0, "> 0").unwrap_err(), "must be > 0, got -1");
        assert!(number_where::<f32>("x", |v| v > 0.0, "> 0").is_err());
    }
}
