//! The evaluation's references: instruments that bound and map what a warm start can gain. They
//! read the step's exact solution (the oracle), so no simulator can run them for real.
//!
//! - [`copies`]: the exact solution as it is, rounded or through the grid; `random`;
//! - [`ablations`]: the exact solution mixed with builtin's guess (`blend:F`, `noise:S`,
//!   `copy-persisting`, ...): the accuracy -> sweeps curve every model is placed on.

pub mod ablations;
pub mod copies;

pub use ablations::{Ablation, OracleAblation};
pub use copies::{Copy, Random};
