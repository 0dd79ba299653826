//! `coarse:S` — builtin's warm start with a coarse-grid correction: the step's own problem solved
//! exactly within piecewise-constant stress fields over square cells of side S.
//!
//! PGS is a smoother: it removes local error in a few sweeps and stalls on error that is smooth
//! over the pile (README "Headroom"). In a packing, a uniform stress `sigma` carried by contact
//! forces `f = sigma n` leaves every interior body in balance: such fields barely change any
//! velocity, which is what makes them PGS's slowest modes — and builtin's step-to-step error in
//! a settling pile is mostly of that kind. So the model cuts the scene into cells, gives each
//! cell the three components of a uniform stress (each contact's `[n^T S n, t^T S n]` for
//! `S = xx, yy, xy`, on active rows only) and adds to builtin's guess the combination that best
//! solves the step's linearised problem in the energy norm of its `J M^-1 J^T` (a Galerkin
//! system, as in algebraic multigrid's coarse-grid correction, applied once before the sweeps).
//! The system is assembled per body from the cells that touch it, so it costs one pass over the
//! rows plus a dense solve of 3 x cells unknowns. Not learned.

use std::collections::HashMap;

use super::galerkin::{builtin_step, BuiltinStep};
use crate::solver::rows::{body_impulses, tangent_of, Impulse};
use crate::solver::stress_parts;
use crate::warm::model::{Needs, Unavailable, WarmStartInput, WarmStartModel};

/// Basis vectors per cell: the stress components xx, yy, xy.
const PER_CELL: usize = 3;

/// See the module documentation.
#[derive(Debug)]
pub struct Coarse {
    name: String,
    /// Side of a cell in metres.
    cell: f32,
    /// Scratch, reused across steps.
    velocities: Vec<[f64; 3]>,
    residual: Vec<[f64; 2]>,
    /// Per row: its cell and the `[normal, tangent]` value of each of the cell's basis vectors.
    row_cells: Vec<usize>,
    row_basis: Vec<[[f64; 2]; PER_CELL]>,
    /// Per body: the generalised force (x, y, torque) of each basis vector that touches it.
    body_forces: Vec<Vec<(usize, [f64; 3])>>,
    /// The cells met this step, numbered; the Galerkin system (row-major).
    cells: HashMap<(i32, i32), usize>,
    system: Vec<f64>,
}

impl Coarse {
    /// Cells of side `cell` metres (> 0).
    pub fn new(name: String, cell: f32) -> Coarse {
        Coarse {
            name,
            cell,
            velocities: Vec::new(),
            residual: Vec::new(),
            row_cells: Vec::new(),
            row_basis: Vec::new(),
            body_forces: Vec::new(),
            cells: HashMap::new(),
            system: Vec::new(),
        }
    }
}

impl WarmStartModel for Coarse {
    fn name(&self) -> &str {
        &self.name
    }

    fn needs(&self) -> Needs {
        Needs::ROWS
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let Some(BuiltinStep { rows, bodies, active, compliance }) =
            builtin_step(input, out, &mut self.velocities, &mut self.residual)
        else {
            return Ok(());
        };

        // Cells numbered in the order rows (sorted by contact key) first meet them: deterministic.
        let cells = &mut self.cells;
        cells.clear();
        self.row_cells.clear();
        self.row_basis.clear();
        for ((contact, row), act) in input.contacts.iter().zip(rows).zip(&active) {
            let at = ((contact.point.x / self.cell).floor() as i32, (contact.point.y / self.cell).floor() as i32);
            let next = cells.len();
            self.row_cells.push(*cells.entry(at).or_insert(next));
            self.row_basis.push(stress_parts(row.normal, tangent_of(row.normal), *act));
        }
        let unknowns = cells.len() * PER_CELL;

        // Per body, the generalised force of every basis vector acting on it (J^T z).
        self.body_forces.iter_mut().for_each(Vec::clear);
        self.body_forces.resize_with(bodies.len(), Vec::new);
        for ((row, &cell), values) in rows.iter().zip(&self.row_cells).zip(&self.row_basis) {
            for (s, value) in values.iter().enumerate() {
                if *value == [0.0; 2] {
                    continue;
                }
                for (body, force) in body_impulses(row, *value) {
                    let index = cell * PER_CELL + s;
                    let forces = &mut self.body_forces[body];
                    match forces.iter_mut().find(|(j, _)| *j == index) {
                        Some((_, f)) => (0..3).for_each(|d| f[d] += force[d]),
                        None => forces.push((index, force)),
                    }
                }
            }
        }

        // Galerkin: (Z^T W Z) y = Z^T r with W = J M^-1 J^T, summed body by body.
        let system = &mut self.system;
        system.clear();
        system.resize(unknowns * unknowns, 0.0);
        for (body, forces) in bodies.iter().zip(&self.body_forces) {
            let inverse = [body.inv_mass as f64, body.inv_mass as f64, body.inv_inertia as f64];
            if inverse == [0.0; 3] {
                continue;
            }
            for (j, fj) in forces {
                for (k, fk) in forces {
                    system[j * unknowns + k] += (0..3).map(|d| fj[d] * inverse[d] * fk[d]).sum::<f64>();
                }
            }
        }
        // Compliance adds Z^T C Z: per row, within its cell's block.
        if let Some(c) = &compliance {
            for ((&cell, values), c) in self.row_cells.iter().zip(&self.row_basis).zip(c) {
                for (a, va) in values.iter().enumerate() {
                    for (b, vb) in values.iter().enumerate() {
                        system[(cell * PER_CELL + a) * unknowns + cell * PER_CELL + b] +=
                            c[0] * va[0] * vb[0] + c[1] * va[1] * vb[1];
                    }
                }
            }
        }
        let mut rhs = vec![0.0f64; unknowns];
        for ((&cell, values), r) in self.row_cells.iter().zip(&self.row_basis).zip(&self.residual) {
            for (s, v) in values.iter().enumerate() {
                rhs[cell * PER_CELL + s] += v[0] * r[0] + v[1] * r[1];
            }
        }
        let Some(y) = solve_semidefinite(system, &rhs, unknowns) else { return Ok(()) };
        for ((o, &cell), values) in out.iter_mut().zip(&self.row_cells).zip(&self.row_basis) {
            let (mut dn, mut dt) = (0.0, 0.0);
            for (s, v) in values.iter().enumerate() {
                dn += y[cell * PER_CELL + s] * v[0];
                dt += y[cell * PER_CELL + s] * v[1];
            }
            o.normal += dn as f32;
            o.tangent += dt as f32;
        }
        Ok(())
    }
}

/// Solves the symmetric positive semi-definite `n x n` system `a x = b` (row-major, overwritten)
/// by Cholesky, leaving out every unknown whose pivot is below 1e-9 of its diagonal — a basis
/// vector the step's problem cannot see, or one the earlier ones already span, gets 0. `None`
/// when nothing is left or a value is not finite.
pub fn solve_semidefinite(a: &mut [f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    let diagonal: Vec<f64> = (0..n).map(|i| a[i * n + i]).collect();
    let mut kept = vec![false; n];
    // In place: the lower triangle becomes L, column by column.
    for j in 0..n {
        let s = a[j * n + j] - (0..j).filter(|&k| kept[k]).map(|k| a[j * n + k] * a[j * n + k]).sum::<f64>();
        if !(diagonal[j] > 0.0 && s > 1e-9 * diagonal[j]) {
            continue;
        }
        let pivot = s.sqrt();
        a[j * n + j] = pivot;
        kept[j] = true;
        for i in j + 1..n {
            let s = a[i * n + j] - (0..j).filter(|&k| kept[k]).map(|k| a[i * n + k] * a[j * n + k]).sum::<f64>();
            a[i * n + j] = s / pivot;
        }
    }
    if !kept.iter().any(|&k| k) {
        return None;
    }
    let mut y = vec![0.0f64; n];
    for i in (0..n).filter(|&i| kept[i]) {
        let s = b[i] - (0..i).filter(|&k| kept[k]).map(|k| a[i * n + k] * y[k]).sum::<f64>();
        y[i] = s / a[i * n + i];
    }
    let mut x = vec![0.0f64; n];
    for i in (0..n).rev().filter(|&i| kept[i]) {
        let s = y[i] - (i + 1..n).filter(|&k| kept[k]).map(|k| a[k * n + i] * x[k]).sum::<f64>();
        x[i] = s / a[i * n + i];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_semidefinite_solve_leaves_out_dependent_unknowns() {
        // x0 and x1 are the same direction twice, x2 independent: 2 x0 + 2 x1 = 2, 3 x2 = 6.
        let mut a = vec![2.0, 2.0, 0.0, 2.0, 2.0, 0.0, 0.0, 0.0, 3.0];
        let x = solve_semidefinite(&mut a, &[2.0, 2.0, 6.0], 3).unwrap();
        assert!((x[0] - 1.0).abs() < 1e-12 && x[1] == 0.0 && (x[2] - 2.0).abs() < 1e-12, "{x:?}");
        let mut zero = vec![0.0; 4];
        assert!(solve_semidefinite(&mut zero, &[1.0, 1.0], 2).is_none());
    }

    use crate::contact::ImpulseHistory;
    use crate::solver::rows::fixtures::{ball, floor_row};
    use crate::solver::rows::SolverBody;
    use crate::warm::model::harness::{floor_contact, guess_on_rows};
    use rapier2d::math::Vec2;

    /// Ground (fixed) and two unit-mass balls falling at 1 and 2 (velocity after gravity), each
    /// resting on one contact at x = 0 and x = `apart`; builtin remembers 0.4 and 0.5 where the
    /// step needs 1 and 2 (the speed times the mass).
    fn guess(model: &mut Coarse, apart: f32, compliance: f32) -> Vec<Impulse> {
        let bodies = [SolverBody::default(), ball(Vec2::new(0.0, -1.0)), ball(Vec2::new(0.0, -2.0))];
        let contacts = [floor_contact(1, 0, 0.0), floor_contact(2, 0, apart)];
        let mut history = ImpulseHistory::default();
        let builtin = [0.4, 0.5].map(|normal| Impulse { normal, tangent: 0.0 });
        history.push(contacts.iter().map(|c| c.key), &builtin, ImpulseHistory::no_trail());
        guess_on_rows(model, &contacts, &history, &[floor_row(1), floor_row(2)], &bodies, compliance)
    }

    #[test]
    fn each_cell_gets_the_uniform_stress_that_best_solves_the_step() {
        // Far apart (cells of 2 m): each ball's cell has its own vertical stress, exact for it.
        let g = guess(&mut Coarse::new("coarse:2".into(), 2.0), 5.0, 0.0);
        assert!((g[0].normal - 1.0).abs() < 1e-5 && (g[1].normal - 2.0).abs() < 1e-5, "{g:?}");
        assert!(g.iter().all(|i| i.tangent.abs() < 1e-6), "a vertical load needs no friction: {g:?}");
        // Both in one cell: one amplitude for both rows. The energy-optimal common increment of
        // 0.6 and 1.5 missing (equal effective masses) is their mean, 1.05.
        let g = guess(&mut Coarse::new("coarse:100".into(), 100.0), 5.0, 0.0);
        assert!((g[0].normal - 1.45).abs() < 1e-5 && (g[1].normal - 1.55).abs() < 1e-5, "{g:?}");
        // Compliant contacts (0.1) ask u + 0.1 l = 0: each ball's own cell gives it 1/1.1, 2/1.1.
        let g = guess(&mut Coarse::new("coarse:2".into(), 2.0), 5.0, 0.1);
        assert!((g[0].normal - 1.0 / 1.1).abs() < 1e-5 && (g[1].normal - 2.0 / 1.1).abs() < 1e-5, "{g:?}");
    }
}
