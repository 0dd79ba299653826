//! Probes: experiments on where a warm start's sweeps are, kept runnable so their findings can be
//! reproduced (docs/research). None is learned and none beats builtin to a tolerance.
//!
//! - [`history`]: from the contacts' history alone (`extrapolate`, `continue`, `builtin-reappear`);
//! - [`galerkin`]: the common start of the corrections by the step's own linear problem;
//! - [`subspace`]: along the previous solve's last sweeps (and a model's direction:
//!   `gnn-subspace`);
//! - [`coarse`]: within piecewise-uniform stress fields over cells;
//! - [`cg`]: a few conjugate-gradient iterations on builtin's active set.

pub mod cg;
pub mod coarse;
pub mod galerkin;
pub mod history;
pub mod subspace;

pub use cg::ConjugateGradient;
pub use coarse::Coarse;
pub use history::{BuiltinReappear, Continue, Extrapolate, MAX_CONTINUE_RATE};
pub use subspace::Subspace;
