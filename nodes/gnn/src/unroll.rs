//! The solver in the loop: `k` projected Gauss-Seidel sweeps from a warm start, exactly in the
//! order and form of `sim::ContactSolver` (tangent row bounded by `mu lambda_n`, then normal row),
//! in f64, and a hand-written reverse pass. The loss is what one more sweep would still change,
//! `sum (d lambda)^2 / m` (the residual left after `k` sweeps, in velocity-energy units): the
//! quantity the solver's stopping rule reads, and invariant to where in the problem's null space
//! the warm start lies. Its gradient with respect to the warm start drives the network.
//!
//! The loss of a warm start for a sweep budget (`dc-gnn-train --loss unrolled --sweeps K`, the
//! `gnn-budget*` models; `dc-unet train --loss unrolled`); to a tolerance it lowers its own loss
//! but not the sweeps. [`Unrolled::delassus`] also serves the gnn's readout fit. Here (not in a
//! trainer) so that every trainer judges a warm start by the same sweeps.

use msgs::{ProblemBody, ProblemContact};

#[derive(Debug, Clone, Copy)]
struct Row {
    a: usize,
    b: usize,
    /// Jacobian rows (tangent, normal) on (v_a, w_a, v_b, w_b): `[-d, -ra x d, d, rb x d]`.
    jt: [f64; 6],
    jn: [f64; 6],
    mt: f64,
    mn: f64,
    mu: f64,
}

/// One update of the tape: which row, its input impulse, `x` before projection, the bounds.
#[derive(Debug, Clone, Copy)]
struct Update {
    c: usize,
    normal: bool,
    lambda_in: f64,
    x: f64,
    lo: f64,
    hi: f64,
}

/// A problem prepared for unrolled sweeps.
pub struct Unrolled {
    /// The loss sums `(d lambda^2 / m)^(power / 2)`: 2 is the energy of the last sweep's
    /// changes; larger powers weigh the largest changes (what the stopping rule reads) more.
    pub power: f64,
    /// Weight of a normal row's last-sweep change that *adds* impulse (the contact still
    /// approaching: too little push, which accumulates as penetration) against 1 for the rest.
    pub approach_weight: f64,
    rows: Vec<Row>,
    v0: Vec<[f64; 3]>,
    inv: Vec<[f64; 3]>,
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

impl Unrolled {
    pub fn new(bodies: &[ProblemBody], contacts: &[ProblemContact]) -> Unrolled {
        let inv: Vec<[f64; 3]> =
            bodies.iter().map(|b| [b.inv_mass as f64, b.inv_mass as f64, b.inv_inertia as f64]).collect();
        let rows = contacts
            .iter()
            .map(|c| {
                let n = [c.normal[0] as f64, c.normal[1] as f64];
                let t = [n[1], -n[0]];
                let (ra, rb) = ([c.ra[0] as f64, c.ra[1] as f64], [c.rb[0] as f64, c.rb[1] as f64]);
                let j = |d: [f64; 2]| [-d[0], -d[1], -cross(ra, d), d[0], d[1], cross(rb, d)];
                let (a, b) = (c.body_a as usize, c.body_b as usize);
                let mass = |jr: [f64; 6]| {
                    let k = jr[0] * jr[0] * inv[a][0]
                        + jr[1] * jr[1] * inv[a][1]
                        + jr[2] * jr[2] * inv[a][2]
                        + jr[3] * jr[3] * inv[b][0]
                        + jr[4] * jr[4] * inv[b][1]
                        + jr[5] * jr[5] * inv[b][2];
                    if k > 0.0 {
                        1.0 / k
                    } else {
                        0.0
                    }
                };
                let (jt, jn) = (j(t), j(n));
                Row { a, b, jt, jn, mt: mass(jt), mn: mass(jn), mu: c.friction as f64 }
            })
            .collect();
        let v0 = bodies.iter().map(|b| [b.v[0] as f64, b.v[1] as f64, b.w as f64]).collect();
        Unrolled { power: 2.0, approach_weight: 1.0, rows, v0, inv }
    }

    fn dot(&self, r: &Row, j: &[f64; 6], v: &[[f64; 3]]) -> f64 {
        let (va, vb) = (v[r.a], v[r.b]);
        j[0] * va[0] + j[1] * va[1] + j[2] * va[2] + j[3] * vb[0] + j[4] * vb[1] + j[5] * vb[2]
    }

    /// The loss weight of a last-sweep change `delta` of a normal (or tangent) row.
    fn weight(&self, normal: bool, delta: f64) -> f64 {
        if normal && delta > 0.0 {
            self.approach_weight
        } else {
            1.0
        }
    }

    /// `v += M^-1 J^T delta` for one row.
    fn apply(&self, r: &Row, j: &[f64; 6], delta: f64, v: &mut [[f64; 3]]) {
        for k in 0..3 {
            v[r.a][k] += self.inv[r.a][k] * j[k] * delta;
            v[r.b][k] += self.inv[r.b][k] * j[3 + k] * delta;
        }
    }

    /// `J M^-1 v-bar` for one row: how an impulse change on it moves the adjoint of `v`.
    fn pull(&self, r: &Row, j: &[f64; 6], vbar: &[[f64; 3]]) -> f64 {
        (0..3).map(|k| self.inv[r.a][k] * j[k] * vbar[r.a][k] + self.inv[r.b][k] * j[3 + k] * vbar[r.b][k]).sum()
    }

    /// The problem's Delassus operator `J M^-1 J^T` applied to impulses `p` (normal, tangent per
    /// contact): the relative velocity (normal, tangent) each contact gets from them, bodies at rest.
    pub fn delassus(&self, p: &[[f64; 2]]) -> Vec<[f64; 2]> {
        let mut v = vec![[0.0f64; 3]; self.v0.len()];
        for (r, l) in self.rows.iter().zip(p) {
            self.apply(r, &r.jn, l[0], &mut v);
            self.apply(r, &r.jt, l[1], &mut v);
        }
        self.rows.iter().map(|r| [self.dot(r, &r.jn, &v), self.dot(r, &r.jt, &v)]).collect()
    }

    /// The loss after `sweeps` sweeps from `warm` (normal, tangent per contact) and its gradient
    /// with respect to `warm`.
    pub fn loss_and_gradient(&self, warm: &[[f64; 2]], sweeps: usize) -> (f64, Vec<[f64; 2]>) {
        let n = self.rows.len();
        // The solver's projection of the guess onto the friction cone, then applied as it is.
        let mut lambda: Vec<[f64; 2]> = Vec::with_capacity(n);
        let mut proj = Vec::with_capacity(n); // (normal kept, tangent: -1 low, 0 free, 1 high)
        for (r, w) in self.rows.iter().zip(warm) {
            let ln = w[0].max(0.0);
            let hi = r.mu * ln;
            let lt = w[1].clamp(-hi, hi);
            proj.push((
                w[0] > 0.0,
                if w[1] >= hi {
                    1
                } else if w[1] <= -hi {
                    -1
                } else {
                    0
                },
            ));
            lambda.push([ln, lt]);
        }
        let mut v = self.v0.clone();
        for (r, l) in self.rows.iter().zip(&lambda) {
            self.apply(r, &r.jn, l[0], &mut v);
            self.apply(r, &r.jt, l[1], &mut v);
        }
        // Forward sweeps, recording each update; the last sweep's changes are the loss.
        let mut tape: Vec<Update> = Vec::with_capacity(2 * n * (sweeps + 1));
        let mut loss = 0.0;
        for sweep in 0..=sweeps {
            for (c, r) in self.rows.iter().enumerate() {
                for normal in [false, true] {
                    let (j, m) = if normal { (&r.jn, r.mn) } else { (&r.jt, r.mt) };
                    // lambda[c][0] is the normal impulse, [1] the tangent one.
                    let l_in = lambda[c][if normal { 0 } else { 1 }];
                    let x = l_in - m * self.dot(r, j, &v);
                    let (lo, hi) =
                        if normal { (0.0, f64::INFINITY) } else { (-r.mu * lambda[c][0], r.mu * lambda[c][0]) };
                    let new = x.clamp(lo, hi);
                    let delta = new - l_in;
                    self.apply(r, j, delta, &mut v);
                    lambda[c][if normal { 0 } else { 1 }] = new;
                    if sweep == sweeps && m > 0.0 {
                        loss += self.weight(normal, delta) * (delta * delta / m).powf(self.power / 2.0);
                    }
                    tape.push(Update { c, normal, lambda_in: l_in, x, lo, hi });
                }
            }
        }
        // Reverse.
        let mut lbar = vec![[0.0f64; 2]; n];
        let mut vbar = vec![[0.0f64; 3]; self.v0.len()];
        let last_sweep_start = tape.len() - 2 * n;
        for (i, u) in tape.iter().enumerate().rev() {
            let r = &self.rows[u.c];
            let (j, m) = if u.normal { (&r.jn, r.mn) } else { (&r.jt, r.mt) };
            let comp = if u.normal { 0 } else { 1 };
            let new = u.x.clamp(u.lo, u.hi);
            let delta = new - u.lambda_in;
            // v_out = v_in + M^-1 J^T delta; loss += delta^2 / m in the last sweep.
            let mut delta_bar = self.pull(r, j, &vbar);
            if i >= last_sweep_start && m > 0.0 {
                // d/d delta of (delta^2 / m)^(p/2) = p (delta^2 / m)^(p/2 - 1) delta / m.
                let e = delta * delta / m;
                if e > 0.0 {
                    delta_bar += self.weight(u.normal, delta) * self.power * e.powf(self.power / 2.0 - 1.0) * delta / m;
                }
            }
            // lambda_out = new; delta = new - lambda_in.
            let new_bar = lbar[u.c][comp] + delta_bar;
            let mut lambda_in_bar = -delta_bar;
            // new = clamp(x, lo, hi); the tangent's bounds are +-mu lambda_n.
            let x_bar = if u.x > u.lo && u.x < u.hi {
                new_bar
            } else {
                if !u.normal {
                    let sign = if u.x >= u.hi { 1.0 } else { -1.0 };
                    lbar[u.c][0] += sign * r.mu * new_bar;
                }
                0.0
            };
            // x = lambda_in - m J v_in.
            lambda_in_bar += x_bar;
            for k in 0..3 {
                vbar[r.a][k] -= m * x_bar * j[k];
                vbar[r.b][k] -= m * x_bar * j[3 + k];
            }
            lbar[u.c][comp] = lambda_in_bar;
        }
        // Through the initial application and the projection.
        let mut grad = vec![[0.0f64; 2]; n];
        for (c, r) in self.rows.iter().enumerate() {
            let gn = lbar[c][0] + self.pull(r, &r.jn, &vbar);
            let gt = lbar[c][1] + self.pull(r, &r.jt, &vbar);
            let (n_kept, t_side) = proj[c];
            grad[c][1] = if t_side == 0 { gt } else { 0.0 };
            let through_bound = if t_side != 0 { t_side as f64 * r.mu * gt } else { 0.0 };
            grad[c][0] = if n_kept { gn + through_bound } else { 0.0 };
        }
        (loss, grad)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pile() -> (Vec<ProblemBody>, Vec<ProblemContact>) {
        let body = |v: [f32; 2], m: f32| ProblemBody { v, w: 0.1, inv_mass: m, inv_inertia: 4.0 * m };
        let bodies =
            vec![ProblemBody::default(), body([0.0, -0.1], 1.0), body([0.05, -0.1], 0.7), body([-0.02, -0.12], 1.3)];
        let contact = |a: u32, b: u32, angle: f32| ProblemContact {
            body_a: a,
            body_b: b,
            normal: [angle.cos(), angle.sin()],
            ra: [0.1, 0.2],
            rb: [-0.2 * angle.cos(), -0.2 * angle.sin()],
            friction: 0.4,
            ..Default::default()
        };
        (
            bodies,
            vec![contact(0, 1, 1.5), contact(0, 2, 1.6), contact(1, 3, 1.2), contact(2, 3, 2.0), contact(1, 2, 0.1)],
        )
    }

    #[test]
    fn the_gradient_matches_finite_differences() {
        let (bodies, contacts) = pile();
        let mut u = Unrolled::new(&bodies, &contacts);
        let warm: Vec<[f64; 2]> = vec![[0.05, 0.001], [0.03, -0.004], [0.02, 0.002], [0.04, 0.0], [0.01, 0.001]];
        for (power, approach_weight) in [(2.0, 1.0), (4.0, 1.0), (2.0, 4.0)] {
            u.power = power;
            u.approach_weight = approach_weight;
            let (loss, grad) = u.loss_and_gradient(&warm, 3);
            assert!(loss > 0.0);
            let h = 1e-7;
            for c in 0..warm.len() {
                for k in 0..2 {
                    let mut plus = warm.clone();
                    plus[c][k] += h;
                    let mut minus = warm.clone();
                    minus[c][k] -= h;
                    let fd = (u.loss_and_gradient(&plus, 3).0 - u.loss_and_gradient(&minus, 3).0) / (2.0 * h);
                    let tolerance = 1e-5 * (1.0 + fd.abs().max(grad[c][k].abs()));
                    assert!(
                        (fd - grad[c][k]).abs() < tolerance,
                        "power {power}, approach weight {approach_weight}, contact {c}, component {k}: analytic {} vs {fd}",
                        grad[c][k]
                    );
                }
            }
        }
    }
}
