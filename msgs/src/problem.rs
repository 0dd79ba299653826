//! The velocity-level contact problem of one step, as the solver is about to solve it: what a
//! learned warm start sees (and is trained on). Published on `problem/bodies` and
//! `problem/contacts` when the simulator runs with `--publish-problem`; with `--label-tolerance`
//! the contacts also carry a reference solution solved from builtin's warm start to that
//! tolerance.
//!
//! Re-solving a recorded problem from the warm start its run used reproduces that run's sweep
//! count exactly: every number the solver reads is here, bit for bit, in the order it visits
//! the contacts.

use crate::StepHeader;
use bytemuck::{Pod, Zeroable};
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use serde::{Deserialize, Serialize};

/// One body as the velocity solver sees it: its velocity after external forces (gravity) and
/// its inverse mass properties (0 for static and kinematic bodies). Index = body id.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::ProblemBody")]
pub struct ProblemBody {
    pub v: [f32; 2],
    pub w: f32,
    pub inv_mass: f32,
    pub inv_inertia: f32,
}

/// One contact row, in the order the solver visits them (sorted by key).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::ProblemContact")]
pub struct ProblemContact {
    pub body_a: u32,
    pub body_b: u32,
    /// The feature pair within the body pair (with the bodies: the contact's key across steps).
    pub feature: u32,
    /// Consecutive steps this contact existed before this one (0: new).
    pub age: u32,
    /// From body a's centre of mass to the contact point.
    pub ra: [f32; 2],
    /// From body b's centre of mass to the contact point.
    pub rb: [f32; 2],
    /// Unit normal from a to b; the tangent is `(n.y, -n.x)`.
    pub normal: [f32; 2],
    pub friction: f32,
    /// Overlap depth (positive when overlapping).
    pub penetration: f32,
    /// The previous step's final impulse (normal, tangent): builtin's warm start; 0 when new.
    pub previous: [f32; 2],
    /// The impulse two steps back; 0 when the contact did not exist then.
    pub before_previous: [f32; 2],
    /// The reference solution (normal, tangent) when the run labels its problems, NaN otherwise.
    pub reference: [f32; 2],
    /// Height of the contact point (world y): the top-down row order's key (0 in recordings
    /// made before it existed, where that order is the recorded one).
    #[serde(default)]
    pub height: f32,
}

/// The header of a step's contact rows: the stopping rule the step was solved with, and the
/// reference solve's if there is one.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::ProblemHeader")]
pub struct ProblemHeader {
    pub step: StepHeader,
    /// Bodies in the matching `problem/bodies` frame.
    pub bodies: u32,
    pub tolerance: f32,
    pub max_sweeps: u32,
    /// Tolerance of the reference solution (0: none).
    pub reference_tolerance: f32,
    /// Sweeps the reference solve took, and whether it reached its tolerance.
    pub reference_sweeps: u32,
    pub reference_converged: u32,
    /// Relative compliance of every contact row the step was solved with (0: rigid contacts;
    /// absent in recordings made before it existed).
    #[serde(default)]
    pub compliance: f32,
    /// Over-relaxation factor the step was solved with (1: projected Gauss-Seidel; 0: not
    /// recorded, see [`crate::recorded_relaxation`]).
    #[serde(default)]
    pub relaxation: f32,
    /// The solver's momentum step: 0 none, 1 NNCG with restart threshold `restart` (absent in
    /// older recordings: none).
    #[serde(default)]
    pub momentum: u32,
    #[serde(default)]
    pub restart: f32,
    /// Row order: 0 recorded, 1 top-down, 2 coloured (absent in older recordings: recorded).
    #[serde(default)]
    pub order: u32,
    /// Stopping rule: 0 the largest change of a sweep, 1 the natural residual, 2 the natural
    /// residual relative to the warm start's RMS impulse (absent in older recordings: the change
    /// rule, the only one then).
    #[serde(default)]
    pub stop: u32,
    /// How it was solved: 0 sweeps (the fields above), 1 Newton, 2 Newton from 200 dynamic
    /// bodies (absent in older recordings: sweeps).
    #[serde(default)]
    pub method: u32,
    /// The friction law of its rows: 0 Box2D's (`|t| <= mu n`), 1 the per-step bound
    /// (`mu` times the previous step's normal impulse for a contact that existed then; absent in
    /// older recordings: Box2D's).
    #[serde(default)]
    pub friction: u32,
    /// The coarse correction between sweeps: the side of its cells in metres (0: none; absent
    /// in older recordings: none) and the sweeps between corrections.
    #[serde(default)]
    pub coarse_cell: f32,
    #[serde(default)]
    pub coarse_every: u32,
}

/// A step's bodies of the problem.
pub type ProblemBodies = crate::Frame<StepHeader, ProblemBody>;
/// A step's contact rows of the problem.
pub type ProblemContacts = crate::Frame<ProblemHeader, ProblemContact>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_are_packed() {
        assert_eq!(std::mem::size_of::<ProblemBody>(), 20);
        assert_eq!(std::mem::size_of::<ProblemContact>(), 76);
        assert_eq!(std::mem::size_of::<ProblemHeader>() % 8, 0);
    }
}
