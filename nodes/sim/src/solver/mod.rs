//! The contact solver: plain data in, impulses out. It owns only reusable buffers and never calls
//! back into the world (rapier's `dynamics/solver/` is the model).
//!
//! - [`rows`]: contact rows, solver bodies and impulses, and the row algebra every solver and
//!   warm-start model shares;
//! - [`pgs`]: the velocity phase, the projected Gauss-Seidel family (PGS, SOR, NNCG; recorded or
//!   top-down row order) iterated from any warm start to a stopping rule, its sweeps counted
//!   ([`ContactSolver::solve`]);
//! - [`newton`]: Newton's method with a sparse Cholesky per iteration (proximal augmented
//!   Lagrangian in body velocities): iterations that do not grow with the pile's depth;
//! - `dissection`: nested dissection of the contact graph from the bodies' positions, the
//!   interior point's elimination order under `ipm:nd`;
//! - [`krylov`]: MPRGP, conjugate gradients on the step's box-constrained QP (no factorisation);
//! - [`sweep`]: what both sweep paths share: the solve's parameters and report, a prepared row,
//!   one row's update, the natural residual of some rows;
//! - [`colour`]: the colour order: rows coloured so that a colour's rows share no moving body,
//!   each colour swept on all threads (`--threads`), the same bits on any thread count;
//! - `coarse`: the coarse correction between sweeps (`/coarse:S:K`): the step's problem on its
//!   active set solved within uniform stress fields over cells, kept when it lowers the energy;
//! - [`setting`]: which member of the family ([`SolverSetting`]) and which stopping rule, spelled
//!   as the command lines spell them;
//! - [`position`]: Box2D 2.3's position pass after integration ([`correct_positions`]);
//! - [`deadline`]: a solve's wall-time budget, checked by every method.

mod coarse;
pub mod colour;
#[cfg(test)]
mod colour_tests;
pub mod deadline;
mod dissection;
pub mod krylov;
pub mod newton;
#[cfg(test)]
mod newton_tests;
pub mod pgs;
mod placement;
pub mod position;
pub mod rows;
pub mod setting;
pub mod sweep;

pub(crate) use coarse::stress_parts;
pub use colour::{machine_cores, process_threads, set_process_threads, SweepThreads, ThreadsError, MAX_THREADS};
pub use krylov::{KrylovSolver, KrylovStats};
pub use newton::{
    NewtonError, NewtonParams, NewtonProblem, NewtonSolver, NewtonStats, Ordering, SecondOrder, CENTRED_START,
};
pub use pgs::{convergence_rate, natural_residual, ContactSolver, RATE_WINDOW};
pub use position::{correct_positions, measure, PoseBody, PositionGeometry, PositionParams, PositionRow};
pub use rows::{relative_velocity, row_masses, tangent_of, ContactRow, Impulse, SolverBody};
pub use setting::{
    parse_settings, CoarseCorrection, FrictionModel, InteriorVariant, Method, Momentum, RowOrder, SolverSetting,
    StopRule, AUTO_NEWTON_FROM,
};
pub use sweep::{NaturalResidual, SolveParams, SolveReport, TRAIL_SWEEPS};
