//! What the network sees of a step's contact problem: per contact, features in its own normal /
//! tangent frame (so the prediction does not depend on the scene's orientation), impulses in
//! velocity units (divided by the contact's effective mass, so light and heavy contacts look
//! alike); per body, its mass class and motion. Computed the same way for training (from
//! recorded `problem/*` frames) and inference (from the live world's problem).

use msgs::{ProblemBody, ProblemContact};

/// Features per contact.
pub const CONTACT_FEATURES: usize = 15;
/// Features per body.
pub const BODY_FEATURES: usize = 4;

#[inline]
fn cross(a: [f32; 2], b: [f32; 2]) -> f32 {
    a[0] * b[1] - a[1] * b[0]
}

#[inline]
fn tangent(n: [f32; 2]) -> [f32; 2] {
    [n[1], -n[0]]
}

/// Effective mass `1 / (J M^-1 J^T)` of a contact along `d` (0 when both bodies are fixed).
pub fn effective_mass(a: &ProblemBody, b: &ProblemBody, c: &ProblemContact, d: [f32; 2]) -> f32 {
    let (rda, rdb) = (cross(c.ra, d), cross(c.rb, d));
    let k = a.inv_mass + b.inv_mass + a.inv_inertia * rda * rda + b.inv_inertia * rdb * rdb;
    if k > 0.0 {
        1.0 / k
    } else {
        0.0
    }
}

/// A contact's effective masses along its normal and tangent.
pub fn contact_masses(bodies: &[ProblemBody], c: &ProblemContact) -> [f32; 2] {
    let (a, b) = (&bodies[c.body_a as usize], &bodies[c.body_b as usize]);
    [effective_mass(a, b, c, c.normal), effective_mass(a, b, c, tangent(c.normal))]
}

/// Body velocities after applying every contact's `previous` impulse (builtin's warm start), as
/// the solver does before its first sweep, into `v`.
fn velocities_after_builtin(bodies: &[ProblemBody], contacts: &[ProblemContact], v: &mut Vec<([f32; 2], f32)>) {
    v.clear();
    v.extend(bodies.iter().map(|b| (b.v, b.w)));
    for c in contacts {
        let t = tangent(c.normal);
        let p =
            [c.normal[0] * c.previous[0] + t[0] * c.previous[1], c.normal[1] * c.previous[0] + t[1] * c.previous[1]];
        let (ia, ib) = (c.body_a as usize, c.body_b as usize);
        let (ba, bb) = (bodies[ia], bodies[ib]);
        v[ia].0[0] -= p[0] * ba.inv_mass;
        v[ia].0[1] -= p[1] * ba.inv_mass;
        v[ia].1 -= ba.inv_inertia * cross(c.ra, p);
        v[ib].0[0] += p[0] * bb.inv_mass;
        v[ib].0[1] += p[1] * bb.inv_mass;
        v[ib].1 += bb.inv_inertia * cross(c.rb, p);
    }
}

/// `ln(1 + age)` for the ages most contacts have (a table: the same values, without a logarithm
/// per contact and step).
fn log_age(age: u32) -> f32 {
    const TABLE: usize = 256;
    static LOGS: std::sync::OnceLock<[f32; TABLE]> = std::sync::OnceLock::new();
    let logs = LOGS.get_or_init(|| std::array::from_fn(|a| (1.0 + a as f32).ln()));
    logs.get(age as usize).copied().unwrap_or_else(|| (1.0 + age as f32).ln())
}

/// The features of a problem: `contact_out` gets [`CONTACT_FEATURES`] per contact, `body_out`
/// [`BODY_FEATURES`] per body, `masses_out` each contact's effective masses (what the network's
/// velocity-unit output is multiplied by).
pub fn features(
    bodies: &[ProblemBody],
    contacts: &[ProblemContact],
    contact_out: &mut Vec<f32>,
    body_out: &mut Vec<f32>,
    masses_out: &mut Vec<[f32; 2]>,
) {
    features_with(&mut Vec::new(), bodies, contacts, contact_out, body_out, masses_out)
}

/// [`features`] with a reusable buffer for the bodies' velocities (what a predictor calls every
/// step).
pub fn features_with(
    v: &mut Vec<([f32; 2], f32)>,
    bodies: &[ProblemBody],
    contacts: &[ProblemContact],
    contact_out: &mut Vec<f32>,
    body_out: &mut Vec<f32>,
    masses_out: &mut Vec<[f32; 2]>,
) {
    velocities_after_builtin(bodies, contacts, v);
    // Written in place (not appended value by value): this runs on the simulator's critical path.
    contact_out.clear();
    contact_out.resize(contacts.len() * CONTACT_FEATURES, 0.0);
    masses_out.clear();
    for (c, x) in contacts.iter().zip(contact_out.chunks_exact_mut(CONTACT_FEATURES)) {
        let (a, b) = (&bodies[c.body_a as usize], &bodies[c.body_b as usize]);
        let t = tangent(c.normal);
        let [kn, kt] = contact_masses(bodies, c);
        let per = |k: f32| if k > 0.0 { 1.0 / k } else { 0.0 };
        let (va, vb) = (v[c.body_a as usize], v[c.body_b as usize]);
        // Relative velocity of b w.r.t. a at the contact after builtin's warm start.
        let dv =
            [vb.0[0] - vb.1 * c.rb[1] - va.0[0] + va.1 * c.ra[1], vb.0[1] + vb.1 * c.rb[0] - va.0[1] - va.1 * c.ra[0]];
        let vn = dv[0] * c.normal[0] + dv[1] * c.normal[1];
        let vt = dv[0] * t[0] + dv[1] * t[1];
        let cone = c.friction * c.previous[0];
        let (pn, pt) = (per(kn), per(kt));
        x.copy_from_slice(&[
            c.previous[0] * pn,
            c.previous[1] * pt,
            (c.previous[0] - c.before_previous[0]) * pn,
            (c.previous[1] - c.before_previous[1]) * pt,
            log_age(c.age),
            (c.age == 0) as u32 as f32,
            c.friction,
            if cone > 0.0 { (c.previous[1].abs() / cone).min(1.0) } else { 0.0 },
            c.penetration * 100.0,
            vn,
            vt,
            (1.0 + kn).ln(),
            (1.0 + kt).ln(),
            (a.inv_mass == 0.0) as u32 as f32,
            (b.inv_mass == 0.0) as u32 as f32,
        ]);
        masses_out.push([kn, kt]);
    }
    body_out.clear();
    body_out.resize(bodies.len() * BODY_FEATURES, 0.0);
    for ((b, (vb, wb)), x) in bodies.iter().zip(v.iter()).zip(body_out.chunks_exact_mut(BODY_FEATURES)) {
        let speed = (vb[0] * vb[0] + vb[1] * vb[1]).sqrt();
        x.copy_from_slice(&[(b.inv_mass == 0.0) as u32 as f32, (1.0 + b.inv_mass).ln(), speed, wb.abs()]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(inv_mass: f32) -> ProblemBody {
        ProblemBody { v: [0.0, -0.1], w: 0.0, inv_mass, inv_inertia: inv_mass * 2.0 }
    }

    #[test]
    fn features_are_invariant_to_rotating_the_scene() {
        let contact = |n: [f32; 2], ra: [f32; 2]| ProblemContact {
            body_a: 0,
            body_b: 1,
            normal: n,
            ra,
            rb: [-ra[0], -ra[1]],
            friction: 0.5,
            previous: [1.0, 0.2],
            before_previous: [0.8, 0.1],
            age: 3,
            ..Default::default()
        };
        let rot = |v: [f32; 2], a: f32| [v[0] * a.cos() - v[1] * a.sin(), v[0] * a.sin() + v[1] * a.cos()];
        let bodies =
            |a: f32| vec![ProblemBody { v: rot([0.3, -0.2], a), w: 0.1, inv_mass: 1.0, inv_inertia: 2.0 }, body(0.5)];
        let (mut f0, mut f1, mut b, mut m) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        features(&bodies(0.0), &[contact([0.0, 1.0], [0.1, 0.4])], &mut f0, &mut b, &mut m);
        let a = 0.7;
        let mut rotated = bodies(a);
        rotated[1].v = rot(rotated[1].v, a);
        features(&rotated, &[contact(rot([0.0, 1.0], a), rot([0.1, 0.4], a))], &mut f1, &mut b, &mut m);
        assert_eq!(f0.len(), CONTACT_FEATURES);
        for (x, y) in f0.iter().zip(&f1) {
            assert!((x - y).abs() < 1e-5, "{f0:?} vs {f1:?}");
        }
    }

    #[test]
    fn effective_mass_of_a_ball_on_the_floor_is_its_mass() {
        let bodies = [ProblemBody::default(), body(0.5)];
        let c = ProblemContact {
            body_a: 0,
            body_b: 1,
            normal: [0.0, 1.0],
            ra: [0.0, 0.0],
            rb: [0.0, -1.0],
            ..Default::default()
        };
        let [kn, _] = contact_masses(&bodies, &c);
        assert!((kn - 2.0).abs() < 1e-6, "{kn}");
    }

    #[test]
    fn the_age_table_is_the_logarithm() {
        for age in (0..300).chain([u32::MAX]) {
            assert_eq!(log_age(age).to_bits(), (1.0 + age as f32).ln().to_bits(), "age {age}");
        }
    }
}
