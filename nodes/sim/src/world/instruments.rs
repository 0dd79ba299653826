//! Measurement the world's stages call, apart from the simulation: none of it changes what the
//! world computes.
//!
//! - the step's exact solution (the oracle), for the reference models that ask for it;
//! - the shadow builtin solve: the same step solved from builtin's warm start on scratch
//!   velocities (the report's *same states vs builtin*);
//! - problem capture: the step's velocity problem as data (`problem/*`), optionally labelled
//!   with a reference solution;
//! - the solver menu: the same step solved from builtin's warm start by each of several solver
//!   settings, sweeps and time each (`dc study solvers`: solvers side by side on the
//!   same states);
//! - the error split: the warm start's error against the step's exact solution and builtin's,
//!   each split into its pile-wide and local part, and what the run's sweeps leave of each
//!   (`dc-sim --error-split`, [`ErrorSplit`]).
//!
//! All of them solve on scratch copies of the solver bodies with their own solver.

use crate::contact::{ContactPoint, ImpulseHistory};
use crate::problem::Problem;
use crate::solver::{ContactRow, ContactSolver, Impulse, SolveParams, SolveReport, SolverBody};
use msgs::{ErrorSplit, ProblemBody, ProblemContact, StepHeader};

/// The step as the instruments read it: its contacts, rows, bodies after external forces and the
/// contacts' history.
#[derive(Clone, Copy)]
pub(crate) struct StepView<'a> {
    pub header: StepHeader,
    pub contacts: &'a [ContactPoint],
    pub rows: &'a [ContactRow],
    pub bodies: &'a [SolverBody],
    pub history: &'a ImpulseHistory,
}

/// The instruments' solver, scratch and results.
#[derive(Default)]
pub(crate) struct Instruments {
    solver: ContactSolver,
    scratch_bodies: Vec<SolverBody>,
    /// builtin's warm start of the step, where each solve starts.
    start: Vec<Impulse>,
    exact: Vec<Impulse>,
    exact_report: Option<SolveReport>,
    /// Whether to capture each step's problem, and the reference solve's stopping rule if labelled.
    pub capture: Option<Option<SolveParams>>,
    /// Whether to solve each step from builtin's warm start too.
    pub shadow_builtin: bool,
    problem: Problem,
    /// Solver settings each step is also solved with, from builtin's warm start.
    pub menu: Vec<SolveParams>,
    /// One solver per menu setting, as a simulation keeps one: what a solver keeps from step to
    /// step (the interior point's symbolic analysis) is its own setting's.
    menu_solvers: Vec<ContactSolver>,
    menu_solves: Vec<MenuSolve>,
    /// Whether to split each step's warm-start error ([`Instruments::split_error`]).
    pub error_split: bool,
    split: Option<ErrorSplit>,
    split_scratch: SplitScratch,
}

/// The error split's buffers, reused from step to step.
#[derive(Default)]
struct SplitScratch {
    exact: Vec<Impulse>,
    fixed: Vec<bool>,
    error: Vec<Impulse>,
    smooth: Vec<Impulse>,
}

impl SplitScratch {
    /// `(smooth, rough)` sums of squares of `start - exact` (`exact` is this scratch's), split
    /// as the `smooth-error` / `rough-error` references split builtin's error.
    fn parts(&mut self, contacts: &[ContactPoint], start: &[Impulse]) -> (f64, f64) {
        use crate::contact::{smooth_over_contacts, SMOOTHING_PASSES};
        self.error.clear();
        self.error.extend(start.iter().zip(&self.exact).map(|(w, e)| minus(w, e)));
        smooth_over_contacts(contacts, &self.fixed, &self.error, SMOOTHING_PASSES, &mut self.smooth);
        let smooth: f64 = self.smooth.iter().map(squared).sum();
        let rough: f64 = self.error.iter().zip(&self.smooth).map(|(e, s)| squared(&minus(e, s))).sum();
        (smooth, rough)
    }

    /// The sum of squares of `impulses - exact`.
    fn distance(&self, impulses: &[Impulse]) -> f64 {
        impulses.iter().zip(&self.exact).map(|(l, e)| squared(&minus(l, e))).sum()
    }
}

/// An impulse's squared length (normal and tangent together).
fn squared(i: &Impulse) -> f64 {
    (i.normal as f64).powi(2) + (i.tangent as f64).powi(2)
}

/// `a - b`, normal and tangent.
fn minus(a: &Impulse, b: &Impulse) -> Impulse {
    Impulse { normal: a.normal - b.normal, tangent: a.tangent - b.tangent }
}

/// Solves the step from `start` with `params` on a scratch copy of its bodies; the impulses are in
/// `solver`.
fn solve_on_scratch(
    solver: &mut ContactSolver,
    scratch: &mut Vec<SolverBody>,
    step: StepView<'_>,
    start: &[Impulse],
    params: &SolveParams,
) -> SolveReport {
    scratch.clear();
    scratch.extend_from_slice(step.bodies);
    solver.solve(step.rows, scratch, start, params)
}

/// One solver setting's solve of a step, from builtin's warm start on scratch velocities.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MenuSolve {
    pub sweeps: u32,
    pub converged: bool,
    /// Wall time of the solve, microseconds (its setup, sweeps and residual passes).
    pub us: f32,
    /// The natural residual of its final impulses: max and RMS over the rows.
    pub natural_max: f32,
    pub natural_rms: f32,
    /// Sparse Cholesky factorisations, and the microseconds of the symbolic analysis (0 when
    /// the kept one served) and of the numeric factorisations with their solves (0 for sweeps).
    pub factorisations: u32,
    pub symbolic_us: f32,
    pub numeric_us: f32,
    /// Coarse corrections kept and dropped, and the microseconds spent in them (0 without).
    pub corrections: u32,
    pub corrections_dropped: u32,
    pub coarse_us: f32,
}

impl Instruments {
    /// Solves the step from builtin's warm start with `params` on scratch velocities; the
    /// impulses are in the solver.
    fn solve_from_builtin(&mut self, step: StepView<'_>, params: &SolveParams) -> SolveReport {
        self.builtin_start(step);
        solve_on_scratch(&mut self.solver, &mut self.scratch_bodies, step, &self.start, params)
    }

    /// builtin's warm start of the step (the previous step's impulses) into `start`.
    fn builtin_start(&mut self, step: StepView<'_>) {
        self.start.clear();
        self.start.resize(step.contacts.len(), Impulse::default());
        step.history.fill_previous(step.contacts, &mut self.start);
    }

    /// The step's exact solution: solved from builtin's warm start to the oracle's stopping rule.
    pub(crate) fn solve_exact(&mut self, step: StepView<'_>, oracle: &SolveParams) {
        self.exact_report = Some(self.solve_from_builtin(step, oracle));
        self.exact.clear();
        self.exact.extend_from_slice(self.solver.impulses());
    }

    /// The last exact solution computed.
    pub(crate) fn exact(&self) -> &[Impulse] {
        &self.exact
    }

    /// Forgets the last step's exact solve (a step whose model asked for none).
    pub(crate) fn clear_exact(&mut self) {
        self.exact_report = None;
    }

    /// The report of the last step's exact solve, if one ran.
    pub(crate) fn exact_report(&self) -> Option<SolveReport> {
        self.exact_report
    }

    /// The sweeps builtin's warm start takes on this step with the run's stopping rule.
    pub(crate) fn builtin_sweeps(&mut self, step: StepView<'_>, solve: &SolveParams) -> u32 {
        self.solve_from_builtin(step, solve).sweeps
    }

    /// Solves the step with every setting of the menu, each from builtin's warm start.
    pub(crate) fn solve_menu(&mut self, step: StepView<'_>) {
        self.menu_solves.clear();
        self.menu_solvers.resize_with(self.menu.len(), ContactSolver::default);
        self.builtin_start(step);
        for (params, solver) in self.menu.iter().zip(self.menu_solvers.iter_mut()) {
            let started = std::time::Instant::now();
            let report = solve_on_scratch(solver, &mut self.scratch_bodies, step, &self.start, params);
            let us = started.elapsed().as_secs_f32() * 1e6;
            let factor = solver.newton_stats();
            self.menu_solves.push(MenuSolve {
                sweeps: report.sweeps,
                converged: report.converged,
                us,
                natural_max: report.natural.max,
                natural_rms: report.natural.rms,
                factorisations: report.factorisations,
                symbolic_us: factor.map_or(0.0, |f| (f.symbolic_seconds * 1e6) as f32),
                numeric_us: factor.map_or(0.0, |f| (f.numeric_seconds * 1e6) as f32),
                corrections: report.corrections,
                corrections_dropped: report.corrections_dropped,
                coarse_us: (solver.coarse_seconds() * 1e6) as f32,
            });
        }
    }

    /// Splits the step's warm start `warm` ([`ErrorSplit`]): its error against the step's exact
    /// solution (the oracle's solve from builtin's warm start) and builtin's start's error, each
    /// into the part a few passes of averaging over the contact graph keep (pile-wide) and the
    /// rest; and what `solve`'s sweeps leave from each start (the part slow for the solver), as
    /// error against the exact solution and as the natural residual.
    /// Every solve runs on scratch velocities; a step without contacts has no split.
    pub(crate) fn split_error(
        &mut self,
        step: StepView<'_>,
        warm: &[Impulse],
        solve: &SolveParams,
        oracle: &SolveParams,
    ) {
        if step.contacts.is_empty() {
            self.split = None;
            return;
        }
        // The model that asked for this step's exact solution had it solved already (from
        // builtin's start, which is in `self.start`); else solve it: builtin's start lands in
        // `self.start`, the exact solution in the solver.
        let solved = self.exact_report.is_some();
        if !solved {
            self.solve_from_builtin(step, oracle);
        }
        let sc = &mut self.split_scratch;
        sc.exact.clear();
        sc.exact.extend_from_slice(if solved { &self.exact } else { self.solver.impulses() });
        sc.fixed.clear();
        sc.fixed.extend(step.bodies.iter().map(|b| b.inv_mass == 0.0));
        let (model_smooth, model_rough) = sc.parts(step.contacts, warm);
        let (builtin_smooth, builtin_rough) = sc.parts(step.contacts, &self.start);
        let left = |start: &[Impulse], solver: &mut ContactSolver, scratch: &mut Vec<SolverBody>| {
            let report = solve_on_scratch(solver, scratch, step, start, solve);
            (sc.distance(solver.impulses()), report.natural.rms as f64)
        };
        let (model_left, model_left_natural) = left(warm, &mut self.solver, &mut self.scratch_bodies);
        let (builtin_left, builtin_left_natural) = left(&self.start, &mut self.solver, &mut self.scratch_bodies);
        self.split = Some(ErrorSplit {
            model_smooth,
            model_rough,
            builtin_smooth,
            builtin_rough,
            model_left,
            builtin_left,
            model_left_natural,
            builtin_left_natural,
            n: step.contacts.len() as u64,
            steps: 1,
        });
    }

    /// The last step's error split, if measured.
    pub(crate) fn split(&self) -> Option<&ErrorSplit> {
        self.split.as_ref()
    }

    /// Forgets the last step's split (the instrument is off).
    pub(crate) fn clear_split(&mut self) {
        self.split = None;
    }

    /// The last step's menu solves, one per setting of the menu.
    pub(crate) fn menu_solves(&self) -> &[MenuSolve] {
        &self.menu_solves
    }

    /// The last captured problem.
    pub(crate) fn problem(&self) -> &Problem {
        &self.problem
    }

    /// Fills the problem from the step, before anything changes the velocities; with
    /// `reference`, labels it with the solution from builtin's warm start with those parameters.
    pub(crate) fn capture_problem(&mut self, step: StepView<'_>, solve: &SolveParams, reference: Option<SolveParams>) {
        let p = &mut self.problem;
        p.bodies.clear();
        p.bodies.extend(step.bodies.iter().map(|b| ProblemBody {
            v: b.v.into(),
            w: b.w,
            inv_mass: b.inv_mass,
            inv_inertia: b.inv_inertia,
        }));
        p.contacts.clear();
        let pasts = step.history.pasts(step.contacts.iter().map(|c| &c.key));
        for ((c, r), past) in step.contacts.iter().zip(step.rows).zip(pasts) {
            let pair = |i: Option<Impulse>| i.map_or([0.0; 2], |i| [i.normal, i.tangent]);
            p.contacts.push(ProblemContact {
                body_a: r.body_a,
                body_b: r.body_b,
                feature: c.key.feature,
                age: past.age,
                ra: r.ra.into(),
                rb: r.rb.into(),
                normal: r.normal.into(),
                friction: r.friction,
                penetration: c.penetration,
                previous: pair(past.previous),
                before_previous: pair(past.before_previous),
                reference: [f32::NAN; 2],
                height: r.height,
            });
        }
        p.header = crate::problem::header_of(step.header, p.bodies.len() as u32, solve);
        if let Some(params) = reference {
            let report = self.solve_from_builtin(step, &params);
            let p = &mut self.problem;
            for (c, l) in p.contacts.iter_mut().zip(self.solver.impulses()) {
                c.reference = [l.normal, l.tangent];
            }
            p.header.reference_tolerance = params.tolerance;
            p.header.reference_sweeps = report.sweeps;
            p.header.reference_converged = report.converged as u32;
        }
    }
}
