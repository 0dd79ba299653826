//! `cg:K` — builtin plus K conjugate-gradient iterations on the step's own linear problem, on
//! builtin's active set: a global solve, its cost paid in the warm start.
//!
//! The closed normals and sticking tangents of builtin's (projected) guess are taken as the
//! step's active set; on it the step asks `u + C lambda = 0` (u the rows' relative velocity, C the
//! solver's compliance, `gamma / m` per row). From builtin the correction `y` solves
//! `(W + C + R) y = -(u + C lambda_builtin)` with `W = J M^-1 J^T`, by Jacobi-preconditioned CG.
//! `R` regularises rigid problems only (`RIGID_REGULARISATION` of each row's own `W_ii`): a
//! jammed pile's `W` has a null space and near-null modes, and the exact least-squares
//! correction chases them far from where PGS stops (README "Not even an exact linear solve
//! pays"); with compliance the problem is regular as it stands and is solved as it is.
//! Not learned: it measures what a global linear solve from builtin buys, which a learned model
//! would have to approximate to pay.

use crate::solver::{row_masses, ContactRow, Impulse, SolverBody};
use crate::subspace::{apply, dot, project_to_cone, relative, step_residual};
use crate::warm::{Unavailable, WarmStartInput, WarmStartModel};

/// Regularisation of a rigid problem, relative to each row's `W_ii` (the best of the uncounted
/// probe's 1e-4 / 1e-3).
pub const RIGID_REGULARISATION: f64 = 1e-4;

/// CG stops early when the preconditioned residual has fallen by this factor.
const RELATIVE_TOLERANCE: f64 = 1e-8;

/// See the module documentation.
#[derive(Debug)]
pub struct ConjugateGradient {
    name: String,
    iterations: usize,
    velocities: Vec<[f64; 3]>,
    residual: Vec<[f64; 2]>,
    /// Per row `W_ii` of its normal and tangent on the active rows, 0 elsewhere (the mask of the
    /// system, and with `extra` its diagonal shift and its Jacobi preconditioner).
    weights: Vec<[f64; 2]>,
    correction: Vec<[f64; 2]>,
    direction: Vec<[f64; 2]>,
    product: Vec<[f64; 2]>,
    preconditioned: Vec<[f64; 2]>,
}

impl ConjugateGradient {
    /// At most `iterations` CG iterations (each one product with `W`, about a sweep's work).
    pub fn new(name: String, iterations: usize) -> ConjugateGradient {
        ConjugateGradient {
            name,
            iterations,
            velocities: Vec::new(),
            residual: Vec::new(),
            weights: Vec::new(),
            correction: Vec::new(),
            direction: Vec::new(),
            product: Vec::new(),
            preconditioned: Vec::new(),
        }
    }

    /// `product = (W + extra W_ii) x` on the active rows.
    fn multiply(&mut self, rows: &[ContactRow], bodies: &[SolverBody], extra: f64, x: &[[f64; 2]]) {
        self.velocities.clear();
        self.velocities.resize(bodies.len(), [0.0; 3]);
        for (row, xi) in rows.iter().zip(x) {
            apply(&mut self.velocities, bodies, row, *xi);
        }
        self.product.clear();
        self.product.extend(rows.iter().zip(x).zip(&self.weights).map(|((row, xi), w)| {
            let [vn, vt] = relative(&self.velocities, row);
            [
                if w[0] > 0.0 { vn + w[0] * extra * xi[0] } else { 0.0 },
                if w[1] > 0.0 { vt + w[1] * extra * xi[1] } else { 0.0 },
            ]
        }));
    }
}

impl WarmStartModel for ConjugateGradient {
    fn name(&self) -> &str {
        &self.name
    }

    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        input.history.fill_previous(input.contacts, out);
        let (rows, bodies) = (input.rows, input.bodies);
        if rows.len() != out.len() || rows.is_empty() || self.iterations == 0 {
            return Ok(());
        }
        let active = project_to_cone(rows, out);
        step_residual(bodies, rows, out, &active, &mut self.velocities, &mut self.residual);
        let gamma = input.compliance as f64;
        let extra = if gamma > 0.0 { gamma } else { RIGID_REGULARISATION };
        // Per row: W_ii (1 / effective mass) where active; the compliance's C_ii = gamma W_ii and
        // the regularisation's are `extra` W_ii; the residual also owes C lambda_builtin.
        self.weights.clear();
        for (((row, act), o), r) in rows.iter().zip(&active).zip(out.iter()).zip(self.residual.iter_mut()) {
            let (mn, mt) = row_masses(row, bodies);
            let w = [if mn > 0.0 { 1.0 / mn as f64 } else { 0.0 }, if mt > 0.0 { 1.0 / mt as f64 } else { 0.0 }];
            let on = [act[0] && w[0] > 0.0, act[1] && w[1] > 0.0];
            self.weights.push([if on[0] { w[0] } else { 0.0 }, if on[1] { w[1] } else { 0.0 }]);
            r[0] = if on[0] { r[0] - gamma * w[0] * o.normal as f64 } else { 0.0 };
            r[1] = if on[1] { r[1] - gamma * w[1] * o.tangent as f64 } else { 0.0 };
        }

        // Jacobi-preconditioned CG from y = 0; the diagonal is (1 + extra) W_ii.
        let precondition = |r: &[[f64; 2]], weights: &[[f64; 2]], z: &mut Vec<[f64; 2]>| {
            z.clear();
            z.extend(r.iter().zip(weights).map(|(r, w)| {
                [
                    if w[0] > 0.0 { r[0] / (w[0] * (1.0 + extra)) } else { 0.0 },
                    if w[1] > 0.0 { r[1] / (w[1] * (1.0 + extra)) } else { 0.0 },
                ]
            }));
        };
        self.correction.clear();
        self.correction.resize(rows.len(), [0.0; 2]);
        let mut z = std::mem::take(&mut self.preconditioned);
        precondition(&self.residual, &self.weights, &mut z);
        self.direction.clone_from(&z);
        let mut rz = dot(&self.residual, &z);
        let start = rz;
        for _ in 0..self.iterations {
            // Converged (or not a number: the correction is dropped below).
            if rz.is_nan() || rz <= RELATIVE_TOLERANCE * RELATIVE_TOLERANCE * start {
                break;
            }
            let direction = std::mem::take(&mut self.direction);
            self.multiply(rows, bodies, extra, &direction);
            self.direction = direction;
            let curvature = dot(&self.direction, &self.product);
            if curvature.is_nan() || curvature <= 0.0 {
                break;
            }
            let step = rz / curvature;
            for (((y, r), p), q) in
                self.correction.iter_mut().zip(self.residual.iter_mut()).zip(&self.direction).zip(&self.product)
            {
                for k in 0..2 {
                    y[k] += step * p[k];
                    r[k] -= step * q[k];
                }
            }
            precondition(&self.residual, &self.weights, &mut z);
            let next = dot(&self.residual, &z);
            let beta = next / rz;
            for (p, zi) in self.direction.iter_mut().zip(&z) {
                p[0] = zi[0] + beta * p[0];
                p[1] = zi[1] + beta * p[1];
            }
            rz = next;
        }
        self.preconditioned = z;
        if self.correction.iter().any(|y| !(y[0].is_finite() && y[1].is_finite())) {
            return Ok(());
        }
        for (o, y) in out.iter_mut().zip(&self.correction) {
            o.normal += y[0] as f32;
            o.tangent += y[1] as f32;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::ImpulseHistory;
    use crate::solver::tests::{ball, floor_row};
    use crate::warm::tests::{floor_contact, guess_on_rows};
    use rapier2d::math::Vec2;

    /// Ground and a unit-mass ball falling at 1 on two contact rows at the same point; builtin
    /// remembers `previous` for them.
    fn guess(model: &mut ConjugateGradient, previous: [f32; 2], compliance: f32) -> Vec<Impulse> {
        let bodies = [SolverBody::default(), ball(Vec2::new(0.0, -1.0))];
        let contacts = [floor_contact(1, 0, 0.0), floor_contact(1, 1, 0.0)];
        let mut history = ImpulseHistory::default();
        let previous = previous.map(|normal| Impulse { normal, tangent: 0.0 });
        history.push(contacts.iter().map(|c| c.key), &previous, ImpulseHistory::no_trail());
        guess_on_rows(model, &contacts, &history, &[floor_row(1), floor_row(1)], &bodies, compliance)
    }

    #[test]
    fn the_compliant_step_is_solved_exactly_from_builtin() {
        // Compliance 0.1: the one answer is 1 / 2.1 on each row (the solver's own test), from
        // builtin's lopsided 0.7 / 0.1.
        let g = guess(&mut ConjugateGradient::new("cg:20".into(), 20), [0.7, 0.1], 0.1);
        for l in &g {
            assert!((l.normal - 1.0 / 2.1).abs() < 1e-5 && l.tangent.abs() < 1e-6, "{g:?}");
        }
    }

    #[test]
    fn a_rigid_step_keeps_builtins_split_and_completes_the_sum() {
        // Rigid: only the sum (1) is fixed; the regularised correction adds the missing 0.2
        // equally (its least change) and keeps builtin's split, up to the regularisation.
        let g = guess(&mut ConjugateGradient::new("cg:20".into(), 20), [0.7, 0.1], 0.0);
        assert!((g[0].normal + g[1].normal - 1.0).abs() < 1e-3, "{g:?}");
        assert!((g[0].normal - g[1].normal - 0.6).abs() < 1e-3, "{g:?}");
        // No iterations: builtin as it is.
        let g = guess(&mut ConjugateGradient::new("cg:0".into(), 0), [0.7, 0.1], 0.0);
        assert_eq!((g[0].normal, g[1].normal), (0.7, 0.1));
    }
}
