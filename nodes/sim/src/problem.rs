//! The velocity problem of a step as data (`msgs::problem`): captured by the world before it
//! solves, and solved again from any warm start — exactly as the world solved it, so a recorded
//! problem re-solved from the warm start its run used takes the same sweeps. What a learned warm
//! start trains on, and the solver it can be judged by in the loop.

use crate::solver::{ContactRow, ContactSolver, Impulse, SolveParams, SolveReport, SolverBody};
use msgs::{ProblemBody, ProblemContact, ProblemHeader};
use rapier2d::math::Vec2;

/// A step's problem: its header, bodies and contact rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Problem {
    pub header: ProblemHeader,
    pub bodies: Vec<ProblemBody>,
    pub contacts: Vec<ProblemContact>,
}

/// The solver's rows of a problem's contacts.
pub fn rows_of(contacts: &[ProblemContact]) -> Vec<ContactRow> {
    contacts
        .iter()
        .map(|c| ContactRow {
            body_a: c.body_a,
            body_b: c.body_b,
            ra: Vec2::from(c.ra),
            rb: Vec2::from(c.rb),
            normal: Vec2::from(c.normal),
            friction: c.friction,
        })
        .collect()
}

/// The solver's bodies of a problem.
pub fn bodies_of(bodies: &[ProblemBody]) -> Vec<SolverBody> {
    bodies
        .iter()
        .map(|b| SolverBody { v: Vec2::from(b.v), w: b.w, inv_mass: b.inv_mass, inv_inertia: b.inv_inertia })
        .collect()
}

/// builtin's warm start of a problem (the previous step's impulses).
pub fn builtin_warm_start(contacts: &[ProblemContact]) -> Vec<Impulse> {
    contacts.iter().map(|c| Impulse { normal: c.previous[0], tangent: c.previous[1] }).collect()
}

/// Solves `bodies`/`contacts` from `warm` with `params`; returns the report and final impulses.
pub fn solve(
    bodies: &[ProblemBody],
    contacts: &[ProblemContact],
    warm: &[Impulse],
    params: &SolveParams,
) -> (SolveReport, Vec<Impulse>) {
    let mut solver_bodies = bodies_of(bodies);
    let mut solver = ContactSolver::new();
    let report = solver.solve(&rows_of(contacts), &mut solver_bodies, warm, params);
    (report, solver.impulses().to_vec())
}

impl Problem {
    /// The stopping rule the step was solved with.
    pub fn params(&self) -> SolveParams {
        SolveParams {
            tolerance: self.header.tolerance,
            max_sweeps: self.header.max_sweeps,
            compliance: self.header.compliance,
            relaxation: msgs::recorded_relaxation(self.header.relaxation),
        }
    }

    /// Solves the problem from `warm` with its own stopping rule.
    pub fn solve(&self, warm: &[Impulse]) -> (SolveReport, Vec<Impulse>) {
        solve(&self.bodies, &self.contacts, warm, &self.params())
    }

    /// The reference solution, if the problem carries one.
    pub fn reference(&self) -> Option<Vec<Impulse>> {
        (self.header.reference_tolerance > 0.0).then(|| {
            self.contacts.iter().map(|c| Impulse { normal: c.reference[0], tangent: c.reference[1] }).collect()
        })
    }
}
