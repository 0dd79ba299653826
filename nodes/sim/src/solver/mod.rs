//! The contact solver: plain data in, impulses out. It owns only reusable buffers and never calls
//! back into the world (rapier's `dynamics/solver/` is the model).
//!
//! - [`rows`]: contact rows, solver bodies and impulses, and the row algebra every solver and
//!   warm-start model shares;
//! - [`pgs`]: the velocity phase, projected Gauss-Seidel (or SOR) iterated to a tolerance from any
//!   warm start, its sweeps counted ([`ContactSolver::solve`]);
//! - [`position`]: Box2D 2.3's position pass after integration ([`correct_positions`]).

pub mod pgs;
pub mod position;
pub mod rows;

pub use pgs::{convergence_rate, ContactSolver, SolveParams, SolveReport, RATE_WINDOW, TRAIL_SWEEPS};
pub use position::{correct_positions, measure, PoseBody, PositionGeometry, PositionParams, PositionRow};
pub use rows::{relative_velocity, row_masses, tangent_of, ContactRow, Impulse, SolverBody};
