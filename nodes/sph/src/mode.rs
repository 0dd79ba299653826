//! The transfer's normalisation: how particle values become node values.
//!
//! Its own module because both the transfer (which is configured with it) and the scatter's inner
//! loops (which branch on it) need it: the dependency runs one way, transfer -> scatter -> kernel
//! and mode. The transfer module's documentation explains the two modes.

use crate::error::SphError;
use std::fmt;
use std::str::FromStr;

/// How particle values become node values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Thesis SPH: weights normalised per particle (sum over its nodes = 1); conserves totals,
    /// shrinks values.
    Sph,
    /// Shepard / SPH gather: weights normalised per node; preserves values.
    Preserving,
}

impl Mode {
    /// Both modes, in the order of the study's tables.
    pub const ALL: [Mode; 2] = [Mode::Sph, Mode::Preserving];
}

impl fmt::Display for Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Mode::Sph => "sph",
            Mode::Preserving => "preserving",
        })
    }
}

impl FromStr for Mode {
    type Err = SphError;
    /// `sph` or `preserving`.
    fn from_str(s: &str) -> Result<Mode, SphError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "sph" => Ok(Mode::Sph),
            "preserving" | "shepard" => Ok(Mode::Preserving),
            _ => Err(SphError::BadParameter(format!("unknown mode `{s}` (sph, preserving)"))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_print_and_parse_back() {
        for mode in Mode::ALL {
            assert_eq!(mode.to_string().parse::<Mode>().unwrap(), mode);
        }
        assert_eq!(" Shepard ".parse::<Mode>().unwrap(), Mode::Preserving);
        assert!("gather".parse::<Mode>().unwrap_err().to_string().contains("unknown mode `gather`"));
    }
}
