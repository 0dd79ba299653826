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

use super::galerkin::{builtin_step, BuiltinStep};
use crate::solver::rows::{apply, dot, relative, row_masses, ContactRow, Impulse, SolverBody};
use crate::warm::model::{Needs, Unavailable, WarmStartInput, WarmStartModel};

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
    /// system).
    weights: Vec<[f64; 2]>,
    /// Per row the system's diagonal shift (the compliance's `C_ii`, or the rigid problem's
    /// regularisation) and its whole diagonal (the Jacobi preconditioner), on the active rows.
    shift: Vec<[f64; 2]>,
    diagonal: Vec<[f64; 2]>,
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
            shift: Vec::new(),
            diagonal: Vec::new(),
            correction: Vec::new(),
            direction: Vec::new(),
            product: Vec::new(),
            preconditioned: Vec::new(),
        }
    }

    /// `product = (W + shift) x` on the active rows.
    fn multiply(&mut self, rows: &[ContactRow], bodies: &[SolverBody], x: &[[f64; 2]]) {
        self.velocities.clear();
        self.velocities.resize(bodies.len(), [0.0; 3]);
        for (row, xi) in rows.iter().zip(x) {
            apply(&mut self.velocities, bodies, row, *xi);
        }
        self.product.clear();
        self.product.extend(rows.iter().zip(x).zip(self.weights.iter().zip(&self.shift)).map(|((row, xi), (w, c))| {
            let [vn, vt] = relative(&self.velocities, row);
            [if w[0] > 0.0 { vn + c[0] * xi[0] } else { 0.0 }, if w[1] > 0.0 { vt + c[1] * xi[1] } else { 0.0 }]
        }));
    }
}

impl WarmStartModel for ConjugateGradient {
    fn name(&self) -> &str {
        &self.name
    }

    fn needs(&self) -> Needs {
        Needs::ROWS
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        if self.iterations == 0 {
            input.history.fill_previous(input.contacts, out);
            return Ok(());
        }
        let Some(BuiltinStep { rows, bodies, active, compliance }) =
            builtin_step(input, out, &mut self.velocities, &mut self.residual)
        else {
            return Ok(());
        };
        // Per active row: W_ii (1 / effective mass); the shift is the compliance's C_ii or, for a
        // rigid problem, the regularisation's RIGID_REGULARISATION W_ii; rows the system leaves
        // out (inactive, or between fixed bodies) owe nothing.
        self.weights.clear();
        self.shift.clear();
        self.diagonal.clear();
        for (i, (row, act)) in rows.iter().zip(&active).enumerate() {
            let (mn, mt) = row_masses(row, bodies);
            let (mut w, mut shift, mut diagonal) = ([0.0; 2], [0.0; 2], [0.0; 2]);
            for (k, m) in [mn, mt].into_iter().enumerate() {
                if act[k] && m > 0.0 {
                    w[k] = 1.0 / m as f64;
                    (shift[k], diagonal[k]) = match &compliance {
                        Some(c) => (c[i][k], w[k] + c[i][k]),
                        None => (w[k] * RIGID_REGULARISATION, w[k] * (1.0 + RIGID_REGULARISATION)),
                    };
                } else {
                    self.residual[i][k] = 0.0;
                }
            }
            self.weights.push(w);
            self.shift.push(shift);
            self.diagonal.push(diagonal);
        }

        // Jacobi-preconditioned CG from y = 0.
        let precondition = |r: &[[f64; 2]], diagonal: &[[f64; 2]], z: &mut Vec<[f64; 2]>| {
            z.clear();
            z.extend(r.iter().zip(diagonal).map(|(r, d)| {
                [if d[0] > 0.0 { r[0] / d[0] } else { 0.0 }, if d[1] > 0.0 { r[1] / d[1] } else { 0.0 }]
            }));
        };
        self.correction.clear();
        self.correction.resize(rows.len(), [0.0; 2]);
        let mut z = std::mem::take(&mut self.preconditioned);
        precondition(&self.residual, &self.diagonal, &mut z);
        self.direction.clone_from(&z);
        let mut rz = dot(&self.residual, &z);
        let start = rz;
        for _ in 0..self.iterations {
            // Converged (or not a number: the correction is dropped below).
            if rz.is_nan() || rz <= RELATIVE_TOLERANCE * RELATIVE_TOLERANCE * start {
                break;
            }
            let direction = std::mem::take(&mut self.direction);
            self.multiply(rows, bodies, &direction);
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
            precondition(&self.residual, &self.diagonal, &mut z);
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
    use crate::solver::rows::fixtures::{ball, floor_row};
    use crate::warm::model::harness::{floor_contact, guess_on_rows};
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
