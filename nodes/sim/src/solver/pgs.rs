//! Projected Gauss-Seidel, in the style of Box2D 2.3 (sequential impulses), but iterated to a
//! tolerance from any warm start and with its sweeps counted.
//!
//! Apply the warm-start impulses to the velocities (Box2D's `WarmStart`), then projected
//! Gauss-Seidel sweeps over the contact rows, each contact's tangent row (bounded by
//! `mu * lambda_n`) before its normal row (`lambda_n >= 0`). A sweep's residual is the largest
//! absolute impulse change it made; the solve has converged when that is at most the tolerance.
//! No Baumgarte bias enters the velocity solve (restitution 0), so the converged impulses solve
//! the plain velocity-level LCP and can be checked against it.
//!
//! No Box2D block solver for two-point manifolds: every point is its own row, which keeps the
//! iteration count comparable across warm-start models and the complementarity check simple.
//! The solver owns only reusable buffers; bodies and contact rows are passed in.

use super::rows::{cross, cross_sv, effective_mass, tangent_of, ContactRow, Impulse, SolverBody};
use rapier2d::math::Vec2;

/// Stopping rule of the velocity solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveParams {
    /// Converged when the largest absolute impulse change of a sweep is at most this.
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
    /// (projected SOR); in (0, 2). Jammed piles converge in fewer sweeps with omega ~1.5.
    pub relaxation: f32,
}

impl Default for SolveParams {
    fn default() -> Self {
        SolveParams { tolerance: 1e-4, max_sweeps: 1000, compliance: 0.0, relaxation: 1.0 }
    }
}

impl SolveParams {
    /// The largest compliance: contacts eleven times softer than their effective mass says; more
    /// is not a contact any more.
    pub const MAX_COMPLIANCE: f32 = 10.0;
    /// Relaxation lies strictly between 0 and this: outside, projected SOR does not converge.
    pub const RELAXATION_LIMIT: f32 = 2.0;

    pub fn valid_compliance(gamma: f32) -> bool {
        gamma.is_finite() && (0.0..=Self::MAX_COMPLIANCE).contains(&gamma)
    }

    pub fn valid_relaxation(omega: f32) -> bool {
        omega.is_finite() && omega > 0.0 && omega < Self::RELAXATION_LIMIT
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

/// Outcome of one velocity solve; the impulses and residuals stay in the solver's buffers.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolveReport {
    /// Sweeps performed.
    pub sweeps: u32,
    /// Whether the tolerance was reached before the sweep cap.
    pub converged: bool,
    /// Residual of the last sweep (0 without contacts).
    pub final_residual: f32,
}

/// A row with its precomputed effective masses.
#[derive(Debug, Clone, Copy)]
struct Prepared {
    a: usize,
    b: usize,
    ra: Vec2,
    rb: Vec2,
    n: Vec2,
    t: Vec2,
    mu: f32,
    normal_mass: f32,
    tangent_mass: f32,
}

/// Sequential-impulse contact solver: reusable buffers only, no world state.
#[derive(Debug, Default, Clone)]
pub struct ContactSolver {
    prepared: Vec<Prepared>,
    impulses: Vec<Impulse>,
    residuals: Vec<f32>,
    /// Each row's impulse changes in the last [`TRAIL_SWEEPS`] sweeps (the directions the
    /// iteration was still moving in: its slowest modes), most recent first once a solve ends.
    trail: Vec<[Impulse; TRAIL_SWEEPS]>,
}

/// How many of a solve's last sweeps [`ContactSolver::trail`] keeps per row.
pub const TRAIL_SWEEPS: usize = 4;

impl ContactSolver {
    /// An empty solver (buffers grow on first use).
    pub fn new() -> ContactSolver {
        ContactSolver::default()
    }

    /// Solves the velocity-level contact problem of `rows` starting from `warm_start` (one impulse
    /// per row), updating the body velocities in place. The final impulses are in
    /// [`Self::impulses`], the residual after every sweep in [`Self::residuals`].
    pub fn solve(
        &mut self,
        rows: &[ContactRow],
        bodies: &mut [SolverBody],
        warm_start: &[Impulse],
        params: &SolveParams,
    ) -> SolveReport {
        assert_eq!(rows.len(), warm_start.len(), "one warm-start impulse per contact row");
        self.prepared.clear();
        self.prepared.extend(rows.iter().map(|r| {
            let (a, b) = (r.body_a as usize, r.body_b as usize);
            let t = tangent_of(r.normal);
            Prepared {
                a,
                b,
                ra: r.ra,
                rb: r.rb,
                n: r.normal,
                t,
                mu: r.friction,
                normal_mass: effective_mass(&bodies[a], &bodies[b], r.ra, r.rb, r.normal),
                tangent_mass: effective_mass(&bodies[a], &bodies[b], r.ra, r.rb, t),
            }
        }));
        self.impulses.clear();
        // A guess outside the friction cone (a learned model may predict a negative normal
        // impulse, or NaN) is projected onto it first: the sweeps assume normal >= 0.
        self.impulses.extend(self.prepared.iter().zip(warm_start).map(|(c, w)| {
            let normal = if w.normal.is_finite() { w.normal.max(0.0) } else { 0.0 };
            let max_t = c.mu * normal;
            let tangent = if w.tangent.is_finite() { w.tangent.clamp(-max_t, max_t) } else { 0.0 };
            Impulse { normal, tangent }
        }));
        self.residuals.clear();
        self.trail.clear();
        self.trail.resize(self.impulses.len(), [Impulse::default(); TRAIL_SWEEPS]);

        // Box2D's WarmStart: the (projected) guess is applied as it is.
        for (c, l) in self.prepared.iter().zip(&self.impulses) {
            let p = c.n * l.normal + c.t * l.tangent;
            apply(bodies, c, p);
        }

        if self.prepared.is_empty() {
            return SolveReport { sweeps: 0, converged: true, final_residual: 0.0 };
        }

        // The compliant update is the rigid one scaled by 1 / (1 + gamma): exactly 1 when rigid.
        let softness = 1.0 / (1.0 + params.compliance);
        let mut report = SolveReport::default();
        while report.sweeps < params.max_sweeps {
            let slot = report.sweeps as usize % TRAIL_SWEEPS;
            // Plain Gauss-Seidel keeps its own loop: the unrelaxed solver bit for bit, at its speed.
            let residual = if params.relaxation == 1.0 {
                self.sweep::<false>(bodies, slot, softness, 1.0)
            } else {
                self.sweep::<true>(bodies, slot, softness, params.relaxation)
            };
            report.sweeps += 1;
            report.final_residual = residual;
            self.residuals.push(residual);
            if residual <= params.tolerance {
                report.converged = true;
                break;
            }
        }
        // The sweeps wrote a ring; put the last sweep first.
        let newest = (report.sweeps as usize + TRAIL_SWEEPS - 1) % TRAIL_SWEEPS;
        for t in &mut self.trail {
            let ring = *t;
            *t = std::array::from_fn(|j| ring[(newest + TRAIL_SWEEPS - j) % TRAIL_SWEEPS]);
        }
        report
    }

    /// One projected Gauss-Seidel sweep, its changes written to slot `slot` of the trail; returns
    /// the largest absolute impulse change.
    fn sweep<const RELAXED: bool>(
        &mut self,
        bodies: &mut [SolverBody],
        slot: usize,
        softness: f32,
        relaxation: f32,
    ) -> f32 {
        let relax = |old: f32, target: f32| if RELAXED { old + relaxation * (target - old) } else { target };
        let mut residual = 0.0f32;
        for ((c, l), trail) in self.prepared.iter().zip(self.impulses.iter_mut()).zip(self.trail.iter_mut()) {
            // Tangent first, bounded by the current normal impulse (Box2D's order).
            let dv = relative(bodies, c);
            let vt = dv.dot(c.t);
            let max_t = c.mu * l.normal;
            let new_t = relax(l.tangent, (l.tangent - c.tangent_mass * vt) * softness).clamp(-max_t, max_t);
            let dt = new_t - l.tangent;
            l.tangent = new_t;
            apply(bodies, c, c.t * dt);

            let dv = relative(bodies, c);
            let vn = dv.dot(c.n);
            let new_n = relax(l.normal, (l.normal - c.normal_mass * vn) * softness).max(0.0);
            let dn = new_n - l.normal;
            l.normal = new_n;
            apply(bodies, c, c.n * dn);

            trail[slot] = Impulse { normal: dn, tangent: dt };
            residual = residual.max(dt.abs()).max(dn.abs());
        }
        residual
    }

    /// The impulses of the last solve, one per row.
    pub fn impulses(&self) -> &[Impulse] {
        &self.impulses
    }

    /// The residual after every sweep of the last solve.
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

/// Relative velocity of b with respect to a at the contact point.
#[inline(always)]
fn relative(bodies: &[SolverBody], c: &Prepared) -> Vec2 {
    let a = &bodies[c.a];
    let b = &bodies[c.b];
    b.v + cross_sv(b.w, c.rb) - a.v - cross_sv(a.w, c.ra)
}

/// Applies impulse `p` (on b; `-p` on a) at the contact point.
#[inline(always)]
fn apply(bodies: &mut [SolverBody], c: &Prepared, p: Vec2) {
    let a = &mut bodies[c.a];
    a.v -= p * a.inv_mass;
    a.w -= a.inv_inertia * cross(c.ra, p);
    let b = &mut bodies[c.b];
    b.v += p * b.inv_mass;
    b.w += b.inv_inertia * cross(c.rb, p);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::rows::fixtures::{ball, floor_row};
    use crate::solver::rows::relative_velocity;

    /// A ball (mass 1, falling at 1 after gravity) on two contact rows at the same point: the
    /// rigid problem only fixes their sum, the compliant one has a single answer.
    fn twin_rows(warm: [f32; 2], compliance: f32) -> [f32; 2] {
        let row = floor_row(1);
        let mut bodies = [SolverBody::default(), ball(Vec2::new(0.0, -1.0))];
        let warm = warm.map(|normal| Impulse { normal, tangent: 0.0 });
        let params = SolveParams { tolerance: 1e-7, max_sweeps: 10_000, compliance, relaxation: 1.0 };
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
}
