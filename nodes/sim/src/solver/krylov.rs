//! A Krylov method on the step's box-constrained QP: MPRGP (modified proportioning with reduced
//! gradient projections; Dostál, "Optimal Quadratic Programming Algorithms", 2009, alg. 5.8).
//!
//! **Why.** Under the per-step friction law a step's problem is the convex QP
//! `min 1/2 x^T (A + R) x + x^T J v0` over impulses `x` in boxes (normal `[0, inf)`, tangent
//! `[-c, c]`), `A = J M^-1 J^T` the Delassus operator, `R` the compliance. What is left after the
//! sweeps' first few passes is the pile-wide error: the smooth modes of `A`, which Gauss-Seidel
//! diffuses at a rate set by the condition number `k` of `A` (iterations ~ `k`, and `k` grows
//! with the pile's depth squared) and conjugate gradients at `sqrt(k)`. MPRGP is conjugate
//! gradients on the face of the box the iterate lies on, with gradient-projection steps that add
//! bounds (expansion) and steps along the chopped gradient that release them (proportioning): a
//! rate bounded by the spectrum of `A`, not by how many contacts change state. Every iteration
//! costs one product with `A` (two passes over the rows, about a sweep's work and a half), no
//! factorisation.
//!
//! **Scaling.** The variables are the impulses scaled by the square roots of the rows' effective
//! masses, so that the operator's diagonal is 1 (Jacobi's preconditioner as a change of
//! variables, which keeps the constraints boxes).
//!
//! **Box2D-law rows** (every row under `--friction box`, a contact's first step under the
//! per-step law) have a tangent bound that follows the normal impulse: it is frozen at `mu`
//! times the current normal impulse, the QP solved on, and refreshed once the frozen problem is
//! solved well ahead of the bounds' own error (staggered, as the interior point does).
//!
//! Everything inside is f64; the stopping rule is the PGS family's natural residual of the
//! unregularised problem.

// The per-part loops index several parallel arrays (impulse, gradient, scale) at once.
#![allow(clippy::needless_range_loop)]

use super::deadline::past;
use super::newton::{check, NewtonError, NewtonProblem, Row};
use super::rows::{Impulse, SolverBody};
use rapier2d::math::Vec2;

/// What one solve did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct KrylovStats {
    /// MPRGP iterations (conjugate-gradient, expansion and proportioning steps).
    pub iterations: u32,
    /// Of which expansion steps (bounds added by a projected step) and proportioning steps
    /// (bounds released).
    pub expansions: u32,
    pub proportionings: u32,
    /// Refreshes of the Box2D-law rows' frozen bounds.
    pub bound_passes: u32,
    /// Operator products (the work: each is two passes over the rows).
    pub products: u32,
    pub converged: bool,
    /// The natural residual's max over rows at the end (f64).
    pub natural_max: f64,
}

/// The solver's reusable buffers (per row part `2 * row + {0: normal, 1: tangent}`).
#[derive(Debug, Default, Clone)]
pub struct KrylovSolver {
    rows: Vec<Row>,
    /// Per body: inverse mass per dof, and its velocity before any impulse.
    inv: Vec<[f64; 3]>,
    v0: Vec<[f64; 3]>,
    /// Body-space scratch: `M^-1 J^T (S p)` of a part vector.
    w: Vec<[f64; 3]>,
    /// Per part: `sqrt(m)` (0 for a part no body can move), the compliance `gamma / m`.
    scale: Vec<f64>,
    soft: Vec<f64>,
    /// Per part: the box in scaled variables.
    lo: Vec<f64>,
    hi: Vec<f64>,
    /// The scaled iterate, its gradient, the search direction and the operator on it.
    y: Vec<f64>,
    g: Vec<f64>,
    p: Vec<f64>,
    ap: Vec<f64>,
    scratch: Vec<f64>,
    /// The natural residual after each iteration (the start first).
    residuals: Vec<f32>,
}

/// `Gamma` of the proportioning test (Dostál's 1: balance the chopped and the free gradient).
const GAMMA: f64 = 1.0;
/// The power iterations that estimate the operator's norm for the expansion step.
const NORM_ITERATIONS: usize = 8;

impl KrylovSolver {
    pub fn new() -> KrylovSolver {
        KrylovSolver::default()
    }

    /// The natural residual after each iteration of the last solve (the start first).
    pub fn residuals(&self) -> &[f32] {
        &self.residuals
    }

    /// Solves `problem` from its warm start in at most `max_iterations` iterations (each about a
    /// sweep and a half of work); the impulses go to `impulses` (row order), the velocities they
    /// give to `bodies`. Refuses a problem with a non-finite value or a row
    /// naming a body that is not there, before touching anything.
    pub fn solve(
        &mut self,
        problem: &NewtonProblem<'_>,
        max_iterations: u32,
        impulses: &mut Vec<Impulse>,
        bodies: &mut [SolverBody],
    ) -> Result<KrylovStats, NewtonError> {
        check(problem.rows, problem.bodies)?;
        let mut stats = KrylovStats::default();
        self.setup(problem);
        let tolerance = problem.tolerance as f64;
        let softness = 1.0 / (1.0 + problem.compliance as f64);
        let step = 1.9 / self.operator_norm(&mut stats);
        self.freeze_bounds();
        self.gradient(&mut stats);
        let (mut residual, mut frozen) = self.natural_residual(softness);
        self.residuals.clear();
        self.residuals.push(residual as f32);
        self.free_gradient_into_p();
        while residual > tolerance && stats.iterations < max_iterations && !past(problem.deadline) {
            // The frozen problem solved well ahead of the bounds' own error: refresh them.
            if frozen <= 0.25 * residual && self.freeze_bounds() {
                stats.bound_passes += 1;
                self.gradient(&mut stats);
                self.free_gradient_into_p();
            }
            stats.iterations += 1;
            self.iterate(step, &mut stats);
            (residual, frozen) = self.natural_residual(softness);
            self.residuals.push(residual as f32);
        }
        stats.converged = residual <= tolerance;
        stats.natural_max = residual;
        self.finish(impulses, bodies);
        Ok(stats)
    }

    /// One MPRGP step: conjugate gradients in the face, an expansion step when CG would leave the
    /// box, a proportioning step when the chopped gradient dominates.
    fn iterate(&mut self, step: f64, stats: &mut KrylovStats) {
        let (mut chopped, mut reduced) = (0.0, 0.0);
        for k in 0..self.y.len() {
            let (y, g, lo, hi) = (self.y[k], self.g[k], self.lo[k], self.hi[k]);
            if lo == hi {
                // A fixed part (a zero friction bound, a part no body moves): never released.
            } else if y <= lo {
                chopped += g.min(0.0).powi(2);
            } else if y >= hi {
                chopped += g.max(0.0).powi(2);
            } else {
                // Dostál's reduced free gradient: no further than the bound a step of `step` reaches.
                let r = if g > 0.0 { ((y - lo) / step).min(g) } else { ((y - hi) / step).max(g) };
                reduced += r * g;
            }
        }
        if chopped > GAMMA * GAMMA * reduced {
            // Proportioning: along the chopped gradient, releasing bounds, as far as the box allows.
            stats.proportionings += 1;
            for k in 0..self.y.len() {
                let (y, g) = (self.y[k], self.g[k]);
                self.scratch[k] = if self.lo[k] == self.hi[k] {
                    0.0
                } else if y <= self.lo[k] {
                    g.min(0.0)
                } else if y >= self.hi[k] {
                    g.max(0.0)
                } else {
                    0.0
                };
            }
            std::mem::swap(&mut self.p, &mut self.scratch);
            self.product(stats);
            let (gd, dad) = (dot(&self.g, &self.p), dot(&self.p, &self.ap));
            let alpha = if dad > 0.0 { (gd / dad).min(self.feasible_step()) } else { self.feasible_step() };
            self.move_along(alpha);
            self.free_gradient_into_p();
            return;
        }
        self.product(stats);
        let (gp, pap) = (dot(&self.g, &self.p), dot(&self.p, &self.ap));
        if pap <= 0.0 || gp == 0.0 {
            // No curvature along p (a direction that moves no body): a projected gradient step.
            self.expand(0.0, step, stats);
            return;
        }
        let (alpha_cg, alpha_f) = (gp / pap, self.feasible_step());
        if alpha_cg <= alpha_f {
            self.move_along(alpha_cg);
            // The next direction A-conjugate to this one within the face.
            let mut phi_ap = 0.0;
            for k in 0..self.y.len() {
                if self.is_free(k) {
                    phi_ap += self.g[k] * self.ap[k];
                }
            }
            let beta = phi_ap / pap;
            for k in 0..self.y.len() {
                let phi = if self.is_free(k) { self.g[k] } else { 0.0 };
                self.p[k] = phi - beta * self.p[k];
            }
        } else {
            self.expand(alpha_f, step, stats);
        }
    }

    /// Expansion: as far along p as the box allows, then a projected step of the free
    /// gradient; the gradient recomputed from scratch.
    fn expand(&mut self, alpha_f: f64, step: f64, stats: &mut KrylovStats) {
        stats.expansions += 1;
        self.move_along(alpha_f);
        for k in 0..self.y.len() {
            if self.is_free(k) {
                self.y[k] = (self.y[k] - step * self.g[k]).clamp(self.lo[k], self.hi[k]);
            }
        }
        self.gradient(stats);
        self.free_gradient_into_p();
    }

    /// `y -= alpha p`, `g -= alpha A p`, landing exactly on a bound it reaches.
    fn move_along(&mut self, alpha: f64) {
        for k in 0..self.y.len() {
            self.y[k] = (self.y[k] - alpha * self.p[k]).clamp(self.lo[k], self.hi[k]);
            self.g[k] -= alpha * self.ap[k];
        }
    }

    /// The longest step along `-p` that stays in the box.
    fn feasible_step(&self) -> f64 {
        let mut alpha = f64::INFINITY;
        for k in 0..self.y.len() {
            let p = self.p[k];
            if p > 0.0 {
                alpha = alpha.min((self.y[k] - self.lo[k]) / p);
            } else if p < 0.0 {
                alpha = alpha.min((self.y[k] - self.hi[k]) / p);
            }
        }
        alpha.max(0.0)
    }

    fn is_free(&self, k: usize) -> bool {
        self.lo[k] < self.y[k] && self.y[k] < self.hi[k]
    }

    fn free_gradient_into_p(&mut self) {
        for k in 0..self.y.len() {
            self.p[k] = if self.is_free(k) { self.g[k] } else { 0.0 };
        }
    }

    /// Freezes the Box2D-law rows' tangent bounds at `mu` times their current normal impulse
    /// (fixed-bound rows keep theirs) and projects the iterate into the box. Returns whether a
    /// bound moved.
    fn freeze_bounds(&mut self) -> bool {
        let mut moved = false;
        for (i, r) in self.rows.iter().enumerate() {
            let (n, t) = (2 * i, 2 * i + 1);
            let s = self.scale[t];
            let (lo, hi) = if s > 0.0 {
                let c = r.bound(self.y[n] * self.scale[n]) / s;
                (-c, c)
            } else {
                (0.0, 0.0)
            };
            moved |= lo != self.lo[t] || hi != self.hi[t];
            self.lo[t] = lo;
            self.hi[t] = hi;
            self.y[t] = self.y[t].clamp(lo, hi);
        }
        moved
    }

    /// The natural residual of the true law (max over row parts) and of the frozen bounds.
    fn natural_residual(&self, softness: f64) -> (f64, f64) {
        let (mut law, mut frozen) = (0.0f64, 0.0f64);
        for (i, r) in self.rows.iter().enumerate() {
            let mut x = [0.0; 2];
            let mut jv = [0.0; 2];
            for part in 0..2 {
                let k = 2 * i + part;
                let s = self.scale[k];
                x[part] = self.y[k] * s;
                // The gradient in scaled variables is `s (J v + R x)`.
                jv[part] = if s > 0.0 { self.g[k] / s - self.soft[k] * x[part] } else { 0.0 };
            }
            let trial = |part: usize| (x[part] - r.mass[part] * jv[part]) * softness;
            let rn = (x[0] - trial(0).max(0.0)).abs();
            let c = r.bound(x[0]);
            let rt = (x[1] - trial(1).clamp(-c, c)).abs();
            let cf = self.hi[2 * i + 1] * self.scale[2 * i + 1];
            let rf = (x[1] - trial(1).clamp(-cf, cf)).abs();
            law = law.max(rn).max(rt);
            frozen = frozen.max(rn).max(rf);
        }
        (law, frozen)
    }

    /// `g = S (J v + R x)` at the iterate, `v = v0 + M^-1 J^T x`.
    fn gradient(&mut self, stats: &mut KrylovStats) {
        stats.products += 1;
        self.w.clone_from(&self.v0);
        operator(&self.rows, &self.inv, &self.scale, &self.soft, &self.y, &mut self.w, &mut self.g);
    }

    /// `ap = S (A + R) S p`.
    fn product(&mut self, stats: &mut KrylovStats) {
        stats.products += 1;
        self.w.iter_mut().for_each(|w| *w = [0.0; 3]);
        operator(&self.rows, &self.inv, &self.scale, &self.soft, &self.p, &mut self.w, &mut self.ap);
    }

    /// The operator's largest eigenvalue, from a few power iterations (at least 1: the diagonal
    /// is 1), times a margin against the estimate falling short.
    fn operator_norm(&mut self, stats: &mut KrylovStats) -> f64 {
        // A start with every row part, deterministic.
        for (k, p) in self.p.iter_mut().enumerate() {
            *p = if self.scale[k] > 0.0 { 1.0 + (k % 7) as f64 * 0.1 } else { 0.0 };
        }
        let mut estimate = 1.0f64;
        for _ in 0..NORM_ITERATIONS {
            let norm = dot(&self.p, &self.p).sqrt();
            if norm == 0.0 {
                break;
            }
            self.p.iter_mut().for_each(|p| *p /= norm);
            self.product(stats);
            estimate = estimate.max(dot(&self.p, &self.ap));
            std::mem::swap(&mut self.p, &mut self.ap);
        }
        1.25 * estimate
    }

    /// Rows, bodies, masses, scales and the projected warm start in f64.
    fn setup(&mut self, problem: &NewtonProblem<'_>) {
        let bodies = problem.bodies;
        self.inv.clear();
        self.v0.clear();
        for b in bodies {
            self.inv.push([b.inv_mass as f64, b.inv_mass as f64, b.inv_inertia as f64]);
            self.v0.push([b.v.x as f64, b.v.y as f64, b.w as f64]);
        }
        self.w.clear();
        self.w.resize(bodies.len(), [0.0; 3]);
        self.rows.clear();
        self.rows.extend(problem.rows.iter().map(|r| Row::of(r, bodies)));
        let parts = 2 * self.rows.len();
        for buf in [&mut self.scale, &mut self.soft, &mut self.lo, &mut self.hi, &mut self.y] {
            buf.clear();
        }
        let gamma = problem.compliance as f64;
        for (r, w) in self.rows.iter().zip(problem.warm_start) {
            for (part, x) in r.projected(w).into_iter().enumerate() {
                let m = r.mass[part];
                let s = if m > 0.0 && m.is_finite() { m.sqrt() } else { 0.0 };
                self.scale.push(s);
                self.soft.push(if s > 0.0 { gamma / m } else { 0.0 });
                self.y.push(if s > 0.0 { x / s } else { 0.0 });
            }
            self.lo.extend([0.0, 0.0]);
            self.hi.extend([f64::INFINITY, 0.0]);
        }
        // A part no body can move stays at zero.
        for k in (0..parts).step_by(2) {
            if self.scale[k] == 0.0 {
                self.hi[k] = 0.0;
            }
        }
        for buf in [&mut self.g, &mut self.p, &mut self.ap, &mut self.scratch] {
            buf.clear();
            buf.resize(parts, 0.0);
        }
    }

    /// Hands the impulses (f32) and the velocities those give to the caller.
    fn finish(&mut self, impulses: &mut Vec<Impulse>, bodies: &mut [SolverBody]) {
        impulses.clear();
        for i in 0..self.rows.len() {
            let (n, t) = (self.y[2 * i] * self.scale[2 * i], self.y[2 * i + 1] * self.scale[2 * i + 1]);
            impulses.push(Impulse { normal: n as f32, tangent: t as f32 });
        }
        // The velocities of the f32 impulses the caller gets, so that its residual is theirs.
        self.w.clone_from(&self.v0);
        scatter(&self.rows, &self.inv, |i| [impulses[i].normal as f64, impulses[i].tangent as f64], &mut self.w);
        for (b, v) in bodies.iter_mut().zip(&self.w) {
            b.v = Vec2::new(v[0] as f32, v[1] as f32);
            b.w = v[2] as f32;
        }
    }
}

/// `out = S (J w + R S x)` after `w += M^-1 J^T (S x)`: with `w` the free velocities the gradient
/// at `x`, from rest the operator `S (A + R) S` on `x`.
fn operator(
    rows: &[Row],
    inv: &[[f64; 3]],
    scale: &[f64],
    soft: &[f64],
    x: &[f64],
    w: &mut [[f64; 3]],
    out: &mut [f64],
) {
    scatter(rows, inv, |i| [scale[2 * i] * x[2 * i], scale[2 * i + 1] * x[2 * i + 1]], w);
    for (i, r) in rows.iter().enumerate() {
        let jw = r.apply(w);
        for part in 0..2 {
            let k = 2 * i + part;
            out[k] = scale[k] * (jw[part] + soft[k] * scale[k] * x[k]);
        }
    }
}

/// `w += M^-1 J^T l`, row `i`'s impulse `l(i)` (`[normal, tangent]`).
fn scatter(rows: &[Row], inv: &[[f64; 3]], l: impl Fn(usize) -> [f64; 2], w: &mut [[f64; 3]]) {
    for (i, r) in rows.iter().enumerate() {
        let x = l(i);
        for (body, offset) in [(r.a, 0), (r.b, 3)] {
            for c in 0..3 {
                w[body][c] += inv[body][c] * (r.j[0][offset + c] * x[0] + r.j[1][offset + c] * x[1]);
            }
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
