//! The errors of the grid transfer, and what a particle stands for in them.

use std::fmt;

/// What a particle stands for, for error messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// A body, by id.
    Body(u32),
    /// A contact, by the ids of its two bodies.
    Contact {
        /// First body.
        body_a: u32,
        /// Second body.
        body_b: u32,
    },
    /// A synthetic particle, by index.
    Index(u32),
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Body(id) => write!(f, "body {id}"),
            Source::Contact { body_a, body_b } => write!(f, "contact between bodies {body_a} and {body_b}"),
            Source::Index(i) => write!(f, "particle {i}"),
        }
    }
}

/// Errors of the grid transfer.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SphError {
    /// A particle value or position is NaN or infinite.
    #[error("{particle}: {what} is {value}, not a finite number")]
    NonFinite {
        /// The body or contact it came from.
        particle: Source,
        /// The channel, or `x` / `y`.
        what: String,
        /// The offending value.
        value: f32,
    },
    /// A parameter out of range (kernel radius, spacing, bounds, names).
    #[error("bad parameter: {0}")]
    BadParameter(String),
    /// A particle with the wrong number of values.
    #[error("particle has {got} values, the set has {expected} channels")]
    ChannelCount {
        /// Channels of the set.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// An output buffer of the wrong size.
    #[error("output buffer holds {got} values, the grid needs {expected}")]
    OutputLength {
        /// Values the grid needs.
        expected: usize,
        /// Values the buffer holds.
        got: usize,
    },
    /// More channels than a `msgs::GridHeader` can name.
    #[error("{0} grid channels, at most {max} fit in a grid header", max = msgs::MAX_GRID_CHANNELS)]
    TooManyChannels(usize),
}
