//! Solver statistics: per-step records from `SolveStats`, aggregation per model, simulation and
//! step, and the evaluation report (CSV, markdown, PNG plots, one HTML page).
//!
//! The numbers follow the thesis's measurements (chapter 7.4-7.5) with its timing flaw fixed:
//! solve time and whole-step time are reported separately.
//!
//! [`phases`] splits runs into step ranges (where the sweeps are spent), with the sweeps histogram
//! and the accuracy -> sweeps table. The charts and the workspace's one quantile / median live in
//! the `charts` library (other nodes' reports use them too).

pub mod aggregate;
pub mod completeness;
pub mod merge;
pub mod phases;
pub mod report;

pub use aggregate::{Aggregate, ModelSummary, StepRecord};
pub use completeness::Completeness;
