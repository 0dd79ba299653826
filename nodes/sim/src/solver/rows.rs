//! The contact rows, bodies and impulses every solver and warm-start model shares, and the row
//! algebra on them: relative velocities, effective masses, a row's impulse on its bodies.
//!
//! `f32` helpers serve the solver's sweeps; the `f64` ones (`apply`, `relative`, `dot`) serve the
//! models that assemble a step's linear problem (Galerkin corrections, conjugate gradients).

use rapier2d::math::Vec2;

/// 2D cross product of two vectors (a scalar).
#[inline]
pub(crate) fn cross(a: Vec2, b: Vec2) -> f32 {
    a.x * b.y - a.y * b.x
}

/// Cross product of a scalar (angular velocity) and a vector: `w x r`.
#[inline]
pub(crate) fn cross_sv(w: f32, r: Vec2) -> Vec2 {
    Vec2::new(-w * r.y, w * r.x)
}

/// The tangent of a contact normal, Box2D's `b2Cross(normal, 1.0f)`.
#[inline]
pub fn tangent_of(n: Vec2) -> Vec2 {
    Vec2::new(n.y, -n.x)
}

/// A contact impulse: along the normal and along the tangent ([`tangent_of`] the normal).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Impulse {
    /// Normal impulse (>= 0 at a solution).
    pub normal: f32,
    /// Tangent (friction) impulse (`|t| <= mu * normal` at a solution).
    pub tangent: f32,
}

/// The velocity state and inverse mass properties of one body, as the solver sees it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolverBody {
    /// Linear velocity of the centre of mass.
    pub v: Vec2,
    /// Angular velocity.
    pub w: f32,
    /// Inverse mass (0 for static and kinematic bodies).
    pub inv_mass: f32,
    /// Inverse moment of inertia about the centre of mass (0 for static and kinematic bodies).
    pub inv_inertia: f32,
}

impl SolverBody {
    /// Whether impulses move the body (a positive inverse mass or inertia): not a static or
    /// kinematic body.
    #[inline(always)]
    pub fn moves(&self) -> bool {
        self.inv_mass > 0.0 || self.inv_inertia > 0.0
    }
}

/// One contact point as the velocity solver needs it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactRow {
    /// Index of body a in the solver's body slice.
    pub body_a: u32,
    /// Index of body b.
    pub body_b: u32,
    /// From body a's centre of mass to the contact point.
    pub ra: Vec2,
    /// From body b's centre of mass to the contact point.
    pub rb: Vec2,
    /// Unit normal from a to b.
    pub normal: Vec2,
    /// Friction coefficient.
    pub friction: f32,
    /// Height of the contact point (world y): the top-down row order's key.
    pub height: f32,
    /// The per-step friction model's bound: `|tangent| <= bound` whatever this step's normal
    /// impulse (`friction` times the contact's normal impulse of the previous step). `None`:
    /// the Box2D law, `|tangent| <= friction * normal` of this step's own normal impulse.
    pub friction_bound: Option<f32>,
}

/// Effective mass `1 / (J M^-1 J^T)` of a row with direction `d` (0 when both bodies are fixed).
#[inline]
pub(crate) fn effective_mass(a: &SolverBody, b: &SolverBody, ra: Vec2, rb: Vec2, d: Vec2) -> f32 {
    let rda = cross(ra, d);
    let rdb = cross(rb, d);
    let k = a.inv_mass + b.inv_mass + a.inv_inertia * rda * rda + b.inv_inertia * rdb * rdb;
    if k > 0.0 {
        1.0 / k
    } else {
        0.0
    }
}

/// Relative velocity of b with respect to a at a row's contact point: `(normal, tangent)` parts.
#[inline]
pub fn relative_velocity(row: &ContactRow, bodies: &[SolverBody]) -> (f32, f32) {
    let a = &bodies[row.body_a as usize];
    let b = &bodies[row.body_b as usize];
    let dv = b.v + cross_sv(b.w, row.rb) - a.v - cross_sv(a.w, row.ra);
    (dv.dot(row.normal), dv.dot(tangent_of(row.normal)))
}

/// Effective masses of a row's `(normal, tangent)` directions: a unit impulse change moves the
/// row's relative velocity by `1 / mass`.
pub fn row_masses(row: &ContactRow, bodies: &[SolverBody]) -> (f32, f32) {
    let a = &bodies[row.body_a as usize];
    let b = &bodies[row.body_b as usize];
    (effective_mass(a, b, row.ra, row.rb, row.normal), effective_mass(a, b, row.ra, row.rb, tangent_of(row.normal)))
}

/// The generalised impulse `J^T [normal, tangent]` of a row on each of its two bodies: per body
/// its index and `(x, y, torque)`.
pub fn body_impulses(row: &ContactRow, [n, t]: [f64; 2]) -> [(usize, [f64; 3]); 2] {
    let (normal, tangent) = (row.normal, tangent_of(row.normal));
    let p = [normal.x as f64 * n + tangent.x as f64 * t, normal.y as f64 * n + tangent.y as f64 * t];
    [(row.body_a as usize, row.ra, -1.0), (row.body_b as usize, row.rb, 1.0)].map(|(body, r, sign)| {
        let torque = r.x as f64 * p[1] - r.y as f64 * p[0];
        (body, [sign * p[0], sign * p[1], sign * torque])
    })
}

/// Adds the velocity change of impulse `[normal, tangent]` at `row` to `v` (per body vx, vy, w).
pub fn apply(v: &mut [[f64; 3]], bodies: &[SolverBody], row: &ContactRow, impulse: [f64; 2]) {
    for (body, j) in body_impulses(row, impulse) {
        let (im, ii) = (bodies[body].inv_mass as f64, bodies[body].inv_inertia as f64);
        v[body][0] += im * j[0];
        v[body][1] += im * j[1];
        v[body][2] += ii * j[2];
    }
}

/// Relative velocity of b with respect to a at the row's point: `[normal, tangent]`.
pub fn relative(v: &[[f64; 3]], row: &ContactRow) -> [f64; 2] {
    let at = |body: usize, r: rapier2d::math::Vec2| {
        let [vx, vy, w] = v[body];
        [vx - w * r.y as f64, vy + w * r.x as f64]
    };
    let (a, b) = (at(row.body_a as usize, row.ra), at(row.body_b as usize, row.rb));
    let d = [b[0] - a[0], b[1] - a[1]];
    let (n, t) = (row.normal, tangent_of(row.normal));
    [d[0] * n.x as f64 + d[1] * n.y as f64, d[0] * t.x as f64 + d[1] * t.y as f64]
}

/// The dot product of two per-row `[normal, tangent]` vectors.
pub fn dot(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x[0] * y[0] + x[1] * y[1]).sum()
}

/// `z += a x`.
pub fn axpy(z: &mut [[f64; 2]], a: f64, x: &[[f64; 2]]) {
    for (zi, xi) in z.iter_mut().zip(x) {
        zi[0] += a * xi[0];
        zi[1] += a * xi[1];
    }
}

#[cfg(test)]
pub(crate) mod fixtures {
    use super::*;

    /// A unit-mass ball moving at `v`.
    pub(crate) fn ball(v: Vec2) -> SolverBody {
        SolverBody { v, w: 0.0, inv_mass: 1.0, inv_inertia: 2.0 }
    }

    /// The contact row of ball `body` (radius 0.5) resting on body 0, the floor, below its centre.
    pub(crate) fn floor_row(body: u32) -> ContactRow {
        ContactRow {
            body_a: 0,
            body_b: body,
            ra: Vec2::ZERO,
            rb: Vec2::new(0.0, -0.5),
            normal: Vec2::Y,
            friction: 0.5,
            height: 0.0,
            friction_bound: None,
        }
    }

    /// Body `i` (1-based) of a stack of unit balls on the floor (body 0), all falling at `v`.
    pub(crate) fn stack(n: usize, v: f32) -> (Vec<SolverBody>, Vec<ContactRow>) {
        let mut bodies = vec![SolverBody::default()];
        bodies.extend((0..n).map(|_| ball(Vec2::new(0.0, v))));
        let rows = (0..n as u32)
            .map(|i| ContactRow {
                body_a: i,
                body_b: i + 1,
                // The floor's point is its own origin; a ball's top is 0.5 above its centre.
                ra: if i == 0 { Vec2::ZERO } else { Vec2::new(0.0, 0.5) },
                rb: Vec2::new(0.0, -0.5),
                normal: Vec2::Y,
                friction: 0.5,
                height: i as f32,
                friction_bound: None,
            })
            .collect();
        (bodies, rows)
    }

    /// A `w` x `h` lattice of unit balls on the floor (body 0), each touching its right and upper
    /// neighbour, falling at different speeds (so the loads are not uniform), and the rows; friction
    /// under the per-step law (each step's problem a convex QP, one bound pass).
    pub(crate) fn lattice(w: usize, h: usize) -> (Vec<SolverBody>, Vec<ContactRow>) {
        let mut bodies = vec![SolverBody::default()];
        bodies.extend((0..w * h).map(|k| ball(Vec2::new(0.02 * (k % 7) as f32, -0.1 - 0.01 * (k % 5) as f32))));
        let id = |x: usize, y: usize| (1 + y * w + x) as u32;
        let mut rows = Vec::new();
        for y in 0..h {
            for x in 0..w {
                if y == 0 {
                    rows.push(ContactRow {
                        ra: Vec2::new(x as f32, 0.0),
                        friction_bound: Some(0.05),
                        ..floor_row(id(x, 0))
                    });
                }
                for (dx, dy) in [(1usize, 0usize), (0, 1)] {
                    if x + dx < w && y + dy < h {
                        let half = Vec2::new(0.5 * dx as f32, 0.5 * dy as f32);
                        rows.push(ContactRow {
                            body_a: id(x, y),
                            body_b: id(x + dx, y + dy),
                            ra: half,
                            rb: -half,
                            normal: Vec2::new(dx as f32, dy as f32),
                            friction: 0.5,
                            height: y as f32 + 0.5 * dy as f32,
                            friction_bound: Some(0.02),
                        });
                    }
                }
            }
        }
        (bodies, rows)
    }
}
