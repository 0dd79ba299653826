//! `subspace:K` — builtin's warm start corrected in the few directions where the previous solve
//! was still moving.
//!
//! PGS removes rough error in a few sweeps and stalls on its slowest modes: impulse patterns that
//! barely change any velocity (near self-stress in a jammed pile). That is where builtin's error
//! costs sweeps (README "Headroom": the error that survives no smoothing is the expensive part).
//! The last sweeps of the previous solve point along exactly those modes, and a pile's slow modes
//! change little from one step to the next. So the model takes builtin's warm start and, within
//! the span of the previous solve's last K sweep changes (matched by contact key), adds the
//! correction that best solves the step's own linearised problem — closed contacts' normal
//! velocity and sticking contacts' tangent velocity to zero — in the energy norm of the step's
//! `J M^-1 J^T`: a K x K Galerkin system. It costs K + 1 passes over the rows, about as much
//! work as K + 1 sweeps. Not learned: the solver's own history is the basis.

use super::galerkin::{builtin_step, BuiltinStep};
use crate::contact::ContactPoint;
use crate::solver::rows::{apply, axpy, dot, relative, Impulse};
use crate::solver::TRAIL_SWEEPS;
use crate::warm::model::{Needs, Unavailable, WarmStartInput, WarmStartModel};

/// The most basis vectors: the solver's kept sweeps and one model's direction.
pub const MAX_DIMENSIONS: usize = TRAIL_SWEEPS + 1;

/// See the module documentation.
pub struct Subspace {
    name: String,
    /// Sweeps of the previous solve's trail in the basis.
    dimensions: usize,
    /// A model whose guess minus builtin's is one more direction (`gnn-subspace`: the network's
    /// correction, its amplitude left to the step's own problem).
    direction: Option<Box<dyn WarmStartModel>>,
    guess: Vec<Impulse>,
    /// Scratch: per row `[normal, tangent]` values of each basis vector, the residual, W z.
    basis: Vec<Vec<[f64; 2]>>,
    residual: Vec<[f64; 2]>,
    product: Vec<[f64; 2]>,
    velocities: Vec<[f64; 3]>,
}

impl Subspace {
    /// `dimensions` of the previous solve's last sweeps (1..=[`TRAIL_SWEEPS`]).
    pub fn new(name: String, dimensions: usize) -> Subspace {
        Subspace {
            name,
            dimensions: dimensions.clamp(1, TRAIL_SWEEPS),
            direction: None,
            guess: Vec::new(),
            basis: Vec::new(),
            residual: Vec::new(),
            product: Vec::new(),
            velocities: Vec::new(),
        }
    }
}

impl Subspace {
    /// `model`'s correction to builtin as one direction, with `dimensions` (0..=[`TRAIL_SWEEPS`])
    /// sweeps of the previous solve's trail.
    pub fn with_direction(name: String, dimensions: usize, model: Box<dyn WarmStartModel>) -> Subspace {
        Subspace { dimensions: dimensions.min(TRAIL_SWEEPS), direction: Some(model), ..Subspace::new(name, 1) }
    }
}

impl std::fmt::Debug for Subspace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subspace")
            .field("name", &self.name)
            .field("dimensions", &self.dimensions)
            .field("direction", &self.direction.as_ref().map(|m| m.name().to_string()))
            .finish()
    }
}

impl WarmStartModel for Subspace {
    fn name(&self) -> &str {
        &self.name
    }

    fn needs(&self) -> Needs {
        let own = Needs::ROWS;
        self.direction.as_ref().map_or(own, |m| own.union(m.needs()))
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        if let Some(model) = &mut self.direction {
            self.guess.clear();
            self.guess.resize(out.len(), Impulse::default());
            model.warm_start(input, &mut self.guess)?;
        }
        // Nothing to correct against (no rows given): builtin as it is.
        let Some(BuiltinStep { rows, bodies, active, compliance }) =
            builtin_step(input, out, &mut self.velocities, &mut self.residual)
        else {
            return Ok(());
        };

        // The basis: the model's direction, then the previous solve's last sweeps, on the active
        // rows, orthonormalised.
        let from_model = usize::from(self.direction.is_some());
        self.basis.resize_with(from_model + self.dimensions, Vec::new);
        let mut kept = 0;
        for j in 0..from_model + self.dimensions {
            let mut z = std::mem::take(&mut self.basis[kept]);
            if j < from_model {
                z.clear();
                z.extend(self.guess.iter().zip(out.iter()).zip(&active).map(|((g, b), act)| {
                    [
                        if act[0] { (g.normal - b.normal) as f64 } else { 0.0 },
                        if act[1] { (g.tangent - b.tangent) as f64 } else { 0.0 },
                    ]
                }));
            } else {
                fill_trail(&mut z, input.contacts, input.history, j - from_model, &active);
            }
            for q in &self.basis[..kept] {
                let d = dot(&z, q);
                axpy(&mut z, -d, q);
            }
            let norm = dot(&z, &z).sqrt();
            if norm > 1e-12 {
                z.iter_mut().for_each(|v| v.iter_mut().for_each(|x| *x /= norm));
                self.basis[kept] = z;
                kept += 1;
            } else {
                self.basis[kept] = z;
            }
        }
        if kept == 0 {
            return Ok(());
        }

        // Galerkin: (Z^T W Z) y = Z^T r, W = J M^-1 J^T on the active rows.
        let mut system = [[0.0f64; MAX_DIMENSIONS]; MAX_DIMENSIONS];
        let mut rhs = [0.0f64; MAX_DIMENSIONS];
        for j in 0..kept {
            self.velocities.clear();
            self.velocities.resize(bodies.len(), [0.0; 3]);
            for (row, z) in rows.iter().zip(&self.basis[j]) {
                apply(&mut self.velocities, bodies, row, *z);
            }
            self.product.clear();
            self.product.extend(rows.iter().zip(&active).map(|(row, act)| {
                let [vn, vt] = relative(&self.velocities, row);
                [if act[0] { vn } else { 0.0 }, if act[1] { vt } else { 0.0 }]
            }));
            if let Some(c) = &compliance {
                for ((p, c), z) in self.product.iter_mut().zip(c).zip(&self.basis[j]) {
                    p[0] += c[0] * z[0];
                    p[1] += c[1] * z[1];
                }
            }
            for (row, z) in system.iter_mut().zip(&self.basis[..kept]) {
                row[j] = dot(z, &self.product);
            }
            rhs[j] = dot(&self.basis[j], &self.residual);
        }
        let Some(y) = solve_spd(&system, &rhs, kept) else { return Ok(()) };
        for (i, o) in out.iter_mut().enumerate() {
            let (mut dn, mut dt) = (0.0, 0.0);
            for (j, yj) in y.iter().enumerate().take(kept) {
                dn += yj * self.basis[j][i][0];
                dt += yj * self.basis[j][i][1];
            }
            o.normal += dn as f32;
            o.tangent += dt as f32;
        }
        Ok(())
    }
}

/// Sweep `-j` of the previous solve's trail per contact, `[normal, tangent]`, zero on inactive
/// rows and new contacts.
fn fill_trail(
    z: &mut Vec<[f64; 2]>,
    contacts: &[ContactPoint],
    history: &crate::contact::ImpulseHistory,
    j: usize,
    active: &[[bool; 2]],
) {
    z.clear();
    z.extend(contacts.iter().zip(active).map(|(c, act)| match history.previous_trail(&c.key) {
        Some(trail) => {
            [if act[0] { trail[j].normal as f64 } else { 0.0 }, if act[1] { trail[j].tangent as f64 } else { 0.0 }]
        }
        None => [0.0, 0.0],
    }));
}

/// Solves the symmetric positive semi-definite `n x n` system by Cholesky, with a ridge of 1e-10
/// of its trace (a direction the step's problem cannot see gets no correction). `None` when the
/// system is empty or not finite.
fn solve_spd(
    a: &[[f64; MAX_DIMENSIONS]; MAX_DIMENSIONS],
    b: &[f64; MAX_DIMENSIONS],
    n: usize,
) -> Option<[f64; MAX_DIMENSIONS]> {
    let trace: f64 = (0..n).map(|i| a[i][i]).sum();
    if !(trace.is_finite() && trace > 0.0) {
        return None;
    }
    let ridge = 1e-10 * trace;
    let mut l = [[0.0f64; MAX_DIMENSIONS]; MAX_DIMENSIONS];
    for i in 0..n {
        for j in 0..=i {
            let s = a[i][j] + if i == j { ridge } else { 0.0 };
            let s = s - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0f64; MAX_DIMENSIONS];
    for i in 0..n {
        let s: f64 = b[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>();
        y[i] = s / l[i][i];
    }
    let mut x = [0.0f64; MAX_DIMENSIONS];
    for i in (0..n).rev() {
        let s: f64 = y[i] - (i + 1..n).map(|k| l[k][i] * x[k]).sum::<f64>();
        x[i] = s / l[i][i];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_solves_a_small_system() {
        let mut a = [[0.0; MAX_DIMENSIONS]; MAX_DIMENSIONS];
        a[0][0] = 4.0;
        a[0][1] = 2.0;
        a[1][0] = 2.0;
        a[1][1] = 3.0;
        let mut b = [0.0; MAX_DIMENSIONS];
        b[0] = 2.0;
        b[1] = 1.0;
        let x = solve_spd(&a, &b, 2).unwrap();
        // 4x + 2y = 2, 2x + 3y = 1 -> x = 0.5, y = 0.
        assert!((x[0] - 0.5).abs() < 1e-8 && x[1].abs() < 1e-8, "{x:?}");
        let zero = [[0.0; MAX_DIMENSIONS]; MAX_DIMENSIONS];
        assert!(solve_spd(&zero, &b, 2).is_none());
    }

    use crate::contact::{ImpulseHistory, SolveTrail};
    use crate::solver::rows::fixtures::{ball, floor_row};
    use crate::solver::rows::SolverBody;
    use crate::warm::model::harness::{floor_contact, guess_on_rows};
    use rapier2d::math::Vec2;

    /// Ground (fixed) and two balls falling at 1 and 2 (velocity after gravity), each on one
    /// contact: the impulse that stops a ball is its speed times its mass (1).
    fn guess(model: &mut Subspace, trail: [Impulse; TRAIL_SWEEPS]) -> Vec<Impulse> {
        guess_with(model, trail, 0.0)
    }

    fn guess_with(model: &mut Subspace, trail: [Impulse; TRAIL_SWEEPS], compliance: f32) -> Vec<Impulse> {
        let bodies = [SolverBody::default(), ball(Vec2::new(0.0, -1.0)), ball(Vec2::new(0.0, -2.0))];
        let contacts = [floor_contact(1, 0, 0.0), floor_contact(2, 0, 0.0)];
        let mut history = ImpulseHistory::default();
        // Ball 1's contact persists with builtin's 0.4 (the ball still falls); ball 2's is new.
        let builtin = [Impulse { normal: 0.4, tangent: 0.0 }];
        history.push([contacts[0].key].into_iter(), &builtin, SolveTrail { changes: &[trail], rate: 0.9 });
        guess_on_rows(model, &contacts, &history, &[floor_row(1), floor_row(2)], &bodies, compliance)
    }

    #[test]
    fn the_correction_solves_the_step_along_the_trail() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let zero = imp(0.0, 0.0);
        // The last sweep moved the normal: along that direction the step's own problem says 1.
        let g = guess(&mut Subspace::new("subspace:2".into(), 2), [imp(0.01, 0.0), imp(0.02, 0.0), zero, zero]);
        assert!((g[0].normal - 1.0).abs() < 1e-6 && g[0].tangent == 0.0, "{g:?}");
        assert_eq!(g[1], zero, "a new contact keeps builtin's 0: no trail there");
        // Compliant contacts (0.1) ask u + 0.1 l = 0: the same direction is scaled to 1 / 1.1.
        let g =
            guess_with(&mut Subspace::new("subspace:2".into(), 2), [imp(0.01, 0.0), imp(0.02, 0.0), zero, zero], 0.1);
        assert!((g[0].normal - 1.0 / 1.1).abs() < 1e-6, "{g:?}");
        // A trail only along the tangent (which the ball does not need) changes nothing.
        let g = guess(&mut Subspace::new("subspace:1".into(), 1), [imp(0.0, 0.3), zero, zero, zero]);
        assert!((g[0].normal - 0.4).abs() < 1e-7 && g[0].tangent.abs() < 1e-7, "{g:?}");
        // No trail (a solve that made no sweeps): builtin as it is.
        let g = guess(&mut Subspace::new("subspace:4".into(), 4), [zero; TRAIL_SWEEPS]);
        assert_eq!(g, vec![imp(0.4, 0.0), zero]);
    }

    /// A model that answers builtin plus a fixed change on every contact.
    struct Nudge(Impulse);

    impl WarmStartModel for Nudge {
        fn name(&self) -> &str {
            "nudge"
        }
        fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
            input.history.fill_previous(input.contacts, out);
            for o in out.iter_mut() {
                (o.normal, o.tangent) = (o.normal + self.0.normal, o.tangent + self.0.tangent);
            }
            Ok(())
        }
    }

    #[test]
    fn a_models_direction_gets_its_amplitude_from_the_step() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let zero = imp(0.0, 0.0);
        // The model says "a little more normal impulse" (0.05 where 0.6 is missing): the step's
        // own problem scales that direction to the full 0.6.
        let nudge = Box::new(Nudge(imp(0.05, 0.0)));
        let g = guess(&mut Subspace::with_direction("gnn-subspace:0".into(), 0, nudge), [zero; TRAIL_SWEEPS]);
        assert!((g[0].normal - 1.0).abs() < 1e-5 && g[0].tangent == 0.0, "{g:?}");
        // A direction pointing the wrong way (less impulse) is followed backwards: the step picks the sign.
        let away = Box::new(Nudge(imp(-0.3, 0.0)));
        let g = guess(&mut Subspace::with_direction("gnn-subspace:0".into(), 0, away), [zero; TRAIL_SWEEPS]);
        assert!((g[0].normal - 1.0).abs() < 1e-5, "{g:?}");
        // Only the active rows of the new contact (none: builtin gives it 0, so it is open) move.
        assert_eq!(g[1], zero);
    }
}
