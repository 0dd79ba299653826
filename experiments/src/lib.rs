//! Studies behind Deep Contact's findings, kept apart from the product: nothing outside this
//! crate depends on it. What each experiment backs and how to run it: `experiments/README.md`.
//!
//! - [`sph_study`]: the SPH transfer-error study (binary `dc-sph-study`), which chose the grid
//!   transfer's mode and parameters;
//! - `dc-sim-diag` (binary only): the settled-pile convergence diagnostic;
//! - `tests/probes.rs`: the Python solver probes (`experiments/python/`) on a real recording.

pub mod sph_study;
