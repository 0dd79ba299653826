//! The Newton solver: a step's contact problem solved with a sparse Cholesky factorisation per
//! iteration, so that its iterations do not grow with the pile's depth as sweeps do.
//!
//! **Formulation** (the proximal point method on the contact impulses, i.e. the augmented
//! Lagrangian in body velocities; MuJoCo's primal Newton solver and Drake's SAP are this family).
//! The contact problem is the dual of `min_v 1/2 |v - v0|_M^2` under the rows' constraints. With
//! the outer iterate `lk` fixed, each row part's impulse is the projection
//! `l(u) = proj_K((lk - rho u) / (1 + rho R))` of a trial value (u the row's relative velocity,
//! `K` its interval: `[0, inf)` for a normal, `[-c, c]` for a tangent, `R` the compliance
//! `gamma / m`), and `v` minimises the convex, piecewise-quadratic, C^1 function
//! `L(v) = 1/2 |v - v0|_M^2 + sum psi(J v)` with `psi' = -l`. Newton on `L`: gradient
//! `M (v - v0) - J^T l(J v)`, Hessian `M + sum_free w J^T J` (w = rho / (1 + rho R) on each row part
//! whose trial value lies inside its interval) — symmetric positive definite however redundant
//! the contacts, so a jammed pile never makes it singular — and an exact line search on `L`
//! (its derivative along the step is monotone and piecewise linear). When `L`'s minimiser is
//! reached, `lk` moves to `l(J v)`: one outer iteration of the proximal point method, which
//! converges at a rate `1 / (1 + rho a)` on a mode of stiffness `a`, so a large `rho` (scaled by
//! each row's effective mass) takes the pile-wide modes that sweeps diffuse slowly in a few
//! outer iterations.
//!
//! **Friction.** Under the per-step model every row's tangent interval is fixed: the problem is a
//! convex QP and the method converges to it. Under the Box2D law the tangent interval
//! `mu * normal` follows the normal impulse, which the outer iteration updates (staggered): the
//! fixed point is the Box2D law's solution, but the coupling is not second order (the issue's
//! prototype stalled near 1e-3 at 400 bodies and more).
//!
//! **Work.** Everything inside is f64. The Hessian's pattern (blocks of body pairs in contact) is
//! the same for every iteration of a step, and across steps while the contact graph keeps its
//! body pairs: the symbolic factorisation (ordering, elimination tree, supernodes) is kept and
//! reused then ([`NewtonStats::symbolic_reused`]). The stopping rule is the PGS family's natural
//! residual of the unregularised problem (no regularisation is left at the solution: the
//! proximal term vanishes as the outer iteration converges).

// The per-dof loops index several parallel `[f64; 3]` arrays (velocity, mass, Jacobian) at once.
#![allow(clippy::needless_range_loop)]

use super::deadline::past;
use super::dissection::Dissection;
use super::rows::{cross, effective_mass, tangent_of, ContactRow, Impulse, SolverBody};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, LltRef, SymbolicCholesky, SymmetricOrdering};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{ColMut, Conj, Par, Side};
use rapier2d::math::Vec2;
use std::time::Instant;

/// Why a Newton solve was refused or failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NewtonError {
    #[error("contact row {row}: {what} is not finite")]
    NonFiniteRow { row: usize, what: &'static str },
    #[error("contact row {row}: body {body} is not one of the {bodies} bodies")]
    NoSuchBody { row: usize, body: u32, bodies: usize },
    #[error("body {body}: {what} is not finite")]
    NonFiniteBody { body: usize, what: &'static str },
    #[error("the sparse Cholesky factorisation failed: {0}")]
    Factorisation(String),
}

/// Which second-order method solves the step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SecondOrder {
    /// Newton on the proximal augmented Lagrangian in body velocities (outer proximal
    /// iterations, inner Newton steps with an exact line search).
    Proximal,
    /// A primal-dual interior-point method (Mehrotra's predictor-corrector) on the step's
    /// box-constrained QP in impulses, each iteration's system reduced to body velocities.
    InteriorPoint,
}

/// How the sparse Cholesky orders the body-velocity system and keeps its symbolic analysis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Ordering {
    /// faer's approximate minimum degree on the scalar pattern, the symbolic analysis kept while
    /// the step's body pairs are exactly the previous one's (`ipm`).
    #[default]
    MinimumDegree,
    /// Nested dissection of the contact graph from the bodies' positions
    /// ([`super::dissection`]), computed on bodies; the symbolic analysis kept while the step's
    /// body pairs are among the kept pattern's, which is rebuilt as the union of the new pairs
    /// and the kept ones (at most [`KEPT_PATTERN_SLACK`] more), so that a contact that comes
    /// and goes does not force a new analysis (`ipm:nd`).
    Dissection,
}

/// `Ordering::Dissection` keeps a pattern at most this factor larger (in body pairs) than the
/// step's own: the zeros of pairs not in contact cost fill, a new analysis costs an ordering.
pub const KEPT_PATTERN_SLACK: f64 = 1.1;

/// The Newton solver's tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonParams {
    pub method: SecondOrder,
    pub ordering: Ordering,
    /// The interior point's start: `None`, the warm start pushed a fixed way inside its bounds
    /// (`1e-2` of the largest impulse; slacks `1e-3` above the relative speeds); `Some(k)`, the
    /// warm start **centred**: each bound's gap and slack set so that their product is at least
    /// `k * tolerance * V` (V = 0.1 m/s, a falling body's speed gained in a few steps), the part
    /// moved inside only as far as that product needs. A good warm start then lies near the
    /// central path at a small duality measure, and the iterations it needs are few.
    pub centred_start: Option<f64>,
    /// The proximal weight `rho` per unit of a row's effective mass (a dimensionless stiffness:
    /// the outer iteration contracts a mode of relative stiffness `a` by `1 / (1 + rho a)`).
    pub rho: f64,
    /// Newton iterations (factorisations) per solve at most.
    pub max_iterations: u32,
    /// Newton iterations per outer iteration at most.
    pub max_inner: u32,
    /// The inner iteration stops when the gradient (momentum units) is below this fraction of the
    /// tolerance.
    pub inner_tolerance: f64,
    /// The first outer iteration's `rho`; each outer iteration multiplies it by `rho_growth` up
    /// to `rho` (continuation: a soft problem first, whose Newton steps cross few kinks).
    pub rho_start: f64,
    pub rho_growth: f64,
}

impl Default for NewtonParams {
    fn default() -> Self {
        NewtonParams {
            method: SecondOrder::InteriorPoint,
            ordering: Ordering::MinimumDegree,
            centred_start: None,
            rho: 1e4,
            max_iterations: 100,
            max_inner: 8,
            inner_tolerance: 0.01,
            rho_start: 1e4,
            rho_growth: 1.0,
        }
    }
}

/// What one Newton solve did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NewtonStats {
    /// Newton iterations: one factorisation and one line search each.
    pub iterations: u32,
    /// Outer (proximal) iterations.
    pub outer: u32,
    /// Whether the step's symbolic factorisation was the previous step's.
    pub symbolic_reused: bool,
    /// The factor's stored entries (its fill).
    pub factor_entries: usize,
    /// Seconds spent on the symbolic analysis (ordering included; 0 when reused) and on the
    /// numeric factorisations and their solves.
    pub symbolic_seconds: f64,
    pub numeric_seconds: f64,
    /// Whether the natural residual reached the tolerance.
    pub converged: bool,
    /// The natural residual's max over rows at the end (f64 arithmetic).
    pub natural_max: f64,
}

/// A row in f64: its bodies, Jacobians (normal, tangent; per body `(x, y, angular)`, body a's
/// negated), effective masses and friction law. Shared with MPRGP ([`super::krylov`]), which
/// leaves the Hessian's block fields alone.
#[derive(Debug, Clone, Copy)]
pub(super) struct Row {
    pub(super) a: usize,
    pub(super) b: usize,
    /// Jacobian rows: `[normal, tangent]`, each `[body a (3), body b (3)]`.
    pub(super) j: [[f64; 6]; 2],
    /// Effective masses `[normal, tangent]` (0 when both bodies are fixed).
    pub(super) mass: [f64; 2],
    mu: f64,
    fixed_bound: Option<f64>,
    /// Where the row's three Hessian blocks live in the block list: (a, a), (b, b), (a, b);
    /// `NONE` when a body is not a variable.
    blocks: [u32; 3],
    /// Whether body a's block comes first in the (a, b) block (it is the upper one).
    a_first: bool,
}

const NONE: u32 = u32::MAX;

/// The Newton solver's reusable state: the Hessian's pattern and symbolic factorisation, and
/// every work vector.
#[derive(Default)]
pub struct NewtonSolver {
    rows: Vec<Row>,
    /// Per body: its block (`NONE`: not a variable), mass per dof (`0`: that dof is fixed).
    block_of: Vec<u32>,
    mass: Vec<[f64; 3]>,
    /// The block pairs `(row block, column block)` of the Hessian's upper triangle, sorted by
    /// column then row: the pattern.
    pairs: Vec<(u32, u32)>,
    /// The previous step's pattern, to reuse its symbolic factorisation.
    symbolic_pairs: Vec<(u32, u32)>,
    symbolic_blocks: usize,
    symbolic_ordering: Ordering,
    symbolic: Option<SymbolicCholesky<usize>>,
    /// Nested dissection's buffers, its elimination order of blocks and the dofs' permutation.
    dissection: Dissection,
    elimination: Vec<u32>,
    perm_fwd: Vec<usize>,
    perm_inv: Vec<usize>,
    /// Time in numeric factorisations and solves during the current solve.
    numeric_seconds: f64,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    /// Per stored entry: its block pair and the element `p * 3 + q` in it.
    scatter: Vec<(u32, u8)>,
    values: Vec<f64>,
    block_values: Vec<[f64; 9]>,
    l_values: Vec<f64>,
    /// Scratch of the numeric factorisation and the solve, sized for the symbolic one.
    stack: Option<MemBuffer>,
    stack_bytes: usize,
    v0: Vec<[f64; 3]>,
    v: Vec<[f64; 3]>,
    direction: Vec<[f64; 3]>,
    rhs: Vec<f64>,
    /// The outer iterate and the trial impulses.
    lambda: Vec<[f64; 2]>,
    trial: Vec<[f64; 2]>,
    u: Vec<[f64; 2]>,
    jd: Vec<[f64; 2]>,
    /// Per row part: its weight in the Hessian (0: not in it).
    weights: Vec<[f64; 2]>,
    /// The interior-point method's bounds, dual slacks and steps, per row part.
    interior: Interior,
    /// Per row part: `rho * m`.
    rho: Vec<[f64; 2]>,
    /// The natural residual (max) after each outer iteration.
    residuals: Vec<f32>,
}

impl std::fmt::Debug for NewtonSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NewtonSolver").field("rows", &self.rows.len()).field("pairs", &self.pairs.len()).finish()
    }
}

impl Clone for NewtonSolver {
    /// A clone starts with empty buffers (they are only a cache).
    fn clone(&self) -> Self {
        NewtonSolver::default()
    }
}

/// The problem a solve is given, in the solver's terms.
pub struct NewtonProblem<'a> {
    pub rows: &'a [ContactRow],
    pub bodies: &'a [SolverBody],
    pub warm_start: &'a [Impulse],
    /// Relative compliance `gamma` of every row (see `SolveParams::compliance`).
    pub compliance: f32,
    /// Natural residual (max over rows) to reach.
    pub tolerance: f32,
    /// Stop at the first check past this instant (the real-time regime), converged or not.
    pub deadline: Option<Instant>,
}

impl NewtonSolver {
    pub fn new() -> NewtonSolver {
        NewtonSolver::default()
    }

    /// Solves `problem` from its warm start; the impulses go to `impulses` (row order) and the
    /// bodies' velocities to `bodies`. Refuses a problem with a non-finite value or a row naming
    /// a body that is not there, before touching anything.
    pub fn solve(
        &mut self,
        problem: &NewtonProblem<'_>,
        params: &NewtonParams,
        impulses: &mut Vec<Impulse>,
        bodies: &mut [SolverBody],
    ) -> Result<NewtonStats, NewtonError> {
        check(problem.rows, problem.bodies)?;
        let mut stats = NewtonStats::default();
        self.setup(problem);
        let analysis = Instant::now();
        stats.symbolic_reused = self.prepare_pattern(problem.rows, params.ordering)?;
        if !stats.symbolic_reused {
            stats.symbolic_seconds = analysis.elapsed().as_secs_f64();
        }
        stats.factor_entries = self.l_values.len();
        self.numeric_seconds = 0.0;
        self.solve_method(problem, params, &mut stats, impulses, bodies)?;
        stats.numeric_seconds = self.numeric_seconds;
        Ok(stats)
    }

    /// The solve proper, by `params.method`, on the prepared pattern.
    fn solve_method(
        &mut self,
        problem: &NewtonProblem<'_>,
        params: &NewtonParams,
        stats: &mut NewtonStats,
        impulses: &mut Vec<Impulse>,
        bodies: &mut [SolverBody],
    ) -> Result<(), NewtonError> {
        if params.method == SecondOrder::InteriorPoint {
            self.interior_point(problem, params, stats)?;
            self.finish(impulses, bodies);
            return Ok(());
        }
        let softness = 1.0 / (1.0 + problem.compliance as f64);
        let compliance = problem.compliance as f64;
        self.residuals.clear();
        let tolerance = problem.tolerance as f64;
        // The start: the projected warm start and the velocities it gives.
        self.velocities_of_lambda();
        let mut residual = self.natural_residual(softness);
        self.residuals.push(residual as f32);
        // An outer iteration without a Newton step (the velocities already minimise L) still
        // moves the impulses; bounded all the same.
        let max_outer = 2 * params.max_iterations;
        let (mut rho, mut weighted) = (params.rho_start.min(params.rho), f64::NAN);
        while residual > tolerance
            && stats.iterations < params.max_iterations
            && stats.outer < max_outer
            && !past(problem.deadline)
        {
            stats.outer += 1;
            if rho != weighted {
                self.set_rho(rho);
                weighted = rho;
            }
            rho = (rho * params.rho_growth).min(params.rho);
            // Inner: Newton on L for this outer iterate.
            for _ in 0..params.max_inner {
                if stats.iterations >= params.max_iterations || past(problem.deadline) {
                    break;
                }
                let gradient_max = self.gradient(compliance);
                if gradient_max <= params.inner_tolerance * tolerance {
                    break;
                }
                self.factorise_and_solve(compliance)?;
                stats.iterations += 1;
                let alpha = self.line_search(compliance);
                for (v, d) in self.v.iter_mut().zip(&self.direction) {
                    for k in 0..3 {
                        v[k] += alpha * d[k];
                    }
                }
            }
            // Outer: the impulses move to the trial values at the minimiser.
            self.relative_velocities();
            self.trial_impulses(compliance);
            std::mem::swap(&mut self.lambda, &mut self.trial);
            self.velocities_of_lambda();
            residual = self.natural_residual(softness);
            self.residuals.push(residual as f32);
        }
        stats.converged = residual <= tolerance;
        stats.natural_max = residual;
        self.finish(impulses, bodies);
        Ok(())
    }

    /// Hands the impulses (f32) and the velocities they give to the caller.
    fn finish(&mut self, impulses: &mut Vec<Impulse>, bodies: &mut [SolverBody]) {
        impulses.clear();
        impulses.extend(self.lambda.iter().map(|l| Impulse { normal: l[0] as f32, tangent: l[1] as f32 }));
        // The velocities of the f32 impulses the caller gets, so that its residual is theirs.
        for (l, out) in self.lambda.iter_mut().zip(impulses.iter()) {
            *l = [out.normal as f64, out.tangent as f64];
        }
        self.velocities_of_lambda();
        for (b, v) in bodies.iter_mut().zip(&self.v) {
            b.v = Vec2::new(v[0] as f32, v[1] as f32);
            b.w = v[2] as f32;
        }
    }

    /// Each row part's proximal weight: `rho` times its effective mass.
    fn set_rho(&mut self, rho: f64) {
        self.rho.clear();
        self.rho.extend(self.rows.iter().map(|r| r.mass.map(|m| rho * m)));
    }

    /// The natural residual after each outer iteration of the last solve (the start first).
    pub fn residuals(&self) -> &[f32] {
        &self.residuals
    }

    /// Rows, bodies, masses and the projected warm start in f64.
    fn setup(&mut self, problem: &NewtonProblem<'_>) {
        let bodies = problem.bodies;
        self.block_of.clear();
        self.mass.clear();
        self.v0.clear();
        let mut blocks = 0u32;
        for b in bodies {
            let inv = [b.inv_mass as f64, b.inv_mass as f64, b.inv_inertia as f64];
            self.mass.push(inv.map(|i| if i > 0.0 { 1.0 / i } else { 0.0 }));
            if inv.iter().any(|&i| i > 0.0) {
                self.block_of.push(blocks);
                blocks += 1;
            } else {
                self.block_of.push(NONE);
            }
            self.v0.push([b.v.x as f64, b.v.y as f64, b.w as f64]);
        }
        self.rows.clear();
        self.rows.extend(problem.rows.iter().map(|r| Row::of(r, bodies)));
        // The warm start projected onto the rows' intervals (a learned guess may be outside).
        self.lambda.clear();
        self.lambda.extend(self.rows.iter().zip(problem.warm_start).map(|(r, w)| r.projected(w)));
        let dofs = blocks as usize;
        self.v.clear();
        self.v.extend_from_slice(&self.v0);
        self.direction.clear();
        self.direction.resize(bodies.len(), [0.0; 3]);
        self.rhs.clear();
        self.rhs.resize(3 * dofs, 0.0);
        let n = self.rows.len();
        for buf in [&mut self.trial, &mut self.u, &mut self.jd, &mut self.weights] {
            buf.clear();
            buf.resize(n, [0.0; 2]);
        }
    }

    /// The Hessian's block pattern; builds the CSC structure and, unless the kept symbolic
    /// factorisation covers the pattern (`ordering`: the same pattern, or one among the kept
    /// pairs), a new one. Returns whether the symbolic one was reused.
    fn prepare_pattern(&mut self, contacts: &[ContactRow], ordering: Ordering) -> Result<bool, NewtonError> {
        let blocks = self.mass.iter().zip(&self.block_of).filter(|(_, &b)| b != NONE).count();
        self.pairs.clear();
        self.pairs.extend((0..blocks as u32).map(|k| (k, k)));
        for r in &self.rows {
            let (ka, kb) = (self.block_of[r.a], self.block_of[r.b]);
            if ka != NONE && kb != NONE && ka != kb {
                self.pairs.push((ka.min(kb), ka.max(kb)));
            }
        }
        // Sorted by column block, then row block: the CSC order.
        self.pairs.sort_unstable_by_key(|&(i, j)| (j, i));
        self.pairs.dedup();
        let kept = self.symbolic.is_some() && self.symbolic_blocks == blocks && self.symbolic_ordering == ordering;
        let reuse = match ordering {
            Ordering::MinimumDegree => kept && self.symbolic_pairs == self.pairs,
            Ordering::Dissection => kept && is_subset(&self.pairs, &self.symbolic_pairs),
        };
        if reuse {
            // The kept pattern, its extra pairs stored as zeros.
            self.pairs.clone_from(&self.symbolic_pairs);
        } else if ordering == Ordering::Dissection && kept {
            let union = sorted_union(&self.pairs, &self.symbolic_pairs);
            if union.len() as f64 <= KEPT_PATTERN_SLACK * self.pairs.len() as f64 {
                self.pairs = union;
            }
        }
        let find = |pairs: &[(u32, u32)], i: u32, j: u32| {
            pairs.binary_search_by_key(&(j, i), |&(r, c)| (c, r)).map(|k| k as u32).unwrap_or(NONE)
        };
        for r in self.rows.iter_mut() {
            let (ka, kb) = (self.block_of[r.a], self.block_of[r.b]);
            let diag = |k: u32| if k == NONE { NONE } else { find(&self.pairs, k, k) };
            let off =
                if ka != NONE && kb != NONE && ka != kb { find(&self.pairs, ka.min(kb), ka.max(kb)) } else { NONE };
            r.blocks = [diag(ka), diag(kb), off];
            r.a_first = ka < kb;
        }
        // CSC of the upper triangle: column (block j, q) holds rows (block i, p) for every pair
        // (i, j), all three p for i < j and p <= q on the diagonal block.
        let dofs = 3 * blocks;
        self.col_ptr.clear();
        self.row_idx.clear();
        self.scatter.clear();
        self.col_ptr.push(0);
        let mut start = 0;
        for j in 0..blocks as u32 {
            let end = start + self.pairs[start..].iter().take_while(|p| p.1 == j).count();
            for q in 0..3u8 {
                for (k, &(i, _)) in self.pairs[start..end].iter().enumerate() {
                    let rows = if i == j { q + 1 } else { 3 };
                    for p in 0..rows {
                        self.row_idx.push(3 * i as usize + p as usize);
                        self.scatter.push(((start + k) as u32, p * 3 + q));
                    }
                }
                self.col_ptr.push(self.row_idx.len());
            }
            start = end;
        }
        self.values.clear();
        self.values.resize(self.row_idx.len(), 0.0);
        self.block_values.clear();
        self.block_values.resize(self.pairs.len(), [0.0; 9]);
        if reuse {
            return Ok(true);
        }
        let structure = SymbolicSparseColMatRef::new_checked(dofs, dofs, &self.col_ptr, None, &self.row_idx);
        let order = match ordering {
            Ordering::MinimumDegree => SymmetricOrdering::Amd,
            Ordering::Dissection => {
                self.dissection.order(blocks, &self.pairs, contacts, &self.block_of, &mut self.elimination);
                // Block k-th eliminated -> dofs 3k, 3k + 1, 3k + 2 (forward: new index to old).
                self.perm_fwd.clear();
                self.perm_fwd.extend(self.elimination.iter().flat_map(|&b| (0..3).map(move |p| 3 * b as usize + p)));
                self.perm_inv.clear();
                self.perm_inv.resize(dofs, 0);
                for (new, &old) in self.perm_fwd.iter().enumerate() {
                    self.perm_inv[old] = new;
                }
                SymmetricOrdering::Custom(PermRef::new_checked(&self.perm_fwd, &self.perm_inv, dofs))
            }
        };
        let symbolic = factorize_symbolic_cholesky(structure, Side::Upper, order, Default::default())
            .map_err(|e| NewtonError::Factorisation(format!("{e:?}")))?;
        let need = symbolic
            .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default())
            .or(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
        let bytes = need.unaligned_bytes_required();
        if self.stack.is_none() || self.stack_bytes < bytes {
            self.stack = Some(MemBuffer::try_new(need).map_err(|e| NewtonError::Factorisation(format!("{e:?}")))?);
            self.stack_bytes = bytes;
        }
        self.l_values.clear();
        self.l_values.resize(symbolic.len_val(), 0.0);
        self.symbolic = Some(symbolic);
        self.symbolic_pairs.clone_from(&self.pairs);
        self.symbolic_blocks = blocks;
        self.symbolic_ordering = ordering;
        Ok(false)
    }

    /// `v = v0 + M^-1 J^T lambda`.
    fn velocities_of_lambda(&mut self) {
        self.v.copy_from_slice(&self.v0);
        for (r, l) in self.rows.iter().zip(&self.lambda) {
            for (body, offset) in [(r.a, 0), (r.b, 3)] {
                let m = self.mass[body];
                for k in 0..3 {
                    if m[k] > 0.0 {
                        self.v[body][k] += (r.j[0][offset + k] * l[0] + r.j[1][offset + k] * l[1]) / m[k];
                    }
                }
            }
        }
    }

    /// Each row's relative velocity `J v`.
    fn relative_velocities(&mut self) {
        for (r, u) in self.rows.iter().zip(self.u.iter_mut()) {
            *u = r.apply(&self.v);
        }
    }

    /// The trial impulses `l(u)` at the current relative velocities, with the intervals of the
    /// current outer iterate.
    fn trial_impulses(&mut self, compliance: f64) {
        for ((((r, l), u), rho), out) in
            self.rows.iter().zip(&self.lambda).zip(&self.u).zip(&self.rho).zip(self.trial.iter_mut())
        {
            *out = r.trial(l, u, rho, compliance).0;
        }
    }

    /// The gradient `M (v - v0) - J^T l(J v)` into `rhs` (negated: the Newton system's right
    /// side), fixed dofs zero; returns its largest absolute entry.
    fn gradient(&mut self, compliance: f64) -> f64 {
        self.relative_velocities();
        self.trial_impulses(compliance);
        self.rhs.iter_mut().for_each(|x| *x = 0.0);
        for (body, (&k, m)) in self.block_of.iter().zip(&self.mass).enumerate() {
            if k == NONE {
                continue;
            }
            for c in 0..3 {
                if m[c] > 0.0 {
                    self.rhs[3 * k as usize + c] = -m[c] * (self.v[body][c] - self.v0[body][c]);
                }
            }
        }
        for (r, l) in self.rows.iter().zip(&self.trial) {
            add_transposed(&mut self.rhs, &self.block_of, &self.mass, r, *l);
        }
        self.rhs.iter().fold(0.0f64, |m, x| m.max(x.abs()))
    }

    /// Assembles the Hessian at the current trial values, factorises it on the kept symbolic
    /// factorisation and solves for the Newton direction (from `rhs`, the negated gradient).
    fn factorise_and_solve(&mut self, compliance: f64) -> Result<(), NewtonError> {
        for ((((r, l), u), rho), w) in
            self.rows.iter().zip(&self.lambda).zip(&self.u).zip(&self.rho).zip(self.weights.iter_mut())
        {
            let (_, free) = r.trial(l, u, rho, compliance);
            *w = std::array::from_fn(|part| if free[part] { r.weight(rho[part], compliance, part) } else { 0.0 });
        }
        self.factorise()?;
        self.solve_direction();
        Ok(())
    }

    /// Assembles `M + sum w J^T J` (`w` from `weights`, per row part) and factorises it on the
    /// kept symbolic factorisation.
    fn factorise(&mut self) -> Result<(), NewtonError> {
        let started = Instant::now();
        self.block_values.iter_mut().for_each(|b| *b = [0.0; 9]);
        for (&k, m) in self.block_of.iter().zip(&self.mass) {
            if k == NONE {
                continue;
            }
            // A fixed dof keeps 1 on the diagonal and nothing else: its row reads `d = 0`.
            let diag = self.pairs.binary_search_by_key(&(k, k), |&(r, c)| (c, r)).expect("every block has a diagonal");
            for c in 0..3 {
                self.block_values[diag][c * 3 + c] = if m[c] > 0.0 { m[c] } else { 1.0 };
            }
        }
        for (r, weights) in self.rows.iter().zip(&self.weights) {
            for part in 0..2 {
                let w = weights[part];
                if w == 0.0 {
                    continue;
                }
                let ja = self.masked(r.a, &r.j[part][0..3]);
                let jb = self.masked(r.b, &r.j[part][3..6]);
                if r.blocks[0] != NONE {
                    add_outer(&mut self.block_values[r.blocks[0] as usize], w, &ja, &ja);
                }
                if r.blocks[1] != NONE {
                    add_outer(&mut self.block_values[r.blocks[1] as usize], w, &jb, &jb);
                }
                if r.blocks[2] != NONE {
                    let (upper, lower) = if r.a_first { (&ja, &jb) } else { (&jb, &ja) };
                    add_outer(&mut self.block_values[r.blocks[2] as usize], w, upper, lower);
                }
            }
        }
        for (value, &(pair, element)) in self.values.iter_mut().zip(&self.scatter) {
            *value = self.block_values[pair as usize][element as usize];
        }
        let symbolic = self.symbolic.as_ref().expect("prepare_pattern made it");
        let dofs = self.rhs.len();
        let structure = SymbolicSparseColMatRef::new_checked(dofs, dofs, &self.col_ptr, None, &self.row_idx);
        let matrix = SparseColMatRef::new(structure, &self.values);
        let stack = MemStack::new(self.stack.as_mut().expect("prepare_pattern made it"));
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.l_values,
                matrix,
                Side::Upper,
                Default::default(),
                Par::Seq,
                stack,
                Default::default(),
            )
            .map_err(|e| NewtonError::Factorisation(format!("{e:?}")))?;
        self.numeric_seconds += started.elapsed().as_secs_f64();
        Ok(())
    }

    /// Solves the last factorisation for `rhs` (per dof) into `direction` (per body).
    fn solve_direction(&mut self) {
        let started = Instant::now();
        let symbolic = self.symbolic.as_ref().expect("prepare_pattern made it");
        let stack = MemStack::new(self.stack.as_mut().expect("prepare_pattern made it"));
        LltRef::new(symbolic, &self.l_values).solve_in_place_with_conj(
            Conj::No,
            ColMut::from_slice_mut(&mut self.rhs).as_mat_mut(),
            Par::Seq,
            stack,
        );
        self.numeric_seconds += started.elapsed().as_secs_f64();
        for (body, &k) in self.block_of.iter().enumerate() {
            self.direction[body] = if k == NONE {
                [0.0; 3]
            } else {
                let at = 3 * k as usize;
                let m = self.mass[body];
                std::array::from_fn(|c| if m[c] > 0.0 { self.rhs[at + c] } else { 0.0 })
            };
        }
    }

    /// A body's Jacobian part with its fixed dofs zeroed.
    fn masked(&self, body: usize, j: &[f64]) -> [f64; 3] {
        let m = self.mass[body];
        std::array::from_fn(|c| if m[c] > 0.0 { j[c] } else { 0.0 })
    }

    /// The exact line search along the direction: the root of `L`'s derivative along it
    /// (monotone, piecewise linear) by safeguarded Newton steps from the full step.
    fn line_search(&mut self, compliance: f64) -> f64 {
        for (r, jd) in self.rows.iter().zip(self.jd.iter_mut()) {
            *jd = r.apply(&self.direction);
        }
        // dT M (v - v0) and dT M d.
        let (mut dm_dv, mut dmd) = (0.0, 0.0);
        for ((v, v0), (d, m)) in self.v.iter().zip(&self.v0).zip(self.direction.iter().zip(&self.mass)) {
            for c in 0..3 {
                dm_dv += d[c] * m[c] * (v[c] - v0[c]);
                dmd += d[c] * m[c] * d[c];
            }
        }
        // The derivative and the second derivative at step `alpha`.
        let slope = |alpha: f64| {
            let (mut first, mut second) = (dm_dv + alpha * dmd, dmd);
            for ((((r, l), u), jd), rho) in self.rows.iter().zip(&self.lambda).zip(&self.u).zip(&self.jd).zip(&self.rho)
            {
                let at = [u[0] + alpha * jd[0], u[1] + alpha * jd[1]];
                let (trial, free) = r.trial(l, &at, rho, compliance);
                for part in 0..2 {
                    first -= jd[part] * trial[part];
                    if free[part] {
                        second += r.weight(rho[part], compliance, part) * jd[part] * jd[part];
                    }
                }
            }
            (first, second)
        };
        let (start, _) = slope(0.0);
        if start >= 0.0 {
            // Not a descent direction (rounding at the minimiser): no step.
            return 0.0;
        }
        let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
        let mut alpha = 1.0;
        for _ in 0..40 {
            let (first, second) = slope(alpha);
            if first.abs() <= 1e-12 * start.abs() {
                return alpha;
            }
            if first < 0.0 {
                lo = alpha;
            } else {
                hi = alpha;
            }
            let newton = alpha - first / second;
            alpha = if newton > lo && newton < hi {
                newton
            } else if hi.is_finite() {
                0.5 * (lo + hi)
            } else {
                2.0 * lo.max(1.0)
            };
            if hi.is_finite() && hi - lo <= 1e-14 * hi {
                break;
            }
        }
        alpha
    }

    /// The natural residual (max over rows) of the current impulses and velocities, with the
    /// rows' own law (the Box2D law's bound from each row's current normal impulse).
    fn natural_residual(&mut self, softness: f64) -> f64 {
        self.relative_velocities();
        self.natural_residual_with(softness, |_, r, l| r.bound(l[0]))
    }

    /// The natural residual (max over rows) at the current `u`, each row's tangent bound given
    /// by `bound(row index, row, impulse)`.
    fn natural_residual_with(&self, softness: f64, bound: impl Fn(usize, &Row, &[f64; 2]) -> f64) -> f64 {
        let mut max = 0.0f64;
        for (k, ((r, l), u)) in self.rows.iter().zip(&self.lambda).zip(&self.u).enumerate() {
            let rn = (l[0] - ((l[0] - r.mass[0] * u[0]) * softness).max(0.0)).abs();
            let c = bound(k, r, l);
            let rt = (l[1] - ((l[1] - r.mass[1] * u[1]) * softness).clamp(-c, c)).abs();
            max = max.max(rn).max(rt);
        }
        max
    }
}

/// The interior-point method's state per row part: bounds `lo <= x <= hi` (a normal's `hi` is
/// infinite), the dual slacks of each bound, the steps, and whether the part is a variable (a
/// tangent whose bound is zero, or a part with no effective mass, stays at zero).
#[derive(Debug, Default)]
struct Interior {
    lo: Vec<[f64; 2]>,
    hi: Vec<[f64; 2]>,
    z_lo: Vec<[f64; 2]>,
    z_hi: Vec<[f64; 2]>,
    active: Vec<[bool; 2]>,
    /// The dual residual `J v + R x - z_lo + z_hi`.
    dual: Vec<[f64; 2]>,
    dx: Vec<[f64; 2]>,
    dz_lo: Vec<[f64; 2]>,
    dz_hi: Vec<[f64; 2]>,
    rhs: Vec<[f64; 2]>,
}

/// Bound passes at most: each fixes the Box-law rows' friction bounds at `mu` times the
/// previous pass's normal impulse (the per-step model's rows keep theirs).
const MAX_BOUND_PASSES: u32 = 8;
/// The fraction of the way to the boundary a step may go.
const TO_BOUNDARY: f64 = 0.995;
/// The speed scale of the centred start's target product (m/s).
const CENTRING_SPEED: f64 = 0.1;
/// The centred start's target product in units of the tolerance times [`CENTRING_SPEED`], as
/// `ipm:warm` uses it ([`NewtonParams::centred_start`]).
pub const CENTRED_START: f64 = 10.0;

impl NewtonSolver {
    /// The primal-dual interior-point method on the step's QP
    /// `min 1/2 x^T (A + R) x + x^T J v0` over `x_n >= 0, |x_t| <= c` (`A = J M^-1 J^T`): each
    /// iteration's system `(A + E) dx = r` (`E` diagonal and positive) is solved as
    /// `(M + J^T E^-1 J) dv = J^T E^-1 r`, `dx = E^-1 (r - J dv)`: the same sparse SPD pattern as
    /// Newton's Hessian, symmetric positive definite however redundant the contacts. Mehrotra's
    /// predictor-corrector: two solves per factorisation. Under the Box2D law the bound `c` is
    /// fixed per pass at `mu` times the last pass's normal impulse (a staggered fixed point);
    /// under the per-step model it is the row's own and one pass solves the problem.
    fn interior_point(
        &mut self,
        problem: &NewtonProblem<'_>,
        params: &NewtonParams,
        stats: &mut NewtonStats,
    ) -> Result<(), NewtonError> {
        let softness = 1.0 / (1.0 + problem.compliance as f64);
        let compliance = problem.compliance as f64;
        let tolerance = problem.tolerance as f64;
        self.residuals.clear();
        self.velocities_of_lambda();
        let mut residual = self.natural_residual(softness);
        self.residuals.push(residual as f32);
        let n = self.rows.len();
        let ip = &mut self.interior;
        for buf in [
            &mut ip.lo,
            &mut ip.hi,
            &mut ip.z_lo,
            &mut ip.z_hi,
            &mut ip.dual,
            &mut ip.dx,
            &mut ip.dz_lo,
            &mut ip.dz_hi,
            &mut ip.rhs,
        ] {
            buf.clear();
            buf.resize(n, [0.0; 2]);
        }
        ip.active.clear();
        ip.active.resize(n, [false; 2]);
        while residual > tolerance
            && stats.iterations < params.max_iterations
            && stats.outer < MAX_BOUND_PASSES
            && !past(problem.deadline)
        {
            stats.outer += 1;
            match (params.centred_start, stats.outer) {
                // Every pass re-centred from where the last one ended: a pass that ended at a
                // tiny duality measure would otherwise restart the moved bounds' parts against
                // slacks near zero, and crawl.
                (Some(k), _) => self.interior_start_centred(k * tolerance * CENTRING_SPEED),
                (None, 1) => self.interior_start(),
                (None, _) => self.interior_rebound(),
            }
            loop {
                // The law's residual, and the pass's own problem's (its fixed bounds).
                self.relative_velocities();
                residual = self.natural_residual_with(softness, |_, r, l| r.bound(l[0]));
                let own = self.natural_residual_with(softness, |k, _, _| self.interior.hi[k][1]);
                if residual <= tolerance || stats.iterations >= params.max_iterations || past(problem.deadline) {
                    break;
                }
                if own <= 0.5 * tolerance {
                    // This pass's problem is solved; only the Box2D law's bounds moved.
                    break;
                }
                stats.iterations += 1;
                if !self.interior_iteration(compliance)? {
                    break;
                }
            }
            self.residuals.push(residual as f32);
        }
        stats.converged = residual <= tolerance;
        stats.natural_max = residual;
        Ok(())
    }

    /// A pass's bounds (the Box2D law's from the current normal impulses) and which parts are
    /// variables; the parts that are not are zeroed. Returns the largest normal impulse (the
    /// impulses' scale, at least 1e-6).
    fn interior_bounds(&mut self) -> f64 {
        let scale = self.lambda.iter().fold(0.0f64, |m, l| m.max(l[0])).max(1e-6);
        let ip = &mut self.interior;
        for (k, (r, l)) in self.rows.iter().zip(self.lambda.iter_mut()).enumerate() {
            let c = r.bound(l[0]);
            ip.lo[k] = [0.0, -c];
            ip.hi[k] = [f64::INFINITY, c];
            ip.active[k] = [r.mass[0] > 0.0, r.mass[1] > 0.0 && c > 1e-12 * scale];
            for part in 0..2 {
                if !ip.active[k][part] {
                    l[part] = 0.0;
                }
            }
        }
        scale
    }

    /// A pass's start: the bounds ([`Self::interior_bounds`]), the impulses pushed strictly
    /// inside them and dual slacks from the relative velocities.
    fn interior_start(&mut self) {
        let scale = self.interior_bounds();
        // How far inside the bounds a start lies, in impulse and in velocity units.
        let inside = 1e-2 * scale;
        let speed = 1e-3;
        let ip = &self.interior;
        for (k, l) in self.lambda.iter_mut().enumerate() {
            let c = ip.hi[k][1];
            if ip.active[k][0] {
                l[0] = l[0].max(inside);
            }
            if ip.active[k][1] {
                l[1] = l[1].clamp(-0.99 * c, 0.99 * c);
            }
        }
        self.velocities_of_lambda();
        self.relative_velocities();
        let ip = &mut self.interior;
        for k in 0..self.rows.len() {
            for part in 0..2 {
                let u = self.u[k][part];
                ip.z_lo[k][part] = u.max(0.0) + speed;
                ip.z_hi[k][part] = if part == 1 { (-u).max(0.0) + speed } else { 0.0 };
            }
        }
    }

    /// A pass's start centred on the warm start: the bounds as [`Self::interior_start`]'s; per
    /// bound, the speed pushing the part onto it at the warm start (its slack at a solution) and
    /// the gap that speed needs for the product `target`; the part moved inside just that far
    /// (at most as far as the fixed start would), each slack `max(speed, target / gap)`.
    fn interior_start_centred(&mut self, target: f64) {
        let inside = 1e-2 * self.interior_bounds();
        // A slack is never below this speed when it sets a gap (a part at rest on its bound).
        let floor = 1e-3;
        self.velocities_of_lambda();
        self.relative_velocities();
        let ip = &mut self.interior;
        for k in 0..self.rows.len() {
            for part in 0..2 {
                if !ip.active[k][part] {
                    continue;
                }
                let u = self.u[k][part];
                let (s_lo, s_hi) = (u.max(0.0), (-u).max(0.0));
                let x = &mut self.lambda[k][part];
                let (lo, hi) = (ip.lo[k][part], ip.hi[k][part]);
                let room = if hi.is_finite() { 0.49 * (hi - lo) } else { f64::INFINITY };
                let need = |s: f64| (target / s.max(floor)).min(inside).min(room);
                *x = x.max(lo + need(s_lo));
                if hi.is_finite() {
                    *x = x.min(hi - need(s_hi));
                }
                let g_lo = *x - lo;
                ip.z_lo[k][part] = s_lo.max(target / g_lo);
                ip.z_hi[k][part] = if hi.is_finite() { s_hi.max(target / (hi - *x)) } else { 0.0 };
            }
        }
        self.velocities_of_lambda();
    }

    /// A later pass's start: only the Box2D law's rows take new bounds (`mu` times their normal
    /// impulse now) and restart their tangent inside them; every other part keeps its iterate
    /// and slacks, so the pass starts near the last one's solution.
    fn interior_rebound(&mut self) {
        let ip = &mut self.interior;
        for (k, (r, l)) in self.rows.iter().zip(self.lambda.iter_mut()).enumerate() {
            if r.fixed_bound.is_some() {
                continue;
            }
            let c = r.bound(l[0]);
            let was = ip.active[k][1];
            ip.lo[k][1] = -c;
            ip.hi[k][1] = c;
            ip.active[k][1] = r.mass[1] > 0.0 && c > 0.0;
            if !ip.active[k][1] {
                l[1] = 0.0;
                continue;
            }
            l[1] = l[1].clamp(-0.99 * c, 0.99 * c);
            if !was || ip.z_lo[k][1] <= 0.0 || ip.z_hi[k][1] <= 0.0 {
                ip.z_lo[k][1] = 1e-3;
                ip.z_hi[k][1] = 1e-3;
            }
        }
        self.velocities_of_lambda();
    }

    /// One predictor-corrector iteration from the current `lambda` (x), `u` and slacks; returns
    /// whether it moved.
    fn interior_iteration(&mut self, compliance: f64) -> Result<bool, NewtonError> {
        let n = self.rows.len();
        // Dual residual, duality measure and the diagonal E (as weights 1 / E).
        let (mut gap_sum, mut count) = (0.0, 0usize);
        for k in 0..n {
            let r = &self.rows[k];
            for part in 0..2 {
                let ip = &mut self.interior;
                if !ip.active[k][part] {
                    self.weights[k][part] = 0.0;
                    continue;
                }
                let x = self.lambda[k][part];
                let stiffness = compliance / r.mass[part].max(f64::MIN_POSITIVE);
                ip.dual[k][part] = self.u[k][part] + stiffness * x - ip.z_lo[k][part] + ip.z_hi[k][part];
                let (g_lo, g_hi) = (x - ip.lo[k][part], ip.hi[k][part] - x);
                let mut e = stiffness + ip.z_lo[k][part] / g_lo;
                gap_sum += g_lo * ip.z_lo[k][part];
                count += 1;
                if g_hi.is_finite() {
                    e += ip.z_hi[k][part] / g_hi;
                    gap_sum += g_hi * ip.z_hi[k][part];
                    count += 1;
                }
                // A part far inside its bounds is nearly an equality: its weight is capped so the
                // factorisation stays well conditioned.
                self.weights[k][part] = (1.0 / e).min(1e10 * r.mass[part]);
            }
        }
        let mu = gap_sum / count.max(1) as f64;
        self.factorise()?;
        // Predictor (affine scaling, sigma = 0).
        self.interior_rhs(0.0, false);
        self.interior_direction();
        let alpha_aff = self.interior_step_length();
        let mut gap_aff = 0.0;
        {
            let ip = &self.interior;
            for k in 0..n {
                for part in 0..2 {
                    if !ip.active[k][part] {
                        continue;
                    }
                    let x = self.lambda[k][part] + alpha_aff * ip.dx[k][part];
                    gap_aff += (x - ip.lo[k][part]) * (ip.z_lo[k][part] + alpha_aff * ip.dz_lo[k][part]);
                    if ip.hi[k][part].is_finite() {
                        gap_aff += (ip.hi[k][part] - x) * (ip.z_hi[k][part] + alpha_aff * ip.dz_hi[k][part]);
                    }
                }
            }
        }
        let sigma = (gap_aff / count.max(1) as f64 / mu.max(f64::MIN_POSITIVE)).clamp(0.0, 1.0).powi(3);
        // Corrector: centring and the predictor's second-order term.
        self.interior_rhs(sigma * mu, true);
        self.interior_direction();
        let alpha = (TO_BOUNDARY * self.interior_step_length()).min(1.0);
        if alpha <= 0.0 {
            return Ok(false);
        }
        let ip = &mut self.interior;
        for k in 0..n {
            for part in 0..2 {
                if ip.active[k][part] {
                    self.lambda[k][part] += alpha * ip.dx[k][part];
                    ip.z_lo[k][part] += alpha * ip.dz_lo[k][part];
                    ip.z_hi[k][part] += alpha * ip.dz_hi[k][part];
                }
            }
        }
        self.velocities_of_lambda();
        Ok(true)
    }

    /// The right side `r` of `(A + E) dx = r` per row part, with centring target `target`; with
    /// `correct`, Mehrotra's second-order term from the current (predictor) steps.
    fn interior_rhs(&mut self, target: f64, correct: bool) {
        let ip = &mut self.interior;
        for k in 0..self.rows.len() {
            for part in 0..2 {
                if !ip.active[k][part] {
                    ip.rhs[k][part] = 0.0;
                    continue;
                }
                let x = self.lambda[k][part];
                let (g_lo, g_hi) = (x - ip.lo[k][part], ip.hi[k][part] - x);
                let (c_lo, c_hi) = if correct {
                    let (dx, dzl, dzh) = (ip.dx[k][part], ip.dz_lo[k][part], ip.dz_hi[k][part]);
                    (target - dx * dzl, target + dx * dzh)
                } else {
                    (target, target)
                };
                let mut r = -ip.dual[k][part] + c_lo / g_lo - ip.z_lo[k][part];
                if g_hi.is_finite() {
                    r += -c_hi / g_hi + ip.z_hi[k][part];
                }
                ip.rhs[k][part] = r;
                // Kept for the slacks' steps below.
                ip.dz_lo[k][part] = c_lo;
                ip.dz_hi[k][part] = c_hi;
            }
        }
    }

    /// Solves `(A + E) dx = rhs` through the body-space factorisation and the slacks' steps.
    fn interior_direction(&mut self) {
        self.rhs.iter_mut().for_each(|x| *x = 0.0);
        for (k, r) in self.rows.iter().enumerate() {
            let wr = [0, 1].map(|part| self.weights[k][part] * self.interior.rhs[k][part]);
            add_transposed(&mut self.rhs, &self.block_of, &self.mass, r, wr);
        }
        self.solve_direction();
        let ip = &mut self.interior;
        for (k, r) in self.rows.iter().enumerate() {
            let jdv = r.apply(&self.direction);
            for part in 0..2 {
                if !ip.active[k][part] {
                    ip.dx[k][part] = 0.0;
                    ip.dz_lo[k][part] = 0.0;
                    ip.dz_hi[k][part] = 0.0;
                    continue;
                }
                let dx = self.weights[k][part] * (ip.rhs[k][part] - jdv[part]);
                let x = self.lambda[k][part];
                let (g_lo, g_hi) = (x - ip.lo[k][part], ip.hi[k][part] - x);
                let (c_lo, c_hi) = (ip.dz_lo[k][part], ip.dz_hi[k][part]);
                ip.dx[k][part] = dx;
                ip.dz_lo[k][part] = (c_lo - ip.z_lo[k][part] * dx) / g_lo - ip.z_lo[k][part];
                ip.dz_hi[k][part] =
                    if g_hi.is_finite() { (c_hi + ip.z_hi[k][part] * dx) / g_hi - ip.z_hi[k][part] } else { 0.0 };
            }
        }
    }

    /// The largest step in `[0, 1]` keeping every variable part and slack inside its bounds.
    fn interior_step_length(&self) -> f64 {
        let ip = &self.interior;
        let mut alpha = 1.0f64;
        let mut limit = |value: f64, step: f64| {
            if step < 0.0 {
                alpha = alpha.min(-value / step);
            }
        };
        for k in 0..self.rows.len() {
            for part in 0..2 {
                if !ip.active[k][part] {
                    continue;
                }
                let (x, dx) = (self.lambda[k][part], ip.dx[k][part]);
                limit(x - ip.lo[k][part], dx);
                limit(ip.z_lo[k][part], ip.dz_lo[k][part]);
                if ip.hi[k][part].is_finite() {
                    limit(ip.hi[k][part] - x, -dx);
                    limit(ip.z_hi[k][part], ip.dz_hi[k][part]);
                }
            }
        }
        alpha.max(0.0)
    }
}

impl Row {
    /// Row `r` of a problem on `bodies`, in f64.
    pub(super) fn of(r: &ContactRow, bodies: &[SolverBody]) -> Row {
        let (a, b) = (r.body_a as usize, r.body_b as usize);
        let t = tangent_of(r.normal);
        let jac = |d: Vec2| {
            let (ca, cb) = (cross(r.ra, d) as f64, cross(r.rb, d) as f64);
            [-d.x as f64, -d.y as f64, -ca, d.x as f64, d.y as f64, cb]
        };
        let (ba, bb) = (&bodies[a], &bodies[b]);
        Row {
            a,
            b,
            j: [jac(r.normal), jac(t)],
            mass: [effective_mass(ba, bb, r.ra, r.rb, r.normal) as f64, effective_mass(ba, bb, r.ra, r.rb, t) as f64],
            mu: r.friction as f64,
            fixed_bound: r.friction_bound.map(|c| c as f64),
            blocks: [NONE; 3],
            a_first: true,
        }
    }

    /// A warm start's impulse projected onto the row's intervals (a learned guess may be
    /// outside; a non-finite part becomes 0).
    pub(super) fn projected(&self, w: &Impulse) -> [f64; 2] {
        let n = if w.normal.is_finite() { (w.normal as f64).max(0.0) } else { 0.0 };
        let c = self.bound(n);
        let t = if w.tangent.is_finite() { (w.tangent as f64).clamp(-c, c) } else { 0.0 };
        [n, t]
    }

    /// `J x` of per-body vectors `x`: `[normal, tangent]`.
    #[inline]
    pub(super) fn apply(&self, x: &[[f64; 3]]) -> [f64; 2] {
        let (xa, xb) = (&x[self.a], &x[self.b]);
        self.j.map(|j| j[0] * xa[0] + j[1] * xa[1] + j[2] * xa[2] + j[3] * xb[0] + j[4] * xb[1] + j[5] * xb[2])
    }

    /// The Hessian weight `rho / (1 + rho R)` of a free row part (`R` its compliance).
    #[inline]
    fn weight(&self, rho: f64, compliance: f64, part: usize) -> f64 {
        rho / (1.0 + rho * compliance / self.mass[part].max(f64::MIN_POSITIVE))
    }

    /// The tangent bound with normal impulse `normal`.
    #[inline]
    pub(super) fn bound(&self, normal: f64) -> f64 {
        self.fixed_bound.unwrap_or(self.mu * normal.max(0.0))
    }

    /// The trial impulses at relative velocity `u` for outer iterate `l`, and whether each part
    /// lies strictly inside its interval (where `L` curves).
    #[inline]
    fn trial(&self, l: &[f64; 2], u: &[f64; 2], rho: &[f64; 2], compliance: f64) -> ([f64; 2], [bool; 2]) {
        let s = |part: usize| {
            let r = compliance / self.mass[part].max(f64::MIN_POSITIVE);
            (l[part] - rho[part] * u[part]) / (1.0 + rho[part] * r)
        };
        let (sn, st) = (s(0), s(1));
        let normal = sn.max(0.0);
        // The tangent interval of this outer iterate: fixed, or the Box2D law's from its normal.
        let c = self.bound(l[0]);
        let tangent = st.clamp(-c, c);
        ([normal, tangent], [sn > 0.0 && self.mass[0] > 0.0, st.abs() < c && self.mass[1] > 0.0])
    }
}

/// `rhs += J^T l` of one row (`l`: its normal and tangent parts), per dof of the bodies' blocks,
/// fixed dofs left alone.
fn add_transposed(rhs: &mut [f64], block_of: &[u32], mass: &[[f64; 3]], r: &Row, l: [f64; 2]) {
    for (body, offset) in [(r.a, 0), (r.b, 3)] {
        let k = block_of[body];
        if k == NONE {
            continue;
        }
        for c in 0..3 {
            if mass[body][c] > 0.0 {
                rhs[3 * k as usize + c] += r.j[0][offset + c] * l[0] + r.j[1][offset + c] * l[1];
            }
        }
    }
}

/// `block += w a b^T` (row-major 3x3).
#[inline]
fn add_outer(block: &mut [f64; 9], w: f64, a: &[f64; 3], b: &[f64; 3]) {
    for p in 0..3 {
        for q in 0..3 {
            block[p * 3 + q] += w * a[p] * b[q];
        }
    }
}

/// Whether every pair of `part` is in `whole` (both sorted alike).
fn is_subset(part: &[(u32, u32)], whole: &[(u32, u32)]) -> bool {
    let key = |&(i, j): &(u32, u32)| (j, i);
    let mut rest = whole.iter();
    part.iter().all(|p| rest.by_ref().any(|w| key(w) == key(p)))
}

/// The sorted union of two pattern lists sorted by column then row.
fn sorted_union(a: &[(u32, u32)], b: &[(u32, u32)]) -> Vec<(u32, u32)> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    out.extend_from_slice(a);
    out.extend_from_slice(b);
    out.sort_unstable_by_key(|&(i, j)| (j, i));
    out.dedup();
    out
}

/// Refuses a problem with a non-finite value or a row naming a missing body (every method
/// outside the sweeps checks this before touching anything).
pub(super) fn check(rows: &[ContactRow], bodies: &[SolverBody]) -> Result<(), NewtonError> {
    let count = bodies.len();
    for (i, b) in bodies.iter().enumerate() {
        for (what, x) in [
            ("velocity", b.v.x),
            ("velocity", b.v.y),
            ("angular velocity", b.w),
            ("inverse mass", b.inv_mass),
            ("inverse inertia", b.inv_inertia),
        ] {
            if !x.is_finite() {
                return Err(NewtonError::NonFiniteBody { body: i, what });
            }
        }
    }
    for (row, r) in rows.iter().enumerate() {
        for body in [r.body_a, r.body_b] {
            if body as usize >= count {
                return Err(NewtonError::NoSuchBody { row, body, bodies: count });
            }
        }
        for (what, x) in [
            ("ra", r.ra.x),
            ("ra", r.ra.y),
            ("rb", r.rb.x),
            ("rb", r.rb.y),
            ("normal", r.normal.x),
            ("normal", r.normal.y),
            ("friction", r.friction),
            ("friction bound", r.friction_bound.unwrap_or(0.0)),
        ] {
            if !x.is_finite() {
                return Err(NewtonError::NonFiniteRow { row, what });
            }
        }
    }
    Ok(())
}
