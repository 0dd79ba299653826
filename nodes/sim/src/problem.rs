//! The velocity problem of a step as data (`msgs::problem`): captured by the world before it
//! solves, and solved again from any warm start — exactly as the world solved it, so a recorded
//! problem re-solved from the warm start its run used takes the same sweeps. What a learned warm
//! start trains on, and the solver it can be judged by in the loop.

use crate::solver::{
    CoarseCorrection, ContactRow, ContactSolver, FrictionModel, Impulse, InteriorVariant, Method, Momentum, RowOrder,
    SolveParams, SolveReport, SolverBody, StopRule,
};
use msgs::{ProblemBody, ProblemContact, ProblemHeader, StepHeader};
use rapier2d::math::Vec2;

/// A step's problem: its header, bodies and contact rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Problem {
    pub header: ProblemHeader,
    pub bodies: Vec<ProblemBody>,
    pub contacts: Vec<ProblemContact>,
}

/// The solver's rows of a problem's contacts under `friction`.
pub fn rows_of(contacts: &[ProblemContact], friction: FrictionModel) -> Vec<ContactRow> {
    contacts
        .iter()
        .map(|c| ContactRow {
            body_a: c.body_a,
            body_b: c.body_b,
            ra: Vec2::from(c.ra),
            rb: Vec2::from(c.rb),
            normal: Vec2::from(c.normal),
            friction: c.friction,
            height: c.height,
            friction_bound: per_step_bound(friction, c.age > 0, c.friction, c.previous[0]),
        })
        .collect()
}

/// A row's fixed friction bound under `friction`: the per-step model's `mu * max(previous
/// normal, 0)` for a contact that existed in the previous step; `None` (the Box2D law) otherwise.
pub fn per_step_bound(friction: FrictionModel, existed: bool, mu: f32, previous_normal: f32) -> Option<f32> {
    (friction == FrictionModel::PerStep && existed).then(|| mu * previous_normal.max(0.0))
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
    let report = solver.solve(&rows_of(contacts, params.friction), &mut solver_bodies, warm, params);
    (report, solver.impulses().to_vec())
}

/// The header of a step's problem solved with `solve` (no reference yet).
pub fn header_of(step: StepHeader, bodies: u32, solve: &SolveParams) -> ProblemHeader {
    let (momentum, restart) = match solve.momentum {
        Momentum::None => (0, 0.0),
        Momentum::Nncg { restart } => (1, restart),
    };
    ProblemHeader {
        step,
        bodies,
        tolerance: solve.tolerance,
        max_sweeps: solve.max_sweeps,
        compliance: solve.compliance,
        relaxation: solve.relaxation,
        momentum,
        restart,
        order: match solve.order {
            RowOrder::Recorded => 0,
            RowOrder::Down => 1,
            RowOrder::Colour => 2,
        },
        stop: match solve.stop {
            StopRule::Change => 0,
            StopRule::Natural => 1,
            StopRule::Relative => 2,
        },
        method: match solve.method {
            Method::Sweeps => 0,
            Method::Newton => 1,
            Method::Auto => 2,
            Method::InteriorPoint(variant) => variant.code(),
            Method::Mprgp => 4,
        },
        friction: (solve.friction == FrictionModel::PerStep) as u32,
        coarse_cell: solve.coarse.map_or(0.0, |c| c.cell),
        coarse_every: solve.coarse.map_or(0, |c| c.every),
        ..ProblemHeader::default()
    }
}

impl Problem {
    /// The solver and stopping rule the step was solved with.
    pub fn params(&self) -> SolveParams {
        let h = &self.header;
        SolveParams {
            tolerance: h.tolerance,
            max_sweeps: h.max_sweeps,
            compliance: h.compliance,
            relaxation: msgs::recorded_relaxation(h.relaxation),
            momentum: if h.momentum == 1 { Momentum::Nncg { restart: h.restart } } else { Momentum::None },
            order: match h.order {
                1 => RowOrder::Down,
                2 => RowOrder::Colour,
                _ => RowOrder::Recorded,
            },
            stop: match h.stop {
                1 => StopRule::Natural,
                2 => StopRule::Relative,
                _ => StopRule::Change,
            },
            method: match h.method {
                1 => Method::Newton,
                2 => Method::Auto,
                4 => Method::Mprgp,
                code => match InteriorVariant::of_code(code) {
                    Some(variant) => Method::InteriorPoint(variant),
                    None => Method::Sweeps,
                },
            },
            friction: if h.friction == 1 { FrictionModel::PerStep } else { FrictionModel::Box },
            coarse: Some(CoarseCorrection { cell: h.coarse_cell, every: h.coarse_every }).filter(|c| c.is_valid()),
            // A recorded problem is re-solved to its tolerance, never against a clock.
            time_budget_us: None,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::SolverSetting;

    #[test]
    fn a_recorded_header_gives_back_the_solver_it_was_solved_with() {
        for setting in crate::solver::setting::SPELLED.into_iter().chain(["nncg:1.2/down"]) {
            let solve =
                SolveParams { stop: StopRule::Relative, friction: FrictionModel::PerStep, ..SolveParams::default() }
                    .with_setting(setting.parse::<SolverSetting>().unwrap());
            let problem =
                Problem { header: header_of(StepHeader::default(), 3, &solve), bodies: vec![], contacts: vec![] };
            assert_eq!(problem.params(), solve, "{setting}");
        }
    }
}
