//! The Deep Contact simulator: seeded scenes, rapier2d for shapes and collision detection, a
//! Box2D-2.3-style sequential-impulse contact solver that starts from any warm start and iterates
//! to a tolerance, and the warm-start models the thesis compares.
//!
//! Why not rapier's own solver: rapier2d 0.36 takes no external warm start and reports no
//! iteration count, the two things this project measures. So rapier builds bodies, shapes, broad
//! and narrow phase ([`rapier2d::pipeline::CollisionPipeline`] only), and [`world::World`] moves the
//! bodies with [`solver::ContactSolver`].
//!
//! Three rooms, and what they stand on:
//! - [`solver`]: the contact solver — rows and their algebra, the PGS family (PGS, SOR, NNCG,
//!   top-down order) to a stopping rule (the change of a sweep, or the natural residual),
//!   Box2D's position pass; plain data in, impulses out;
//! - [`world`]: one step as named stages (collide, external forces, warm start, solve,
//!   integrate, correct positions), measurement in its own module;
//! - [`warm`]: the warm-start trait and registry, and the models in three groups: product,
//!   references (need the oracle), probes;
//! - [`scene`]: ball-box (thesis), drum, mixed; numpy-exact or native sampling;
//! - [`body`]: a body's state and mass properties (what the world moves and the models read);
//! - [`contact`]: contact keys and points, the impulse history across steps, smoothing over
//!   the contact graph;
//! - [`problem`]: the step's velocity problem as data (`problem/*` topics), re-solved exactly;
//! - [`run`]: the step loop of a run, its control messages, a sink for each step's outputs;
//! - [`source`]: grids from another node as warm starts, with the producer's fault handling;
//! - [`bus`]: the simulator as a node: its publishers, served models' inboxes, runs on the bus;
//! - [`cli`]: the flags every simulator program shares (scene and seeds, the solve);
//! - [`rng`]: MT19937 / numpy legacy `RandomState`, xoshiro256++.
//!
//! The studies that use the simulator (solvers side by side, the real-time regime, the
//! benchmark against rapier) live in their own crate, `study` (`dc study`), which uses this one
//! and never the other way round.

pub mod body;
pub mod bus;
pub mod cli;
pub mod contact;
pub mod error;
pub mod problem;
pub mod rng;
pub mod run;
pub mod scene;
pub mod solver;
pub mod source;
pub mod warm;
pub mod world;

pub use contact::{ContactKey, ContactPoint, ImpulseHistory, SolveTrail};
pub use error::SimError;
pub use msgs::StepStats;
pub use scene::{SamplerKind, Scene, SceneConfig, SceneKind};
pub use solver::{
    ContactSolver, Impulse, NaturalResidual, PositionParams, RowOrder, SolveParams, SolveReport, SolverSetting,
    StopRule,
};
pub use warm::{ModelFiles, ModelKind, ModelSpec, WarmStartModel, WarmStarter};
pub use world::{World, WorldParams};

use std::time::Duration;

/// Parses a seed list: `7`, `0..30` (exclusive), `0..=29`, or a comma list of those; the result
/// is sorted and without duplicates (downstream nodes rely on increasing simulation ids).
pub fn parse_seeds(s: &str) -> Result<Vec<u64>, SimError> {
    msgs::parse_seeds(s).map_err(|why| SimError::InvalidParameter { name: "seeds", value: s.to_string(), why })
}

/// Parses a grid deadline: `none` (lockstep: wait as long as it takes), or a duration such as
/// `20ms`, `0.5s`, `1500us`, or a plain number of milliseconds.
pub fn parse_deadline(s: &str) -> Result<Option<Duration>, SimError> {
    let t = s.trim();
    if t.eq_ignore_ascii_case("none") || t.eq_ignore_ascii_case("lockstep") {
        return Ok(None);
    }
    runtime::parse_duration(t).map(Some).map_err(|why| SimError::InvalidParameter {
        name: "deadline",
        value: s.to_string(),
        why: format!("{why}, or `none`"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_lists_parse() {
        assert_eq!(parse_seeds("0..3").unwrap(), vec![0, 1, 2]);
        assert_eq!(parse_seeds("0..=2,7,1").unwrap(), vec![0, 1, 2, 7]);
        assert_eq!(parse_seeds("29").unwrap(), vec![29]);
        assert!(parse_seeds("3..1").is_err());
        assert!(parse_seeds("x").unwrap_err().to_string().contains("seeds"));
    }

    #[test]
    fn deadlines_parse() {
        assert_eq!(parse_deadline("none").unwrap(), None);
        assert_eq!(parse_deadline("20ms").unwrap(), Some(Duration::from_millis(20)));
        assert_eq!(parse_deadline("0.5s").unwrap(), Some(Duration::from_millis(500)));
        assert_eq!(parse_deadline("15").unwrap(), Some(Duration::from_millis(15)));
        assert!(parse_deadline("soon").is_err());
    }
}
