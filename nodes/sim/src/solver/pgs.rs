//! The velocity solve: the projected Gauss-Seidel family, in the style of Box2D 2.3 (sequential
//! impulses), iterated from any warm start to a stopping rule with its sweeps counted.
//!
//! Apply the warm-start impulses to the velocities (Box2D's `WarmStart`), then sweeps over the
//! contact rows, each contact's tangent row (bounded by `mu * lambda_n`) before its normal row
//! (`lambda_n >= 0`). The family, all on the same rows, warm start and stopping rule:
//! - **PGS**: each row moves to its projected Gauss-Seidel target (the thesis's solver);
//! - **projected SOR**: each row moves `omega` times its step before projection;
//! - **NNCG** (Silcowitz, Niebe & Erleben 2010; Bullet's `btNNCGConstraintSolver`): after each
//!   sweep with change `dx`, `beta = |dx|^2 / |dx_prev|^2`; restart (`p = 0`) when beta exceeds
//!   the restart threshold, else `x += beta p` (projected onto the friction cone here, so the
//!   impulses stay feasible) and `p = beta p + dx`;
//! - rows visited in the recorded order (contact keys) or **top-down** (by contact height, top
//!   first: load flows down a pile within one sweep).
//!
//! Stopping rules ([`StopRule`]): the thesis's "largest impulse change of a sweep", or the
//! solver-independent **natural residual**: per row, what one projected Jacobi step would change
//! ([`NaturalResidual`]), checked after every sweep (a pass over the rows, counted in the solve's
//! time). No Baumgarte bias enters the velocity solve (restitution 0), so the converged impulses
//! solve the plain velocity-level LCP and can be checked against it.
//!
//! No Box2D block solver for two-point manifolds: every point is its own row, which keeps the
//! iteration count comparable across warm-start models and the complementarity check simple.
//! The solver owns only reusable buffers; bodies and contact rows are passed in.

use super::coarse::{CoarseSpace, Outcome};
use super::colour::{self, ColouredSolve, Colouring, Layout, SweepThreads};
use super::deadline::{deadline_after, past};
use super::krylov::KrylovSolver;
use super::newton::{
    NewtonError, NewtonParams, NewtonProblem, NewtonSolver, NewtonStats, Ordering, SecondOrder, CENTRED_START,
};
use super::rows::{ContactRow, Impulse, SolverBody};
use super::setting::AUTO_NEWTON_FROM;
use super::setting::{InteriorVariant, Method, Momentum, RowOrder, StopRule};
use super::sweep::{
    apply, momentum_row, natural_residual_rows, update_row, NaturalResidual, Prepared, SolveParams, SolveReport,
    SweepChange, TRAIL_SWEEPS,
};
use std::time::Instant;

/// A method outside the sweeps, which hands its impulses to them short of the tolerance.
#[derive(Debug, Clone, Copy)]
enum Outside {
    /// A sparse Cholesky per iteration ([`super::newton`]); the interior point in that variant.
    Newton(SecondOrder, InteriorVariant),
    /// Conjugate gradients on the QP ([`super::krylov`]).
    Mprgp,
}

/// Sequential-impulse contact solver: reusable buffers only, no world state.
#[derive(Debug, Default, Clone)]
pub struct ContactSolver {
    /// Row indices in the order the sweeps visit them; the work buffers below are in this order.
    visit: Vec<u32>,
    prepared: Vec<Prepared>,
    work: Vec<Impulse>,
    work_trail: Vec<[Impulse; TRAIL_SWEEPS]>,
    /// NNCG's search direction.
    direction: Vec<Impulse>,
    /// The final impulses, in row order.
    impulses: Vec<Impulse>,
    residuals: Vec<f32>,
    /// Each row's impulse changes in the last [`TRAIL_SWEEPS`] sweeps (the directions the
    /// iteration was still moving in: its slowest modes), most recent first, in row order.
    trail: Vec<[Impulse; TRAIL_SWEEPS]>,
    /// The Newton method's state (pattern, symbolic factorisation), kept across steps.
    newton: NewtonSolver,
    /// What the last solve's sparse Cholesky did (none: the last solve factorised nothing).
    newton_stats: Option<NewtonStats>,
    /// MPRGP's buffers.
    krylov: KrylovSolver,
    /// The impulses a second-order method hands the sweeps that finish its solve, and its
    /// velocities before they are handed to the caller.
    handed: Vec<Impulse>,
    solved: Vec<SolverBody>,
    /// The colour order's colours and its bodies' layout ([`colour`]).
    colouring: Colouring,
    layout: Layout,
    /// The threads the colour order runs on; none: the process's ([`colour::process_threads`]).
    threads: Option<SweepThreads>,
    /// The coarse correction's space and buffers ([`super::coarse`]), and the wall time the last
    /// solve spent in it (its setup and corrections).
    coarse: CoarseSpace,
    coarse_seconds: f64,
}

impl ContactSolver {
    /// An empty solver (buffers grow on first use).
    pub fn new() -> ContactSolver {
        ContactSolver::default()
    }

    /// An empty solver whose colour order runs on `threads` (not the process's).
    pub fn with_threads(threads: SweepThreads) -> ContactSolver {
        ContactSolver { threads: Some(threads), ..ContactSolver::default() }
    }

    /// The threads the colour order runs on.
    #[allow(clippy::redundant_closure)] // the closure shortens the process's 'static to self's
    pub fn threads(&self) -> &SweepThreads {
        self.threads.as_ref().unwrap_or_else(|| colour::process_threads())
    }

    /// Solves the velocity-level contact problem of `rows` starting from `warm_start` (one impulse
    /// per row), updating the body velocities in place. The final impulses are in
    /// [`Self::impulses`], the stopping rule's residual after every sweep in [`Self::residuals`].
    pub fn solve(
        &mut self,
        rows: &[ContactRow],
        bodies: &mut [SolverBody],
        warm_start: &[Impulse],
        params: &SolveParams,
    ) -> SolveReport {
        let deadline = deadline_after(params.time_budget_us);
        self.newton_stats = None;
        self.coarse_seconds = 0.0;
        self.solve_until(rows, bodies, warm_start, &params.for_start(warm_start), deadline)
    }

    /// [`Self::solve`] with an absolute stopping rule, stopping at `deadline` if one is given.
    fn solve_until(
        &mut self,
        rows: &[ContactRow],
        bodies: &mut [SolverBody],
        warm_start: &[Impulse],
        params: &SolveParams,
        deadline: Option<Instant>,
    ) -> SolveReport {
        assert_eq!(rows.len(), warm_start.len(), "one warm-start impulse per contact row");
        let outside = match params.method {
            Method::Newton => Some(Outside::Newton(SecondOrder::Proximal, InteriorVariant::default())),
            Method::InteriorPoint(variant) => Some(Outside::Newton(SecondOrder::InteriorPoint, variant)),
            Method::Auto => AUTO_NEWTON_FROM
                .is_some_and(|from| dynamic_bodies(bodies) >= from)
                .then_some(Outside::Newton(SecondOrder::InteriorPoint, InteriorVariant::default())),
            Method::Mprgp => Some(Outside::Mprgp),
            Method::Sweeps => None,
        };
        if let (Some(method), false) = (outside, rows.is_empty()) {
            match self.solve_outside(rows, bodies, warm_start, params, method, deadline) {
                Ok(report) if report.converged => return report,
                Ok(report) => {
                    // Short of the tolerance (the bodies untouched): the sweeps finish from its
                    // impulses; both counts are reported.
                    let handed = std::mem::replace(&mut self.impulses, std::mem::take(&mut self.handed));
                    let sweeps = params.with_setting(params.setting().sweeps());
                    let mut finished = self.solve_until(rows, bodies, &handed, &sweeps, deadline);
                    self.handed = handed;
                    finished.sweeps += report.sweeps;
                    finished.factorisations = report.factorisations;
                    return finished;
                }
                // The bodies are untouched: the sweeps solve the same problem.
                Err(e) => {
                    tracing::warn!(
                        "{} solver: {e}; this step is solved by {}",
                        params.setting(),
                        params.setting().sweeps()
                    )
                }
            }
        }
        self.visit.clear();
        self.visit.extend(0..rows.len() as u32);
        if matches!(params.order, RowOrder::Down | RowOrder::Colour) {
            // Top first; a stable sort keeps the recorded order between equal heights.
            self.visit.sort_by(|&i, &j| rows[j as usize].height.total_cmp(&rows[i as usize].height));
        }
        if params.order == RowOrder::Colour {
            self.colouring.colour(rows, bodies, &mut self.visit, colour::BANDS);
        }
        self.prepared.clear();
        self.prepared.extend(self.visit.iter().map(|&i| Prepared::of(&rows[i as usize], bodies)));
        self.work.clear();
        // A guess outside the friction cone (a learned model may predict a negative normal
        // impulse, or NaN) is projected onto it first: the sweeps assume normal >= 0.
        self.work.extend(self.prepared.iter().zip(&self.visit).map(|(c, &i)| {
            let w = warm_start[i as usize];
            let normal = if w.normal.is_finite() { w.normal.max(0.0) } else { 0.0 };
            let max_t = c.bound(normal);
            let tangent = if w.tangent.is_finite() { w.tangent.clamp(-max_t, max_t) } else { 0.0 };
            Impulse { normal, tangent }
        }));
        self.residuals.clear();
        self.work_trail.clear();
        self.work_trail.resize(self.work.len(), [Impulse::default(); TRAIL_SWEEPS]);

        // Box2D's WarmStart: the (projected) guess is applied as it is.
        for (c, l) in self.prepared.iter().zip(&self.work) {
            let p = c.n * l.normal + c.t * l.tangent;
            apply(bodies, c, p);
        }

        // The compliant update is the rigid one scaled by 1 / (1 + gamma): exactly 1 when rigid.
        let softness = 1.0 / (1.0 + params.compliance);
        let mut report = SolveReport::default();
        if self.prepared.is_empty() {
            report.converged = true;
            self.finish(&report);
            return report;
        }
        let restart = match params.momentum {
            Momentum::None => None,
            Momentum::Nncg { restart } => {
                self.direction.clear();
                self.direction.resize(self.work.len(), Impulse::default());
                Some(restart)
            }
        };
        if params.order == RowOrder::Colour {
            let threads = self.threads().clone();
            self.layout.gather(&mut self.prepared, bodies);
            let solve = ColouredSolve {
                prepared: &self.prepared,
                colouring: &self.colouring,
                work: &mut self.work,
                trail: &mut self.work_trail,
                direction: &mut self.direction,
                bodies: &mut self.layout.bodies,
            };
            let report = colour::sweep_coloured(solve, params, softness, deadline, &threads, &mut self.residuals);
            let report = closed(report, &self.prepared, &self.work, &self.layout.bodies, params, softness);
            self.layout.scatter(bodies);
            self.finish(&report);
            return report;
        }
        // The colour order, which has no correction (the spelling refuses it), returned above.
        let coarse = params.coarse;
        if let Some(correction) = coarse {
            let started = Instant::now();
            self.coarse.prepare(&self.prepared, bodies, correction.cell);
            self.coarse_seconds += started.elapsed().as_secs_f64();
        }
        let mut previous_squared = 0.0f64;
        while report.sweeps < params.max_sweeps && !past(deadline) {
            let slot = report.sweeps as usize % TRAIL_SWEEPS;
            // Plain Gauss-Seidel keeps its own loop: the unrelaxed solver bit for bit, at its speed.
            let change = if params.relaxation == 1.0 {
                self.sweep::<false>(bodies, slot, softness, 1.0)
            } else {
                self.sweep::<true>(bodies, slot, softness, params.relaxation)
            };
            if let Some(restart) = restart {
                // The first sweep has no earlier change: it starts the direction.
                let beta = if report.sweeps == 0 || previous_squared == 0.0 {
                    f64::INFINITY
                } else {
                    change.squared / previous_squared
                };
                self.momentum_step(bodies, slot, beta, restart as f64);
                previous_squared = change.squared;
            }
            report.sweeps += 1;
            let residual = match params.stop {
                StopRule::Change => change.max,
                StopRule::Natural | StopRule::Relative => {
                    report.natural = self.natural_residual(bodies, softness);
                    report.natural.max
                }
            };
            report.final_residual = residual;
            self.residuals.push(residual);
            if residual <= params.tolerance {
                report.converged = true;
                break;
            }
            if coarse.is_some_and(|c| report.sweeps % c.every == 0) {
                let started = Instant::now();
                let outcome = self.coarse.correct(&self.prepared, &mut self.work, bodies, softness);
                self.coarse_seconds += started.elapsed().as_secs_f64();
                match outcome {
                    Outcome::Kept => {
                        // The iterate jumped: NNCG's direction starts again from the next sweep.
                        report.corrections += 1;
                        self.direction.fill(Impulse::default());
                        previous_squared = 0.0;
                    }
                    Outcome::Dropped => report.corrections_dropped += 1,
                    Outcome::Empty => {}
                }
            }
        }
        let report = closed(report, &self.prepared, &self.work, bodies, params, softness);
        self.finish(&report);
        report
    }

    /// A solve by a method outside the sweeps; its iterations are the report's sweeps.
    fn solve_outside(
        &mut self,
        rows: &[ContactRow],
        bodies: &mut [SolverBody],
        warm_start: &[Impulse],
        params: &SolveParams,
        method: Outside,
        deadline: Option<Instant>,
    ) -> Result<SolveReport, NewtonError> {
        let problem = NewtonProblem {
            rows,
            bodies,
            warm_start,
            compliance: params.compliance,
            tolerance: params.tolerance,
            deadline,
        };
        self.solved.clear();
        self.solved.extend_from_slice(bodies);
        self.residuals.clear();
        let (iterations, factorisations) = match method {
            Outside::Newton(method, variant) => {
                let newton = NewtonParams {
                    method,
                    ordering: if variant.dissection { Ordering::Dissection } else { Ordering::MinimumDegree },
                    centred_start: variant.centred_start.then_some(CENTRED_START),
                    max_iterations: params.max_sweeps.min(NewtonParams::default().max_iterations),
                    ..NewtonParams::default()
                };
                let stats = self.newton.solve(&problem, &newton, &mut self.impulses, &mut self.solved)?;
                self.newton_stats = Some(stats);
                self.residuals.extend_from_slice(self.newton.residuals());
                (stats.iterations, stats.iterations)
            }
            Outside::Mprgp => {
                let stats = self.krylov.solve(&problem, params.max_sweeps, &mut self.impulses, &mut self.solved)?;
                self.residuals.extend_from_slice(self.krylov.residuals());
                (stats.iterations, 0)
            }
        };
        Ok(self.second_order_report(rows, bodies, params, iterations, factorisations))
    }

    /// A solve outside the sweeps done (its impulses in `impulses`, their velocities in
    /// `solved`, its residuals in `residuals`): the report on the natural residual of the f32
    /// impulses; the velocities go to the caller only with a solution.
    fn second_order_report(
        &mut self,
        rows: &[ContactRow],
        bodies: &mut [SolverBody],
        params: &SolveParams,
        iterations: u32,
        factorisations: u32,
    ) -> SolveReport {
        self.prepared.clear();
        self.prepared.extend(rows.iter().map(|r| Prepared::of(r, &self.solved)));
        let natural =
            natural_residual_of(&self.prepared, &self.impulses, &self.solved, 1.0 / (1.0 + params.compliance));
        // The velocities go to the caller only with a solution; short of one, the sweeps that
        // finish start from the step's own.
        if natural.max <= params.tolerance {
            bodies.copy_from_slice(&self.solved);
        }
        self.trail.clear();
        self.trail.resize(rows.len(), [Impulse::default(); TRAIL_SWEEPS]);
        SolveReport {
            sweeps: iterations,
            converged: natural.max <= params.tolerance,
            final_residual: natural.max,
            natural,
            factorisations,
            ..SolveReport::default()
        }
    }

    /// The final impulses and trail back in row order, the trail's last sweep first.
    fn finish(&mut self, report: &SolveReport) {
        let newest = (report.sweeps as usize + TRAIL_SWEEPS - 1) % TRAIL_SWEEPS;
        self.impulses.clear();
        self.impulses.resize(self.work.len(), Impulse::default());
        self.trail.clear();
        self.trail.resize(self.work.len(), [Impulse::default(); TRAIL_SWEEPS]);
        for ((&i, l), ring) in self.visit.iter().zip(&self.work).zip(&self.work_trail) {
            self.impulses[i as usize] = *l;
            self.trail[i as usize] = std::array::from_fn(|j| ring[(newest + TRAIL_SWEEPS - j) % TRAIL_SWEEPS]);
        }
    }

    /// One projected Gauss-Seidel (or SOR) sweep, its changes written to slot `slot` of the trail.
    fn sweep<const RELAXED: bool>(
        &mut self,
        bodies: &mut [SolverBody],
        slot: usize,
        softness: f32,
        relaxation: f32,
    ) -> SweepChange {
        let mut change = SweepChange::default();
        for ((c, l), trail) in self.prepared.iter().zip(self.work.iter_mut()).zip(self.work_trail.iter_mut()) {
            let d = update_row::<RELAXED, _>(bodies, c, l, softness, relaxation);
            trail[slot] = d;
            change.add(d);
        }
        change
    }

    /// NNCG's vector update after a sweep whose changes are in trail slot `slot`: restart when
    /// `beta > restart`, else move `beta` along the direction (projected onto the friction cone,
    /// the velocities following) and extend the direction by the sweep's change.
    fn momentum_step(&mut self, bodies: &mut [SolverBody], slot: usize, beta: f64, restart: f64) {
        if beta.is_nan() || beta > restart {
            self.direction.fill(Impulse::default());
            return;
        }
        let beta = beta as f32;
        for (((c, l), p), trail) in
            self.prepared.iter().zip(self.work.iter_mut()).zip(self.direction.iter_mut()).zip(&self.work_trail)
        {
            momentum_row(bodies, c, l, p, trail[slot], beta);
        }
    }

    /// The natural residual of the current impulses and velocities.
    fn natural_residual(&self, bodies: &[SolverBody], softness: f32) -> NaturalResidual {
        natural_residual_of(&self.prepared, &self.work, bodies, softness)
    }

    /// What the last solve's sparse Cholesky did: its fill and where its time went (none when
    /// it factorised nothing).
    pub fn newton_stats(&self) -> Option<&NewtonStats> {
        self.newton_stats.as_ref()
    }

    /// The wall time the last solve spent in its coarse corrections (their setup included;
    /// 0 without), seconds.
    pub fn coarse_seconds(&self) -> f64 {
        self.coarse_seconds
    }

    /// The impulses of the last solve, one per row.
    pub fn impulses(&self) -> &[Impulse] {
        &self.impulses
    }

    /// The stopping rule's residual after every sweep of the last solve.
    pub fn residuals(&self) -> &[f32] {
        &self.residuals
    }

    /// Each row's impulse changes in the last [`TRAIL_SWEEPS`] sweeps of the last solve, most
    /// recent first (zero where it made fewer sweeps).
    pub fn trail(&self) -> &[[Impulse; TRAIL_SWEEPS]] {
        &self.trail
    }

    /// Row `i`'s impulse change in the last sweep of the last solve (zero without sweeps).
    pub fn last_change(&self, i: usize) -> Impulse {
        self.trail[i][0]
    }

    /// The last solve's rate of convergence: the geometric mean of the residual's ratio over (at
    /// most) its last [`RATE_WINDOW`] sweeps, in [0, 1]; 0 when it made fewer than two sweeps.
    /// PGS that has run for a while converges like its slowest mode, so the distance still to go
    /// is about `last_change * rate / (1 - rate)`.
    pub fn convergence_rate(&self) -> f32 {
        convergence_rate(&self.residuals)
    }
}

/// A sweeps' report completed: the natural residual of the final state where the stopping rule
/// did not measure it, and the start as the answer where not one sweep ran (out of time).
fn closed(
    mut report: SolveReport,
    prepared: &[Prepared],
    work: &[Impulse],
    bodies: &[SolverBody],
    params: &SolveParams,
    softness: f32,
) -> SolveReport {
    if params.stop == StopRule::Change || report.sweeps == 0 {
        report.natural = natural_residual_of(prepared, work, bodies, softness);
    }
    if report.sweeps == 0 {
        report.final_residual = report.natural.max;
        report.converged = report.natural.max <= params.tolerance;
    }
    report
}

/// The natural residual of `impulses` on `rows` with the velocities `bodies` they led to (the
/// solver's own measure, for checks from outside: a test, a recorded solution).
pub fn natural_residual(
    rows: &[ContactRow],
    bodies: &[SolverBody],
    impulses: &[Impulse],
    compliance: f32,
) -> NaturalResidual {
    let prepared: Vec<Prepared> = rows.iter().map(|r| Prepared::of(r, bodies)).collect();
    natural_residual_of(&prepared, impulses, bodies, 1.0 / (1.0 + compliance))
}

/// The natural residual of `impulses` on prepared rows (see [`NaturalResidual`]).
fn natural_residual_of(
    prepared: &[Prepared],
    impulses: &[Impulse],
    bodies: &[SolverBody],
    softness: f32,
) -> NaturalResidual {
    let (max, squared) = natural_residual_rows(prepared, impulses, bodies, softness);
    let parts = 2 * prepared.len().max(1);
    NaturalResidual { max, rms: (squared / parts as f64).sqrt() as f32 }
}

/// Bodies that move under impulses (a positive inverse mass or inertia).
fn dynamic_bodies(bodies: &[SolverBody]) -> usize {
    bodies.iter().filter(|b| b.moves()).count()
}

/// How many of the last sweeps [`ContactSolver::convergence_rate`] averages over.
pub const RATE_WINDOW: usize = 8;

/// See [`ContactSolver::convergence_rate`].
pub fn convergence_rate(residuals: &[f32]) -> f32 {
    let n = residuals.len();
    if n < 2 {
        return 0.0;
    }
    let m = (n - 1).min(RATE_WINDOW);
    let (first, last) = (residuals[n - 1 - m], residuals[n - 1]);
    if first <= 0.0 || !first.is_finite() || !last.is_finite() {
        return 0.0;
    }
    (last / first).powf(1.0 / m as f32).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::rows::fixtures::{ball, floor_row, lattice, stack};
    use crate::solver::rows::relative_velocity;
    use rapier2d::math::Vec2;

    /// A ball (mass 1, falling at 1 after gravity) on two contact rows at the same point: the
    /// rigid problem only fixes their sum, the compliant one has a single answer.
    fn twin_rows(warm: [f32; 2], compliance: f32) -> [f32; 2] {
        let row = floor_row(1);
        let mut bodies = [SolverBody::default(), ball(Vec2::new(0.0, -1.0))];
        let warm = warm.map(|normal| Impulse { normal, tangent: 0.0 });
        let params = SolveParams { tolerance: 1e-7, max_sweeps: 10_000, compliance, ..Default::default() };
        let mut s = ContactSolver::new();
        assert!(s.solve(&[row, row], &mut bodies, &warm, &params).converged);
        [s.impulses()[0].normal, s.impulses()[1].normal]
    }

    #[test]
    fn compliance_makes_the_solution_unique() {
        // Rigid: any split of the 1 that stops the ball solves it; PGS keeps the warm start's.
        let [a, b] = twin_rows([0.8, 0.0], 0.0);
        assert!((a + b - 1.0).abs() < 1e-5 && a > 0.7, "rigid from (0.8, 0): {a} {b}");
        let [a, b] = twin_rows([0.0, 0.0], 0.0);
        assert!((a + b - 1.0).abs() < 1e-5 && b < 1e-6, "rigid from 0: {a} {b}");
        // Compliance 0.1: each row (effective mass 1) asks u + 0.1 l = 0 with u = -1 + a + b,
        // so a = b = 1 / 2.1 from any start — the split is no longer the warm start's to choose.
        for warm in [[0.8, 0.0], [0.0, 0.0], [0.0, 3.0]] {
            let [a, b] = twin_rows(warm, 0.1);
            assert!((a - 1.0 / 2.1).abs() < 1e-5 && (b - 1.0 / 2.1).abs() < 1e-5, "{warm:?}: {a} {b}");
        }
    }

    #[test]
    fn the_natural_residual_is_what_one_projected_jacobi_step_would_change() {
        // Ball 1 slides at 2 and still approaches at 0.7 after a normal impulse of 0.3 (mass 1,
        // normal mass 1, tangent mass 1 / (1 + 2 * 0.5^2) = 2/3, friction 0.5); ball 2 rests
        // with no impulse (solved). By hand: normal |0.3 - max(0, 0.3 + 1 * 0.7)| = 0.7; tangent
        // |0 - clip(0 - 2/3 * 2, +-0.5 * 0.3)| = 0.15; ball 2 nothing.
        let rows = [floor_row(1), floor_row(2)];
        let bodies = [SolverBody::default(), ball(Vec2::new(2.0, -0.7)), ball(Vec2::ZERO)];
        let impulses = [Impulse { normal: 0.3, tangent: 0.0 }, Impulse::default()];
        let r = natural_residual(&rows, &bodies, &impulses, 0.0);
        assert!((r.max - 0.7).abs() < 1e-6, "{r:?}");
        let rms = ((0.7f64.powi(2) + 0.15f64.powi(2)) / 4.0).sqrt() as f32;
        assert!((r.rms - rms).abs() < 1e-6, "{r:?} vs {rms}");
        // Compliance 1 halves the step's target: normal |0.3 - (0.3 + 0.7) / 2| = 0.2.
        let r = natural_residual(&rows[..1], &bodies, &impulses[..1], 1.0);
        assert!((r.max - 0.2).abs() < 1e-6, "{r:?}");
    }

    #[test]
    fn a_warm_start_outside_the_friction_cone_is_projected_not_a_panic() {
        // A learned model may predict a negative normal impulse (or NaN); the solve must still
        // converge to the same answer as from zero.
        let row = floor_row(1);
        for guess in [
            Impulse { normal: -0.3, tangent: 0.2 },
            Impulse { normal: f32::NAN, tangent: 1.0 },
            Impulse { normal: 0.1, tangent: -9.0 },
        ] {
            let mut bodies = [SolverBody::default(), ball(Vec2::new(-5.0, -1.0))];
            let mut s = ContactSolver::new();
            let rep = s.solve(&[row], &mut bodies, &[guess], &SolveParams::default());
            assert!(rep.converged, "{guess:?}");
            let l = s.impulses()[0];
            assert!(
                (l.normal - 1.0).abs() < 1e-3 && (l.tangent.abs() - 0.5 * l.normal).abs() < 1e-4,
                "{guess:?} -> {l:?}"
            );
        }
    }

    #[test]
    fn single_contact_stops_the_approach_and_bounds_friction() {
        // Body 1 falls onto fixed body 0 while sliding: normal velocity -1, tangent 5.
        let mut bodies = [SolverBody::default(), ball(Vec2::new(-5.0, -1.0))];
        let row = ContactRow {
            body_a: 0,
            body_b: 1,
            ra: Vec2::ZERO,
            rb: Vec2::new(0.0, -0.5),
            normal: Vec2::Y,
            friction: 0.5,
            height: 0.0,
            friction_bound: None,
        };
        let mut s = ContactSolver::new();
        let rep = s.solve(&[row], &mut bodies, &[Impulse::default()], &SolveParams::default());
        assert!(rep.converged);
        let (vn, _vt) = relative_velocity(&row, &bodies);
        assert!(vn.abs() < 1e-4, "vn {vn}");
        let l = s.impulses()[0];
        assert!((l.normal - 1.0).abs() < 1e-3, "{l:?}");
        // Still sliding: friction at the cone boundary.
        assert!((l.tangent.abs() - 0.5 * l.normal).abs() < 1e-4, "{l:?}");
        // The last sweep's change is what the residual measured, and the trail holds the sweeps
        // before it in order.
        let d = s.last_change(0);
        assert_eq!(d.normal.abs().max(d.tangent.abs()), rep.final_residual);
        let n = s.residuals().len();
        for (k, change) in s.trail()[0].iter().enumerate() {
            let measured = if k < n { s.residuals()[n - 1 - k] } else { 0.0 };
            assert_eq!(change.normal.abs().max(change.tangent.abs()), measured, "sweep -{k} of {n}");
        }
    }

    #[test]
    fn convergence_rate_is_the_mean_ratio_of_the_last_sweeps() {
        let geometric: Vec<f32> = (0..30).map(|k| 0.9f32.powi(k)).collect();
        assert!((convergence_rate(&geometric) - 0.9).abs() < 1e-4);
        assert_eq!(convergence_rate(&[1.0]), 0.0, "one sweep says nothing");
        assert_eq!(convergence_rate(&[0.0, 0.0]), 0.0);
        assert_eq!(convergence_rate(&[1.0, f32::NAN]), 0.0);
        // Only the last RATE_WINDOW sweeps count: an early fast phase does not.
        let mut late = vec![1e3, 1.0];
        late.extend((1..=RATE_WINDOW as i32).map(|k| 0.5f32.powi(k)));
        assert!((convergence_rate(&late) - 0.5).abs() < 1e-4);
    }

    #[test]
    fn separating_contact_gets_no_impulse() {
        let mut bodies = [SolverBody::default(), ball(Vec2::new(0.0, 2.0))];
        let row = ContactRow { body_a: 0, body_b: 1, normal: Vec2::Y, friction: 0.5, ..Default::default() };
        let mut s = ContactSolver::new();
        let rep = s.solve(&[row], &mut bodies, &[Impulse { normal: 3.0, tangent: 1.0 }], &SolveParams::default());
        assert!(rep.converged);
        assert_eq!(s.impulses()[0], Impulse::default());
        assert!((bodies[1].v.y - 2.0).abs() < 1e-5);
    }

    /// Every member of the family the issue names, each under the natural rule.
    fn family() -> Vec<SolveParams> {
        [
            "pgs",
            "sor:1.4",
            "sor:0.8",
            "nncg",
            "pgs/down",
            "sor:1.4/down",
            "nncg/down",
            "mprgp",
            "pgs/colour",
            "nncg:1.2/colour",
        ]
        .iter()
        .map(|s| SolveParams {
            tolerance: 1e-6,
            max_sweeps: 10_000,
            stop: StopRule::Natural,
            ..SolveParams::default().with_setting(s.parse().unwrap())
        })
        .collect()
    }

    #[test]
    fn the_natural_residual_measures_a_known_violation() {
        let row = floor_row(1);
        let zero = Impulse::default();
        // Approaching at 1 with no impulse: the normal row is 1 (its effective mass) short.
        let r = natural_residual(&[row], &[SolverBody::default(), ball(Vec2::new(0.0, -1.0))], &[zero], 0.0);
        assert!((r.max - 1.0).abs() < 1e-6 && (r.rms - 0.5f32.sqrt()).abs() < 1e-6, "{r:?}");
        // Separating at 2 while pushing with 0.5: the push should be 0.
        let push = Impulse { normal: 0.5, tangent: 0.0 };
        let r = natural_residual(&[row], &[SolverBody::default(), ball(Vec2::new(0.0, 2.0))], &[push], 0.0);
        assert!((r.max - 0.5).abs() < 1e-6, "{r:?}");
        // Sliding at 3 with no friction: the tangent row wants the cone's edge, -mu * 1 = -0.5
        // (its mass, 1 / (1 + 2 * 0.5^2), would ask for -2 unbounded).
        let rest = Impulse { normal: 1.0, tangent: 0.0 };
        let r = natural_residual(&[row], &[SolverBody::default(), ball(Vec2::new(3.0, 0.0))], &[rest], 0.0);
        assert!((r.max - 0.5).abs() < 1e-6, "{r:?}");
        // At rest with the load carried: a solution, residual 0.
        let r = natural_residual(&[row], &[SolverBody::default(), ball(Vec2::ZERO)], &[rest], 0.0);
        assert_eq!(r, NaturalResidual::default());
    }

    #[test]
    fn every_solver_stops_a_stack_of_three_with_the_same_loads() {
        // The floor carries all three balls, the top contact one: unique impulses.
        for params in family() {
            let (mut bodies, rows) = stack(3, -0.1);
            let mut s = ContactSolver::new();
            let rep = s.solve(&rows, &mut bodies, &[Impulse::default(); 3], &params);
            assert!(rep.converged && rep.natural.max <= 1e-6, "{}: {rep:?}", params.setting());
            for (i, l) in s.impulses().iter().enumerate() {
                let load = 0.1 * (3 - i) as f32;
                assert!(
                    (l.normal - load).abs() < 1e-5 && l.tangent.abs() < 1e-6,
                    "{}: row {i} {l:?}",
                    params.setting()
                );
            }
            assert!(bodies[1..].iter().all(|b| b.v.length() < 1e-5), "{}: {bodies:?}", params.setting());
        }
    }

    #[test]
    fn every_solver_stops_a_ball_driven_into_a_corner_with_friction() {
        // Floor below, wall on the left (normal +x, its tangent (0, -1)); the ball moves into
        // both. Sticking at rest is feasible (wall 2, floor 1, no friction needed), so every
        // solver must bring it to rest with the natural residual ~0 (the impulses themselves
        // are not unique: friction can trade against the normals).
        let wall =
            ContactRow { ra: Vec2::ZERO, rb: Vec2::new(-0.5, 0.0), normal: Vec2::X, height: 0.5, ..floor_row(1) };
        for params in family() {
            let mut bodies = [SolverBody::default(), ball(Vec2::new(-2.0, -1.0))];
            let mut s = ContactSolver::new();
            let rep = s.solve(&[floor_row(1), wall], &mut bodies, &[Impulse::default(); 2], &params);
            assert!(rep.converged, "{}: {rep:?}", params.setting());
            let b = bodies[1];
            assert!(b.v.length() < 1e-5 && b.w.abs() < 1e-5, "{}: {b:?}", params.setting());
            let [floor, wall] = [s.impulses()[0], s.impulses()[1]];
            assert!(floor.normal > 0.0 && wall.normal > 0.0, "{}: {floor:?} {wall:?}", params.setting());
            assert!(floor.tangent.abs() <= 0.5 * floor.normal + 1e-6 && wall.tangent.abs() <= 0.5 * wall.normal + 1e-6);
        }
    }

    #[test]
    fn every_solver_stops_the_ball_on_the_floor() {
        for params in family() {
            let mut bodies = [SolverBody::default(), ball(Vec2::new(0.0, -1.0))];
            let mut s = ContactSolver::new();
            let rep = s.solve(&[floor_row(1)], &mut bodies, &[Impulse::default()], &params);
            assert!(rep.converged && (s.impulses()[0].normal - 1.0).abs() < 1e-6, "{}: {rep:?}", params.setting());
        }
    }

    #[test]
    fn nncg_that_always_restarts_is_pgs_bit_for_bit() {
        let (bodies, rows) = stack(12, -0.1);
        let warm: Vec<Impulse> = (0..12).map(|i| Impulse { normal: 0.05 * i as f32, tangent: 0.01 }).collect();
        let solve = |setting: &str| {
            let params =
                SolveParams { tolerance: 1e-6, ..SolveParams::default().with_setting(setting.parse().unwrap()) };
            let mut b = bodies.clone();
            let mut s = ContactSolver::new();
            let rep = s.solve(&rows, &mut b, &warm, &params);
            (rep, s.impulses().to_vec(), b, s.residuals().to_vec())
        };
        let pgs = solve("pgs");
        assert_eq!(solve("nncg:0"), pgs);
        // The real NNCG takes other steps (and here fewer sweeps: a stack is its best case).
        let nncg = solve("nncg");
        assert_ne!(nncg.1, pgs.1);
        assert!(nncg.0.sweeps < pgs.0.sweeps, "nncg {} vs pgs {}", nncg.0.sweeps, pgs.0.sweeps);
    }

    #[test]
    fn the_coarse_correction_reaches_the_same_solution_and_is_deterministic() {
        // A 20 x 15 lattice under the per-step law (a convex QP: its velocities are unique), solved
        // by NNCG top-down with and without corrections over 3 m cells every 4 sweeps.
        let (bodies, rows) = lattice(20, 15);
        let run = |setting: &str| {
            let params = SolveParams {
                tolerance: 1e-6,
                max_sweeps: 20_000,
                stop: StopRule::Natural,
                ..SolveParams::default().with_setting(setting.parse().unwrap())
            };
            let mut b = bodies.clone();
            let mut s = ContactSolver::new();
            let rep = s.solve(&rows, &mut b, &vec![Impulse::default(); rows.len()], &params);
            (rep, s.impulses().to_vec(), b)
        };
        let plain = run("nncg:1.2/down");
        let corrected = run("nncg:1.2/down/coarse:3:4");
        assert!(plain.0.converged && corrected.0.converged, "{:?} {:?}", plain.0, corrected.0);
        assert_eq!((plain.0.corrections, plain.0.corrections_dropped), (0, 0));
        assert!(corrected.0.corrections > 0, "{:?}", corrected.0);
        for (i, (p, c)) in plain.2.iter().zip(&corrected.2).enumerate() {
            assert!((p.v - c.v).length() < 1e-3 && (p.w - c.w).abs() < 1e-3, "body {i}: {p:?} vs {c:?}");
        }
        for (row, l) in rows.iter().zip(&corrected.1) {
            assert!(l.normal >= 0.0 && l.tangent.abs() <= row.friction_bound.unwrap() + 1e-6, "{l:?}");
        }
        assert_eq!(run("nncg:1.2/down/coarse:3:4"), corrected, "same rows, same bits");
        eprintln!("sweeps without {} with {} ({:?})", plain.0.sweeps, corrected.0.sweeps, corrected.0);
    }

    #[test]
    fn the_top_down_order_visits_higher_rows_first_and_is_deterministic() {
        // A stack at rest, listed bottom-up, and its top ball landing: visited top-down, each
        // sweep carries the blow the whole way down; in the recorded order only one row further.
        let (mut bodies, rows) = stack(20, 0.0);
        bodies[20].v.y = -1.0;
        let run = |order: RowOrder| {
            let params = SolveParams { tolerance: 1e-6, max_sweeps: 10_000, order, ..SolveParams::default() };
            let mut b = bodies.clone();
            let mut s = ContactSolver::new();
            let rep = s.solve(&rows, &mut b, &[Impulse::default(); 20], &params);
            (rep, s.impulses().to_vec(), b)
        };
        let (up, down) = (run(RowOrder::Recorded), run(RowOrder::Down));
        assert!(up.0.converged && down.0.converged);
        assert!(down.0.sweeps < up.0.sweeps, "down {:?}, recorded {:?}", down.0, up.0);
        assert_eq!(run(RowOrder::Down), down, "same rows, same order, same bits");
        // The impulses come back in row order whatever the visiting order: the same solution.
        for (i, (u, d)) in up.1.iter().zip(&down.1).enumerate() {
            assert!((u.normal - d.normal).abs() < 1e-4, "row {i}: {u:?} {d:?}");
        }
    }

    #[test]
    fn the_natural_rule_stops_on_the_natural_residual() {
        let (mut bodies, rows) = stack(8, -0.1);
        let params = SolveParams { stop: StopRule::Natural, ..SolveParams::default() };
        let mut s = ContactSolver::new();
        let rep = s.solve(&rows, &mut bodies, &[Impulse::default(); 8], &params);
        assert!(rep.converged && rep.final_residual == rep.natural.max && rep.natural.max <= params.tolerance);
        assert_eq!(natural_residual(&rows, &bodies, s.impulses(), 0.0), rep.natural);
        // The change rule's report measures its final state by the same residual.
        let (mut bodies, rows) = stack(8, -0.1);
        let rep = s.solve(&rows, &mut bodies, &[Impulse::default(); 8], &SolveParams::default());
        assert_eq!(natural_residual(&rows, &bodies, s.impulses(), 0.0), rep.natural);
    }

    #[test]
    fn the_relative_rule_scales_the_tolerance_by_the_starts_rms_impulse() {
        // A stack of 30 balls stopping (the bottom row carries 30x the top's load), started
        // from twice its solution: from a start of RMS impulse r, the relative rule at 1e-4 is
        // the natural rule at 1e-4 * r exactly.
        let (bodies, rows) = stack(30, -0.05);
        let warm: Vec<Impulse> = (0..30).map(|i| Impulse { normal: 0.1 * (30 - i) as f32, tangent: 0.01 }).collect();
        let sum: f64 = warm.iter().map(|l| (l.normal as f64).powi(2) + (l.tangent as f64).powi(2)).sum();
        let rms = (sum / 30.0).sqrt() as f32;
        let relative =
            SolveParams { stop: StopRule::Relative, tolerance: 1e-4, max_sweeps: 50_000, ..SolveParams::default() };
        let absolute = SolveParams { stop: StopRule::Natural, tolerance: 1e-4 * rms, ..relative };
        assert_eq!(relative.for_start(&warm), absolute);
        let run = |params: &SolveParams| {
            let mut b = bodies.clone();
            let mut s = ContactSolver::new();
            (s.solve(&rows, &mut b, &warm, params), s.impulses().to_vec())
        };
        let (rel, abs) = (run(&relative), run(&absolute));
        assert!(rel.0.converged && rel.0.natural.max <= 1e-4 * rms, "{:?}", rel.0);
        assert_eq!(rel, abs, "the same solve, bit for bit");
        // Looser than the absolute 1e-4 here (r > 1), so fewer sweeps.
        let strict = run(&SolveParams { stop: StopRule::Natural, ..relative });
        assert!(rms > 1.0 && rel.0.sweeps < strict.0.sweeps, "{rms} {:?} {:?}", rel.0, strict.0);
        // An all-zero start keeps the absolute tolerance.
        assert_eq!(relative.for_start(&[Impulse::default(); 30]).tolerance, 1e-4);
        assert_eq!(relative.for_start(&[Impulse { normal: f32::NAN, tangent: 0.0 }]).tolerance, 1e-4);
    }

    #[test]
    fn a_time_budget_stops_the_solve_and_reports_where_it_stood() {
        // 200 balls landing on a stack: far more sweeps than a microsecond allows.
        let (mut bodies, rows) = stack(200, 0.0);
        bodies[200].v.y = -5.0;
        let warm = vec![Impulse::default(); 200];
        for setting in ["pgs", "nncg:1.2", "ipm"] {
            let free =
                SolveParams { stop: StopRule::Natural, tolerance: 1e-6, max_sweeps: 100_000, ..SolveParams::default() }
                    .with_setting(setting.parse().unwrap());
            let hurried = SolveParams { time_budget_us: Some(1.0), ..free };
            let (mut b, mut s) = (bodies.clone(), ContactSolver::new());
            let done = s.solve(&rows, &mut b, &warm, &free);
            assert!(done.converged, "{setting}: {done:?}");
            let (mut b, mut s) = (bodies.clone(), ContactSolver::new());
            let cut = s.solve(&rows, &mut b, &warm, &hurried);
            assert!(!cut.converged && cut.sweeps < done.sweeps, "{setting}: {cut:?} vs {done:?}");
            // What it reports is the residual of the impulses and velocities it hands back.
            assert_eq!(natural_residual(&rows, &b, s.impulses(), 0.0), cut.natural, "{setting}");
            assert!(cut.natural.max > free.tolerance, "{setting}: {cut:?}");
        }
    }
}
