//! The coarse correction between sweeps (`/coarse:S:K`, issue #51): a two-level step aimed at the
//! pile-wide error the sweeps diffuse, restricted to the problem's active set.
//!
//! A sweep fixes each row against its neighbours; what it moves slowly is error that is smooth
//! over the pile: a column carrying a little too much or too little of the load above it. Such
//! errors are, locally, uniform stress fields: contact forces `f = sigma n` leave an interior
//! body in balance, so they barely change a velocity and a sweep barely sees them. So every `K`
//! sweeps the pile is cut into square cells of side `S` (from the bodies' positions, read off
//! the rows' lever arms), each cell given the three components of a uniform stress (`xx`, `yy`,
//! `xy`: a row's parts are `n^T sigma n` and `t^T sigma n`), and the impulses move by the
//! combination that minimises the step's energy within that space (a Galerkin system, as in
//! algebraic multigrid's coarse-grid correction).
//!
//! The space follows the active set: a row carrying no load and separating is left out, a
//! sliding row (its tangent on the friction bound) contributes its normal part only, a sticking
//! row both. The moved impulses are projected onto the friction cone, and the correction is kept
//! only if the energy fell (`1/2 v^T M v` plus the compliance's `gamma / 2m * lambda^2`, which
//! projected Gauss-Seidel descends): else the half step is tried, else nothing changes and the
//! drop is counted. Cells are ordered column by column, so the system is banded and factorised
//! in its envelope (a few hundred unknowns at 1,000 bodies; no dense solve, no library call).

use super::placement::Placement;
use super::rows::{Impulse, SolverBody};
use super::sweep::{apply, relative_of, Prepared};
use rapier2d::math::Vec2;

/// Unknowns per cell: the stress components `xx`, `yy`, `xy`.
const PER_CELL: usize = 3;

/// A tangent within this fraction of its bound counts as sliding (outside the coarse space).
const STICKING: f32 = 1.0 - 1e-4;

/// Relative shift of the coarse system's diagonal: the space may hold stress fields that move no
/// body (a jammed pile's self-stress), where the system is singular.
const SHIFT: f64 = 1e-9;

/// What a correction did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Outcome {
    /// The impulses moved and the energy fell.
    Kept,
    /// Neither the step nor its half lowered the energy: nothing changed.
    Dropped,
    /// No row was active (nothing to correct).
    Empty,
}

/// The coarse space of one solve and the buffers of its corrections, reused across solves.
#[derive(Debug, Default, Clone)]
pub(super) struct CoarseSpace {
    /// Per row (visiting order): its cell.
    cell_of: Vec<u32>,
    cells: usize,
    /// Per row: the slot of body a and body b (`u32::MAX`: a body no impulse moves).
    slot_a: Vec<u32>,
    slot_b: Vec<u32>,
    /// Per moving body: its slots (one per cell its rows lie in), `slot_start[b]..slot_start[b+1]`.
    slot_start: Vec<u32>,
    slot_cell: Vec<u32>,
    /// Per slot: the generalised force (x, y, torque) of each of the cell's stress components.
    forces: Vec<[[f64; 3]; PER_CELL]>,
    /// Per row: each component's `[normal, tangent]` part (zero outside the active set).
    basis: Vec<[[f64; 2]; PER_CELL]>,
    system: Envelope,
    rhs: Vec<f64>,
    /// The state before a correction, restored if it is dropped.
    saved_work: Vec<Impulse>,
    saved_bodies: Vec<SolverBody>,
    /// The bodies' centres, read off the rows.
    placement: Placement,
    keys: Vec<(i32, i32)>,
}

impl CoarseSpace {
    /// Sets up the space of a solve's rows (`prepared`, visiting order) on `bodies`: cells of side
    /// `cell` metres, the slots and the system's envelope. The rows' geometry is fixed within a
    /// solve; only the active set changes between corrections.
    pub(super) fn prepare(&mut self, prepared: &[Prepared], bodies: &[SolverBody], cell: f32) {
        let joints =
            prepared.iter().map(|c| (c.a as u32, c.b as u32, [(c.ra.x - c.rb.x) as f64, (c.ra.y - c.rb.y) as f64]));
        let position = self.placement.place(bodies.len(), joints);
        // Cells numbered column by column (x, then y): neighbours are near in the numbering, so
        // the system's envelope stays narrow.
        let side = cell as f64;
        self.keys.clear();
        self.keys.extend(prepared.iter().map(|c| {
            let p = position[c.a];
            let (x, y) = (p[0] + c.ra.x as f64, p[1] + c.ra.y as f64);
            ((x / side).floor() as i32, (y / side).floor() as i32)
        }));
        let mut sorted = self.keys.clone();
        sorted.sort_unstable();
        sorted.dedup();
        self.cells = sorted.len();
        self.cell_of.clear();
        self.cell_of.extend(self.keys.iter().map(|k| sorted.binary_search(k).expect("every key is sorted") as u32));

        // Slots: per moving body, the cells its rows lie in.
        let mut body_cells: Vec<(u32, u32)> = Vec::with_capacity(2 * prepared.len());
        for (c, &cell) in prepared.iter().zip(&self.cell_of) {
            for (body, moves) in [(c.a, c.moves[0]), (c.b, c.moves[1])] {
                if moves {
                    body_cells.push((body as u32, cell));
                }
            }
        }
        body_cells.sort_unstable();
        body_cells.dedup();
        self.slot_start.clear();
        self.slot_start.resize(bodies.len() + 1, 0);
        for &(body, _) in &body_cells {
            self.slot_start[body as usize + 1] += 1;
        }
        for b in 0..bodies.len() {
            self.slot_start[b + 1] += self.slot_start[b];
        }
        self.slot_cell.clear();
        self.slot_cell.extend(body_cells.iter().map(|&(_, cell)| cell));
        let slot = |body: usize, cell: u32, slot_start: &[u32], slot_cell: &[u32]| {
            let (from, to) = (slot_start[body] as usize, slot_start[body + 1] as usize);
            from as u32 + slot_cell[from..to].binary_search(&cell).expect("the body's cell has a slot") as u32
        };
        self.slot_a.clear();
        self.slot_b.clear();
        for (c, &cell) in prepared.iter().zip(&self.cell_of) {
            let of = |body: usize, moves: bool| {
                if moves {
                    slot(body, cell, &self.slot_start, &self.slot_cell)
                } else {
                    u32::MAX
                }
            };
            let (a, b) = (of(c.a, c.moves[0]), of(c.b, c.moves[1]));
            self.slot_a.push(a);
            self.slot_b.push(b);
        }

        // The envelope: a cell couples with every cell a body shares with it.
        let mut first = (0..self.cells as u32).collect::<Vec<u32>>();
        for b in 0..bodies.len() {
            let cells = &self.slot_cell[self.slot_start[b] as usize..self.slot_start[b + 1] as usize];
            if let Some(&lowest) = cells.first() {
                for &cell in cells {
                    first[cell as usize] = first[cell as usize].min(lowest);
                }
            }
        }
        self.system.shape(first.iter().flat_map(|&f| [PER_CELL * f as usize; PER_CELL]));
    }

    /// Cells of the prepared space.
    #[cfg(test)]
    pub(super) fn cells(&self) -> usize {
        self.cells
    }

    /// One correction of `work` (visiting order, the velocities `bodies` it led to) within the
    /// prepared space; `softness` is the sweeps' `1 / (1 + gamma)`.
    pub(super) fn correct(
        &mut self,
        prepared: &[Prepared],
        work: &mut [Impulse],
        bodies: &mut [SolverBody],
        softness: f32,
    ) -> Outcome {
        let gamma = (1.0 / softness as f64) - 1.0;
        self.forces.clear();
        self.forces.resize(self.slot_cell.len(), [[0.0; 3]; PER_CELL]);
        self.basis.clear();
        self.rhs.clear();
        self.rhs.resize(PER_CELL * self.cells, 0.0);
        self.system.clear();
        let mut active = false;
        for (i, (c, l)) in prepared.iter().zip(work.iter()).enumerate() {
            let dv = relative_of(&bodies[c.a], &bodies[c.b], c);
            let (vn, vt) = (dv.dot(c.n), dv.dot(c.t));
            let normal_active = l.normal > 0.0 || vn <= 0.0;
            let bound = c.bound(l.normal);
            let tangent_active = normal_active && l.tangent.abs() < STICKING * bound;
            if !normal_active {
                self.basis.push([[0.0; 2]; PER_CELL]);
                continue;
            }
            active = true;
            let values = stress_parts(c.n, c.t, [true, tangent_active]);
            self.basis.push(values);
            let cell = self.cell_of[i] as usize;
            // The energy's gradient along the row's parts: its velocity, plus the compliance's pull.
            let compliance = |l: f32, mass: f32| if mass > 0.0 { gamma * l as f64 / mass as f64 } else { 0.0 };
            let gradient =
                [vn as f64 + compliance(l.normal, c.normal_mass), vt as f64 + compliance(l.tangent, c.tangent_mass)];
            let stiffness = [compliance(1.0, c.normal_mass), compliance(1.0, c.tangent_mass)];
            for k in 0..PER_CELL {
                self.rhs[PER_CELL * cell + k] -= values[k][0] * gradient[0] + values[k][1] * gradient[1];
                for j in 0..=k {
                    let d = values[k][0] * values[j][0] * stiffness[0] + values[k][1] * values[j][1] * stiffness[1];
                    if d != 0.0 {
                        self.system.add(PER_CELL * cell + k, PER_CELL * cell + j, d);
                    }
                }
            }
            // Each component's generalised force on the row's moving bodies (J^T z).
            for (slot, r, sign) in [(self.slot_a[i], c.ra, -1.0), (self.slot_b[i], c.rb, 1.0)] {
                if slot == u32::MAX {
                    continue;
                }
                let force = &mut self.forces[slot as usize];
                let (rx, ry) = (r.x as f64, r.y as f64);
                for (k, [vn, vt]) in values.iter().enumerate() {
                    let p = [vn * c.n.x as f64 + vt * c.t.x as f64, vn * c.n.y as f64 + vt * c.t.y as f64];
                    let f = [p[0], p[1], rx * p[1] - ry * p[0]];
                    for d in 0..3 {
                        force[k][d] += sign * f[d];
                    }
                }
            }
        }
        if !active {
            return Outcome::Empty;
        }
        // The Galerkin system, body by body: Z^T J M^-1 J^T Z summed over each body's slots.
        for (b, body) in bodies.iter().enumerate() {
            let slots = self.slot_start[b] as usize..self.slot_start[b + 1] as usize;
            let inverse = [body.inv_mass as f64, body.inv_mass as f64, body.inv_inertia as f64];
            for s in slots.clone() {
                for t in slots.start..=s {
                    let (fs, ft) = (&self.forces[s], &self.forces[t]);
                    let (cs, ct) = (self.slot_cell[s] as usize, self.slot_cell[t] as usize);
                    for (k, force_k) in fs.iter().enumerate() {
                        for (j, force_j) in ft.iter().enumerate() {
                            let (row, col) = (PER_CELL * cs + k, PER_CELL * ct + j);
                            if col > row {
                                continue;
                            }
                            let v: f64 = (0..3).map(|d| force_k[d] * inverse[d] * force_j[d]).sum();
                            if v != 0.0 {
                                self.system.add(row, col, v);
                            }
                        }
                    }
                }
            }
        }
        self.system.factorise();
        self.system.solve(&mut self.rhs);

        let before = energy(prepared, work, bodies, gamma);
        self.saved_work.clear();
        self.saved_work.extend_from_slice(work);
        self.saved_bodies.clear();
        self.saved_bodies.extend_from_slice(bodies);
        for scale in [1.0, 0.5] {
            self.step(prepared, work, bodies, scale);
            if energy(prepared, work, bodies, gamma) < before {
                return Outcome::Kept;
            }
            work.copy_from_slice(&self.saved_work);
            bodies.copy_from_slice(&self.saved_bodies);
        }
        Outcome::Dropped
    }

    /// Moves the impulses by `scale` times the coarse solution, projected onto the friction cone,
    /// the velocities following.
    fn step(&self, prepared: &[Prepared], work: &mut [Impulse], bodies: &mut [SolverBody], scale: f64) {
        for ((c, l), (values, &cell)) in prepared.iter().zip(work.iter_mut()).zip(self.basis.iter().zip(&self.cell_of))
        {
            if *values == [[0.0; 2]; PER_CELL] {
                continue;
            }
            let y = &self.rhs[PER_CELL * cell as usize..PER_CELL * (cell as usize + 1)];
            let (mut dn, mut dt) = (0.0f64, 0.0f64);
            for k in 0..PER_CELL {
                dn += values[k][0] * y[k];
                dt += values[k][1] * y[k];
            }
            let normal = (l.normal + (scale * dn) as f32).max(0.0);
            let bound = c.bound(normal);
            let tangent = (l.tangent + (scale * dt) as f32).clamp(-bound, bound);
            let (dn, dt) = (normal - l.normal, tangent - l.tangent);
            if dn != 0.0 || dt != 0.0 {
                *l = Impulse { normal, tangent };
                apply(bodies, c, c.n * dn + c.t * dt);
            }
        }
    }
}

/// A row's `[normal, tangent]` parts of the three uniform stresses `xx`, `yy`, `xy`:
/// `[n^T S n, t^T S n]`, the normal part zero on an open row and the tangent part on a row that
/// is not sticking (shared with the `coarse:S` warm start, which applies them once).
pub(crate) fn stress_parts(n: Vec2, t: Vec2, [closed, sticking]: [bool; 2]) -> [[f64; 2]; PER_CELL] {
    let (nx, ny, tx, ty) = (n.x as f64, n.y as f64, t.x as f64, t.y as f64);
    let mask = |[vn, vt]: [f64; 2]| [if closed { vn } else { 0.0 }, if sticking { vt } else { 0.0 }];
    [mask([nx * nx, tx * nx]), mask([ny * ny, ty * ny]), mask([2.0 * nx * ny, tx * ny + ty * nx])]
}

/// The step's energy at `work`: the bodies' kinetic energy plus the compliance's
/// `gamma / 2m * lambda^2` per row part (what projected Gauss-Seidel descends; constant terms
/// of static bodies left out).
fn energy(prepared: &[Prepared], work: &[Impulse], bodies: &[SolverBody], gamma: f64) -> f64 {
    let kinetic: f64 = bodies
        .iter()
        .map(|b| {
            let linear = if b.inv_mass > 0.0 { b.v.length_squared() as f64 / b.inv_mass as f64 } else { 0.0 };
            let angular = if b.inv_inertia > 0.0 { (b.w as f64).powi(2) / b.inv_inertia as f64 } else { 0.0 };
            0.5 * (linear + angular)
        })
        .sum();
    if gamma == 0.0 {
        return kinetic;
    }
    let part = |l: f32, mass: f32| if mass > 0.0 { 0.5 * gamma * (l as f64).powi(2) / mass as f64 } else { 0.0 };
    kinetic
        + prepared
            .iter()
            .zip(work)
            .map(|(c, l)| part(l.normal, c.normal_mass) + part(l.tangent, c.tangent_mass))
            .sum::<f64>()
}

/// A symmetric matrix stored by its lower envelope (per row, from its first nonzero column to
/// the diagonal), factorised in place by Cholesky, which fills only inside the envelope.
#[derive(Debug, Default, Clone)]
struct Envelope {
    /// Per row: its first column, and where its entries start in `values`.
    first: Vec<usize>,
    start: Vec<usize>,
    values: Vec<f64>,
    /// Per row: pinned to zero by the last factorisation (nothing touches it).
    pinned: Vec<bool>,
}

impl Envelope {
    /// Rows with these first columns (each at most its row), all entries zero.
    fn shape(&mut self, first: impl IntoIterator<Item = usize>) {
        self.first.clear();
        self.first.extend(first);
        self.start.clear();
        let mut at = 0;
        for (i, &f) in self.first.iter().enumerate() {
            debug_assert!(f <= i);
            self.start.push(at);
            at += i + 1 - f;
        }
        self.start.push(at);
        self.values.clear();
        self.values.resize(at, 0.0);
    }

    fn clear(&mut self) {
        self.values.fill(0.0);
    }

    /// Adds `v` at `(row, col)`, `col <= row`, inside the envelope.
    #[inline]
    fn add(&mut self, row: usize, col: usize, v: f64) {
        debug_assert!(col <= row && col >= self.first[row]);
        self.values[self.start[row] + col - self.first[row]] += v;
    }

    /// `L L^T` in place. An unknown no row touches (zero diagonal) is pinned to zero; a pivot
    /// that cancels (a direction that moves no body) keeps its diagonal, which leaves that
    /// direction out of the correction rather than blowing it up.
    fn factorise(&mut self) {
        let n = self.first.len();
        self.pinned.clear();
        self.pinned.resize(n, false);
        for i in 0..n {
            let (fi, si) = (self.first[i], self.start[i]);
            let diagonal = self.values[si + i - fi];
            if diagonal <= 0.0 {
                self.values[si..si + i - fi].fill(0.0);
                self.values[si + i - fi] = 1.0;
                self.pinned[i] = true;
                continue;
            }
            for j in fi..i {
                let (fj, sj) = (self.first[j], self.start[j]);
                let from = fi.max(fj);
                let mut s = self.values[si + j - fi];
                for k in from..j {
                    s -= self.values[si + k - fi] * self.values[sj + k - fj];
                }
                self.values[si + j - fi] = s / self.values[sj + j - fj];
            }
            let mut s = diagonal * (1.0 + SHIFT);
            for k in fi..i {
                s -= self.values[si + k - fi].powi(2);
            }
            self.values[si + i - fi] = if s > 1e-10 * diagonal { s.sqrt() } else { diagonal.sqrt() };
        }
    }

    /// Solves `L L^T x = b` in place (after [`Self::factorise`]).
    fn solve(&self, b: &mut [f64]) {
        let n = self.first.len();
        for i in 0..n {
            if self.pinned[i] {
                b[i] = 0.0;
                continue;
            }
            let (fi, si) = (self.first[i], self.start[i]);
            let mut s = b[i];
            for (l, x) in self.values[si..si + i - fi].iter().zip(&b[fi..i]) {
                s -= l * x;
            }
            b[i] = s / self.values[si + i - fi];
        }
        for i in (0..n).rev() {
            let (fi, si) = (self.first[i], self.start[i]);
            b[i] /= self.values[si + i - fi];
            let x = b[i];
            for (bk, l) in b[fi..i].iter_mut().zip(&self.values[si..si + i - fi]) {
                *bk -= l * x;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::rows::fixtures::{lattice, stack};
    use super::super::rows::ContactRow;
    use super::super::sweep::natural_residual_rows;
    use super::*;

    /// The rows prepared in their order, and a space of cells of side `cell` on them.
    fn space(rows: &[ContactRow], bodies: &[SolverBody], cell: f32) -> (Vec<Prepared>, CoarseSpace) {
        let prepared: Vec<Prepared> = rows.iter().map(|r| Prepared::of(r, bodies)).collect();
        let mut space = CoarseSpace::default();
        space.prepare(&prepared, bodies, cell);
        (prepared, space)
    }

    #[test]
    fn one_correction_removes_a_uniform_load_error_down_a_stack() {
        // 30 balls falling at 0.1 onto the floor: the solution loads row i with 0.1 (30 - i).
        // Every row carrying 0.05 too much leaves each ball but the top one in balance: the
        // error sweeps remove one row a sweep. It is a uniform stress (yy) in every 2 m cell,
        // so one correction removes it.
        let (mut bodies, rows) = stack(30, -0.1);
        let (prepared, mut space) = space(&rows, &bodies, 2.0);
        assert_eq!(space.cells(), 15, "the column's 30 contact points in 2 m cells");
        let solution: Vec<Impulse> = (0..30).map(|i| Impulse { normal: 0.1 * (30 - i) as f32, tangent: 0.0 }).collect();
        let mut work: Vec<Impulse> = solution.iter().map(|l| Impulse { normal: l.normal + 0.05, ..*l }).collect();
        for (c, l) in prepared.iter().zip(&work) {
            apply(&mut bodies, c, c.n * l.normal + c.t * l.tangent);
        }
        let (start, _) = natural_residual_rows(&prepared, &work, &bodies[..], 1.0);
        let before = energy(&prepared, &work, &bodies, 0.0);
        assert_eq!(space.correct(&prepared, &mut work, &mut bodies, 1.0), Outcome::Kept);
        assert!(energy(&prepared, &work, &bodies, 0.0) < 1e-6 * before);
        let (after, _) = natural_residual_rows(&prepared, &work, &bodies[..], 1.0);
        assert!(start > 0.01 && after < 1e-4, "{start} -> {after}");
        for (i, (l, s)) in work.iter().zip(&solution).enumerate() {
            assert!((l.normal - s.normal).abs() < 1e-4 && l.tangent == 0.0, "row {i}: {l:?} against {s:?}");
        }
    }

    #[test]
    fn a_correction_keeps_the_impulses_feasible_and_lowers_the_energy_or_changes_nothing() {
        // A lattice under the per-step law with a start that has some rows loaded and some
        // sliding: whatever the correction does, the impulses stay in their bounds, and it is
        // kept only with a lower energy; at the solution it has nothing to gain.
        let (mut bodies, rows) = lattice(12, 8);
        let (prepared, mut space) = space(&rows, &bodies, 3.0);
        let mut work: Vec<Impulse> = prepared
            .iter()
            .enumerate()
            .map(|(i, c)| Impulse { normal: 0.02 * (i % 3) as f32, tangent: c.bound(0.0) * [0.0, 1.0, -1.0][i % 3] })
            .collect();
        for (c, l) in prepared.iter().zip(&work) {
            apply(&mut bodies, c, c.n * l.normal + c.t * l.tangent);
        }
        let before = energy(&prepared, &work, &bodies, 0.0);
        let (saved_work, saved_bodies) = (work.clone(), bodies.clone());
        match space.correct(&prepared, &mut work, &mut bodies, 1.0) {
            Outcome::Kept => assert!(energy(&prepared, &work, &bodies, 0.0) < before),
            outcome => {
                assert_eq!((outcome, &work, &bodies), (Outcome::Dropped, &saved_work, &saved_bodies));
            }
        }
        for (c, l) in prepared.iter().zip(&work) {
            assert!(l.normal >= 0.0 && l.tangent.abs() <= c.bound(l.normal), "{l:?}");
        }
    }

    #[test]
    fn a_problem_with_no_active_row_has_nothing_to_correct() {
        // A ball moving away from the floor, no impulse: its row is not in the space. (Balls of
        // a stack moving together would be: their rows close at zero speed.)
        let (mut bodies, rows) = stack(1, 1.0);
        let (prepared, mut space) = space(&rows, &bodies, 2.0);
        let mut work = vec![Impulse::default(); 1];
        assert_eq!(space.correct(&prepared, &mut work, &mut bodies, 1.0), Outcome::Empty);
    }

    #[test]
    fn the_envelope_cholesky_solves_a_banded_system() {
        // A tridiagonal SPD matrix (2 on the diagonal, -1 beside) and an arrow entry inside the
        // envelope of the last row: the solution checks against the matrix.
        let n = 7;
        let mut m = Envelope::default();
        m.shape((0..n).map(|i: usize| if i == n - 1 { 0 } else { i.saturating_sub(1) }));
        let mut dense = vec![vec![0.0f64; n]; n];
        let mut put = |m: &mut Envelope, i: usize, j: usize, v: f64| {
            m.add(i, j, v);
            dense[i][j] += v;
            if i != j {
                dense[j][i] += v;
            }
        };
        for i in 0..n {
            put(&mut m, i, i, 2.0);
            if i > 0 {
                put(&mut m, i, i - 1, -1.0);
            }
        }
        put(&mut m, n - 1, 0, 0.3);
        let b: Vec<f64> = (0..n).map(|i| 1.0 + i as f64).collect();
        let mut x = b.clone();
        m.factorise();
        m.solve(&mut x);
        for i in 0..n {
            let ax: f64 = (0..n).map(|j| dense[i][j] * x[j]).sum();
            assert!((ax - b[i]).abs() < 1e-7 * b[i], "row {i}: {ax} vs {}", b[i]);
        }
    }

    #[test]
    fn an_unknown_no_row_touches_is_pinned_to_zero() {
        let mut m = Envelope::default();
        m.shape([0, 0, 1]);
        m.add(0, 0, 4.0);
        m.add(2, 2, 1.0);
        m.factorise();
        let mut x = vec![8.0, 5.0, 3.0];
        m.solve(&mut x);
        assert!((x[0] - 2.0).abs() < 1e-6 && x[1] == 0.0 && (x[2] - 3.0).abs() < 1e-6, "{x:?}");
    }

    #[test]
    fn a_uniform_stress_has_a_rows_normal_and_tangent_parts() {
        // A floor contact (normal +y, tangent +x... Box2D's tangent is (n.y, -n.x) = (1, 0)).
        let [xx, yy, xy] = stress_parts(Vec2::Y, Vec2::X, [true, true]);
        assert_eq!((xx, yy, xy), ([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]));
        // Sliding: the tangent part is not in the space.
        assert_eq!(stress_parts(Vec2::Y, Vec2::X, [true, false])[2], [0.0, 0.0]);
    }
}
