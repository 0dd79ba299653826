//! The sweeps' shared pieces, below both sweep paths (one thread in [`super::pgs`], every core in
//! [`super::colour`]): the solve's parameters and report, a row prepared with its effective
//! masses, one row's projected update and NNCG's vector step, the natural residual of some rows,
//! and the row's impulse on its two bodies. One formula each, whichever path runs it.

use super::rows::{cross, cross_sv, effective_mass, tangent_of, ContactRow, Impulse, SolverBody};
use super::setting::{
    valid_relaxation, CoarseCorrection, FrictionModel, Method, Momentum, RowOrder, SolverSetting, StopRule,
    RELAXATION_LIMIT,
};
use rapier2d::math::Vec2;

/// The velocity solve's iteration and stopping rule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveParams {
    /// Converged when the stopping rule's residual is at most this (impulse units).
    pub tolerance: f32,
    /// Sweep cap (the thesis: 1000).
    pub max_sweeps: u32,
    /// Relative compliance `gamma` of every contact row (0: rigid, the thesis's problem). A row
    /// then asks `u + gamma / m * lambda = 0` (u its relative velocity, m its effective mass)
    /// instead of `u = 0`: a slightly soft contact, as Box2D v3's soft step, ODE's constraint
    /// force mixing and MuJoCo's impedance make it. Rigid contacts in a jammed pile have a whole
    /// set of solutions (impulses that move no body); a compliant problem has one.
    pub compliance: f32,
    /// Over-relaxation factor `omega` of every row update (1: plain projected Gauss-Seidel, the
    /// thesis's solver). Each row moves `omega` times its Gauss-Seidel step before projection
    /// (projected SOR); in (0, 2).
    pub relaxation: f32,
    /// A momentum step after each sweep (NNCG), or none.
    pub momentum: Momentum,
    /// The order the rows are visited in.
    pub order: RowOrder,
    /// A coarse correction between sweeps ([`super::coarse`]), or none.
    pub coarse: Option<CoarseCorrection>,
    /// What "converged" means.
    pub stop: StopRule,
    /// Sweeps or Newton ([`Method`]).
    pub method: Method,
    /// The friction law the rows were built with (the rows carry their bounds; this says which
    /// law made them, for the problem's header and the solver's checks).
    pub friction: FrictionModel,
    /// A wall-time budget per solve, microseconds (the real-time regime at a fixed time per
    /// step): the iteration stops at the tolerance or at the first check past the budget (after
    /// each sweep or factorisation; at least the warm start's residual is measured). None: no
    /// limit, and the solve is deterministic; with a budget it is not (it depends on the clock).
    pub time_budget_us: Option<f32>,
}

impl Default for SolveParams {
    fn default() -> Self {
        SolveParams {
            tolerance: 1e-4,
            max_sweeps: 1000,
            compliance: 0.0,
            relaxation: 1.0,
            momentum: Momentum::None,
            order: RowOrder::Recorded,
            coarse: None,
            stop: StopRule::Change,
            method: Method::Sweeps,
            friction: FrictionModel::Box,
            time_budget_us: None,
        }
    }
}

impl SolveParams {
    /// The recommended solver and rule ([`SolverSetting::RECOMMENDED`], [`StopRule::RECOMMENDED`])
    /// with the default tolerance and cap: what `dc-sim` solves with unless told otherwise.
    /// (`Default` stays the thesis's PGS and change rule, which the solver's own tests check.)
    pub fn recommended() -> SolveParams {
        SolveParams { stop: StopRule::RECOMMENDED, ..SolveParams::default() }.with_setting(SolverSetting::RECOMMENDED)
    }

    /// The largest compliance: contacts eleven times softer than their effective mass says; more
    /// is not a contact any more.
    pub const MAX_COMPLIANCE: f32 = 10.0;
    pub const RELAXATION_LIMIT: f32 = RELAXATION_LIMIT;

    pub fn valid_compliance(gamma: f32) -> bool {
        gamma.is_finite() && (0.0..=Self::MAX_COMPLIANCE).contains(&gamma)
    }

    pub fn valid_relaxation(omega: f32) -> bool {
        valid_relaxation(omega)
    }

    /// The solver these parameters pick.
    pub fn setting(&self) -> SolverSetting {
        SolverSetting {
            method: self.method,
            relaxation: self.relaxation,
            momentum: self.momentum,
            order: self.order,
            coarse: self.coarse,
        }
    }

    /// These parameters with `setting`'s iteration and row order.
    pub fn with_setting(self, setting: SolverSetting) -> SolveParams {
        SolveParams {
            method: setting.method,
            relaxation: setting.relaxation,
            momentum: setting.momentum,
            order: setting.order,
            coarse: setting.coarse,
            ..self
        }
    }

    /// The parameters a solve from `start` runs by: [`StopRule::Relative`] becomes the natural
    /// rule at `tolerance` times the start's RMS impulse (the absolute tolerance when the start
    /// is all zero or not finite).
    pub fn for_start(&self, start: &[Impulse]) -> SolveParams {
        self.relative_to(start.iter().copied())
    }

    /// [`Self::for_start`] of the start `impulses` yields (no buffer needed).
    pub fn relative_to(&self, impulses: impl IntoIterator<Item = Impulse>) -> SolveParams {
        if self.stop != StopRule::Relative {
            return *self;
        }
        let (mut sum, mut rows) = (0.0f64, 0usize);
        for l in impulses {
            sum += (l.normal as f64).powi(2) + (l.tangent as f64).powi(2);
            rows += 1;
        }
        let rms = (sum / rows.max(1) as f64).sqrt() as f32;
        let scale = if rms.is_finite() && rms > 0.0 { rms } else { 1.0 };
        SolveParams { stop: StopRule::Natural, tolerance: self.tolerance * scale, ..*self }
    }

    /// What a compliance must be, in words: `in [0, 10]`.
    pub fn compliance_range() -> String {
        format!("in [0, {}]", Self::MAX_COMPLIANCE)
    }

    /// What a relaxation must be, in words: `in (0, 2)`.
    pub fn relaxation_range() -> String {
        format!("in (0, {})", Self::RELAXATION_LIMIT)
    }
}

/// The natural residual of a state: per row, what one projected Jacobi step from it would change,
/// in impulse units — normal `|ln - max(0, ln - m_n v_n)|`, tangent
/// `|lt - clip(lt - m_t v_t, +-mu ln)|` (with compliance, the step's target is scaled by
/// `1 / (1 + gamma)` as the sweep's is). Zero exactly at a solution of the LCP, whatever solver
/// got there; `max` over all rows and parts, `rms` over all rows' two parts.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NaturalResidual {
    pub max: f32,
    pub rms: f32,
}

/// Outcome of one velocity solve; the impulses and residuals stay in the solver's buffers.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolveReport {
    /// Sweeps performed (a momentum method's vector update belongs to its sweep).
    pub sweeps: u32,
    /// Whether the stopping rule was met before the sweep cap.
    pub converged: bool,
    /// The stopping rule's residual after the last sweep (0 without contacts).
    pub final_residual: f32,
    /// The natural residual of the final impulses (whatever the stopping rule).
    pub natural: NaturalResidual,
    /// Sparse Cholesky factorisations (Newton: one per iteration, counted in `sweeps` too).
    pub factorisations: u32,
    /// Coarse corrections kept, and tried but dropped (they would have raised the energy).
    pub corrections: u32,
    pub corrections_dropped: u32,
}

/// A row with its precomputed effective masses.
#[derive(Debug, Clone, Copy)]
pub(super) struct Prepared {
    pub(super) a: usize,
    pub(super) b: usize,
    pub(super) ra: Vec2,
    pub(super) rb: Vec2,
    pub(super) n: Vec2,
    pub(super) t: Vec2,
    /// The tangent bound is `mu * normal + fixed_bound`: the Box2D law (`fixed_bound` 0) or the
    /// per-step model's fixed bound (`mu` 0), without a branch in the sweep.
    mu: f32,
    fixed_bound: f32,
    pub(super) normal_mass: f32,
    pub(super) tangent_mass: f32,
    /// Whether body a and body b move under impulses (the coloured sweeps never write a static
    /// body, which rows of one colour may share).
    pub(super) moves: [bool; 2],
}

impl Prepared {
    /// The largest tangent impulse with normal impulse `normal`.
    #[inline(always)]
    pub(super) fn bound(&self, normal: f32) -> f32 {
        self.mu * normal + self.fixed_bound
    }

    pub(super) fn of(r: &ContactRow, bodies: &[SolverBody]) -> Prepared {
        let (a, b) = (r.body_a as usize, r.body_b as usize);
        let t = tangent_of(r.normal);
        Prepared {
            a,
            b,
            ra: r.ra,
            rb: r.rb,
            n: r.normal,
            t,
            mu: if r.friction_bound.is_some() { 0.0 } else { r.friction },
            fixed_bound: r.friction_bound.unwrap_or(0.0),
            normal_mass: effective_mass(&bodies[a], &bodies[b], r.ra, r.rb, r.normal),
            tangent_mass: effective_mass(&bodies[a], &bodies[b], r.ra, r.rb, t),
            moves: [bodies[a].moves(), bodies[b].moves()],
        }
    }
}

/// Where a sweep reads and writes the body velocities: the body slice (one thread), or the
/// coloured sweeps' shared view ([`super::colour`], several threads, each on its own rows).
pub(super) trait Velocities {
    /// Relative velocity of b with respect to a at the row's contact point.
    fn relative(&self, c: &Prepared) -> Vec2;
    /// Applies impulse `p` (on b; `-p` on a) at the row's contact point.
    fn apply(&mut self, c: &Prepared, p: Vec2);
}

impl Velocities for [SolverBody] {
    #[inline(always)]
    fn relative(&self, c: &Prepared) -> Vec2 {
        relative(self, c)
    }

    #[inline(always)]
    fn apply(&mut self, c: &Prepared, p: Vec2) {
        apply(self, c, p)
    }
}

/// One row's projected Gauss-Seidel (or SOR) update, tangent first, bounded by the current
/// normal impulse (Box2D's order); returns the row's change.
#[inline(always)]
pub(super) fn update_row<const RELAXED: bool, V: Velocities + ?Sized>(
    bodies: &mut V,
    c: &Prepared,
    l: &mut Impulse,
    softness: f32,
    relaxation: f32,
) -> Impulse {
    let relax = |old: f32, target: f32| if RELAXED { old + relaxation * (target - old) } else { target };
    let vt = bodies.relative(c).dot(c.t);
    let max_t = c.bound(l.normal);
    let new_t = relax(l.tangent, (l.tangent - c.tangent_mass * vt) * softness).clamp(-max_t, max_t);
    let dt = new_t - l.tangent;
    l.tangent = new_t;
    bodies.apply(c, c.t * dt);

    let vn = bodies.relative(c).dot(c.n);
    let new_n = relax(l.normal, (l.normal - c.normal_mass * vn) * softness).max(0.0);
    let dn = new_n - l.normal;
    l.normal = new_n;
    bodies.apply(c, c.n * dn);
    Impulse { normal: dn, tangent: dt }
}

/// One row of NNCG's vector update: move `beta` along the direction `p` (projected onto the
/// friction cone, the velocities following), then extend the direction by the sweep's change.
#[inline(always)]
pub(super) fn momentum_row<V: Velocities + ?Sized>(
    bodies: &mut V,
    c: &Prepared,
    l: &mut Impulse,
    p: &mut Impulse,
    dx: Impulse,
    beta: f32,
) {
    if beta > 0.0 {
        let normal = (l.normal + beta * p.normal).max(0.0);
        let max_t = c.bound(normal);
        let tangent = (l.tangent + beta * p.tangent).clamp(-max_t, max_t);
        let (dn, dt) = (normal - l.normal, tangent - l.tangent);
        *l = Impulse { normal, tangent };
        bodies.apply(c, c.n * dn + c.t * dt);
    }
    *p = Impulse { normal: beta * p.normal + dx.normal, tangent: beta * p.tangent + dx.tangent };
}

/// How many of a solve's last sweeps [`super::ContactSolver::trail`] keeps per row.
pub const TRAIL_SWEEPS: usize = 4;

/// What one sweep did: its largest absolute change and the sum of the squared changes.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct SweepChange {
    pub(super) max: f32,
    pub(super) squared: f64,
}

impl SweepChange {
    /// Counts one row's change.
    #[inline(always)]
    pub(super) fn add(&mut self, d: Impulse) {
        self.max = self.max.max(d.tangent.abs()).max(d.normal.abs());
        self.squared += (d.normal as f64).powi(2) + (d.tangent as f64).powi(2);
    }

    /// Two parts' changes as one (the earlier part first).
    pub(super) fn merge(self, later: SweepChange) -> SweepChange {
        SweepChange { max: self.max.max(later.max), squared: self.squared + later.squared }
    }
}

/// The natural residual's parts over some rows: the largest, and the sum of the squares.
#[inline]
pub(super) fn natural_residual_rows<V: Velocities + ?Sized>(
    prepared: &[Prepared],
    impulses: &[Impulse],
    bodies: &V,
    softness: f32,
) -> (f32, f64) {
    let (mut max, mut squared) = (0.0f32, 0.0f64);
    for (c, l) in prepared.iter().zip(impulses) {
        let dv = bodies.relative(c);
        let (vn, vt) = (dv.dot(c.n), dv.dot(c.t));
        let rn = (l.normal - ((l.normal - c.normal_mass * vn) * softness).max(0.0)).abs();
        let max_t = c.bound(l.normal);
        let rt = (l.tangent - ((l.tangent - c.tangent_mass * vt) * softness).clamp(-max_t, max_t)).abs();
        max = max.max(rn).max(rt);
        squared += (rn as f64).powi(2) + (rt as f64).powi(2);
    }
    (max, squared)
}

/// Relative velocity of b with respect to a at the contact point.
#[inline(always)]
fn relative(bodies: &[SolverBody], c: &Prepared) -> Vec2 {
    relative_of(&bodies[c.a], &bodies[c.b], c)
}

/// Relative velocity of `b` with respect to `a` at the row's contact point (the bodies however
/// they are reached: the slice, or the coloured sweeps' shared view).
#[inline(always)]
pub(super) fn relative_of(a: &SolverBody, b: &SolverBody, c: &Prepared) -> Vec2 {
    b.v + cross_sv(b.w, c.rb) - a.v - cross_sv(a.w, c.ra)
}

/// Applies impulse `p` (on b; `-p` on a) at the contact point.
#[inline(always)]
pub(super) fn apply(bodies: &mut [SolverBody], c: &Prepared, p: Vec2) {
    pull(&mut bodies[c.a], c.ra, p);
    push(&mut bodies[c.b], c.rb, p);
}

/// Body a's part of a row's impulse `p`: `-p` at `ra`.
#[inline(always)]
pub(super) fn pull(a: &mut SolverBody, ra: Vec2, p: Vec2) {
    a.v -= p * a.inv_mass;
    a.w -= a.inv_inertia * cross(ra, p);
}

/// Body b's part of a row's impulse `p`: `p` at `rb`.
#[inline(always)]
pub(super) fn push(b: &mut SolverBody, rb: Vec2, p: Vec2) {
    b.v += p * b.inv_mass;
    b.w += b.inv_inertia * cross(rb, p);
}
