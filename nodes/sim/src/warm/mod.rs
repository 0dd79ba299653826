//! Warm starts: where the solver's initial guess comes from, in three rooms.
//!
//! - [`model`]: what a model is — the [`WarmStartModel`] trait, its input and [`Needs`], and the
//!   [`WarmStarter`] that falls back to a named model (counted) when a model is unavailable;
//! - [`registry`]: every model by name ([`ModelKind`], [`ModelSpec`]) and the one place that
//!   builds a model from its spec;
//! - [`product`]: what a simulator user runs (`none`, `builtin`, `grid`, `unet`, `unet-delta`,
//!   `gnn`, `gnn-node`);
//! - [`references`]: the evaluation's instruments, built from the step's exact solution or
//!   deliberately poor (`copy*`, `copy-grid*`, `bad`, `random`, the oracle ablations);
//! - [`probes`]: research experiments on where the sweeps are (`extrapolate`, `continue`,
//!   `builtin-reappear`, `subspace`, `coarse`, `cg`, `gnn-subspace`).
//!
//! The solver never knows which model ran; no product model reads the oracle (tested in the
//! registry).

pub mod model;
pub mod probes;
pub mod product;
pub mod references;
pub mod registry;

pub use model::{
    ContactWarmSource, GridSource, Needs, SolvedStep, StepRows, Unavailable, WarmStartInput, WarmStartModel,
    WarmStarter,
};
pub use product::{Builtin, Constant, GnnModel, GnnNodeModel, GnnPipelinedModel, GridModel, ProblemSender};
pub use registry::{ModelFiles, ModelKind, ModelSpec, Served};
