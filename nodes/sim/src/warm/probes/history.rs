//! Probes built from the contacts' history alone: extrapolating the last two steps
//! (`extrapolate:beta`), continuing where the previous solve was still going (`continue:G`),
//! and builtin with contacts that flickered off for one step (`builtin-reappear`).

use crate::solver::rows::Impulse;
use crate::warm::model::{Unavailable, WarmStartInput, WarmStartModel};

/// `extrapolate[:beta]`: `l(k-1) + beta (l(k-1) - l(k-2))` on contacts that persisted two steps
/// (beta 1: linear extrapolation), `l(k-1)` on those that persisted one, clamped to the friction
/// cone.
#[derive(Debug)]
pub struct Extrapolate {
    name: String,
    beta: f32,
}

impl Extrapolate {
    /// `l1 + beta (l1 - l2)`, named `name` in the statistics.
    pub fn new(name: String, beta: f32) -> Extrapolate {
        Extrapolate { name, beta }
    }
}

impl WarmStartModel for Extrapolate {
    fn name(&self) -> &str {
        &self.name
    }
    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let beta = self.beta;
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            *o = match (input.history.previous(&c.key), input.history.before_previous(&c.key)) {
                (Some(l1), Some(l2)) => {
                    let n = (l1.normal + beta * (l1.normal - l2.normal)).max(0.0);
                    let t_max = c.friction * n;
                    Impulse { normal: n, tangent: (l1.tangent + beta * (l1.tangent - l2.tangent)).clamp(-t_max, t_max) }
                }
                (Some(l1), None) => l1,
                _ => Impulse::default(),
            };
        }
        Ok(())
    }
}

/// `continue[:G]`: builtin plus `G` times the distance the previous solve still had to go along
/// its last sweep's direction. A PGS solve stopped at its tolerance has long been converging like
/// its slowest (smooth, pile-wide) mode, `change(k+1) ~ rate * change(k)`, so the rest of the way
/// is the geometric series `last_change * rate / (1 - rate)` (Aitken's extrapolation): exactly the
/// smooth error that the next solve would otherwise spend its sweeps removing.
#[derive(Debug)]
pub struct Continue {
    name: String,
    gain: f32,
}

/// The largest rate [`Continue`] believes (a solve at its cap converges at a rate near 1, and the
/// series' factor `rate / (1 - rate)` would explode).
pub const MAX_CONTINUE_RATE: f32 = 0.995;

impl Continue {
    /// builtin plus `gain` times the rest of the previous solve's way, named `name`.
    pub fn new(name: String, gain: f32) -> Continue {
        Continue { name, gain }
    }

    /// The factor on the last sweep's change: `gain * rate / (1 - rate)`, rate capped.
    pub fn factor(gain: f32, rate: f32) -> f32 {
        let r = rate.clamp(0.0, MAX_CONTINUE_RATE);
        gain * r / (1.0 - r)
    }
}

impl WarmStartModel for Continue {
    fn name(&self) -> &str {
        &self.name
    }
    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let factor = Continue::factor(self.gain, input.history.previous_rate());
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            let (Some(l), Some(d)) = (input.history.previous(&c.key), input.history.previous_last_change(&c.key))
            else {
                continue;
            };
            let n = (l.normal + factor * d.normal).max(0.0);
            let t_max = c.friction * n;
            *o = Impulse { normal: n, tangent: (l.tangent + factor * d.tangent).clamp(-t_max, t_max) };
        }
        Ok(())
    }
}

/// `builtin-reappear`: builtin, and a contact new this step that existed two steps ago (it
/// flickered off for one step) starts from its impulse then.
#[derive(Debug, Default)]
pub struct BuiltinReappear;

impl WarmStartModel for BuiltinReappear {
    fn name(&self) -> &str {
        "builtin-reappear"
    }
    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            *o = input.history.previous(&c.key).or_else(|| input.history.before_previous(&c.key)).unwrap_or_default();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::{ContactPoint, ImpulseHistory};
    use crate::warm::model::harness::{floor_contact, guess};
    use crate::warm::product::Builtin;

    fn point(body_b: u32) -> ContactPoint {
        floor_contact(body_b, 0, 0.0)
    }

    #[test]
    fn reappearing_contacts_and_damped_extrapolation() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let mut history = ImpulseHistory::default();
        // Two steps ago: contacts 1 and 2; last step: contacts 1 and 3 (2 flickered off).
        history.push(
            [point(1).key, point(2).key].into_iter(),
            &[imp(1.0, 0.1), imp(2.0, 0.2)],
            ImpulseHistory::no_trail(),
        );
        history.push(
            [point(1).key, point(3).key].into_iter(),
            &[imp(1.5, 0.2), imp(3.0, 0.3)],
            ImpulseHistory::no_trail(),
        );
        let contacts = [point(1), point(2), point(3)];
        assert_eq!(guess(&mut Builtin, &contacts, &history), [imp(1.5, 0.2), imp(0.0, 0.0), imp(3.0, 0.3)]);
        assert_eq!(guess(&mut BuiltinReappear, &contacts, &history), [imp(1.5, 0.2), imp(2.0, 0.2), imp(3.0, 0.3)]);
        // l1 + beta (l1 - l2) on the contact with two steps of history, l1 on the one with one.
        let mut half = Extrapolate::new("extrapolate:0.5".into(), 0.5);
        let g = guess(&mut half, &contacts, &history);
        assert_eq!((g[0].normal, g[1], g[2]), (1.75, imp(0.0, 0.0), imp(3.0, 0.3)));
        assert!((g[0].tangent - 0.25).abs() < 1e-6);
    }

    #[test]
    fn continue_follows_the_last_sweep_by_the_geometric_series() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let mut history = ImpulseHistory::default();
        let zero = imp(0.0, 0.0);
        let changes = [[imp(0.01, -0.002), zero, zero, zero], [imp(-0.5, 0.0), zero, zero, zero]];
        let trail = crate::contact::SolveTrail { changes: &changes, rate: 0.9 };
        history.push([point(1).key, point(2).key].into_iter(), &[imp(1.0, 0.1), imp(0.2, 0.0)], trail);
        let contacts = [point(1), point(2), point(3)];
        // rate 0.9: the rest of the way is 9 times the last change; gain 0.5 takes half of it.
        assert!((Continue::factor(0.5, 0.9) - 4.5).abs() < 1e-5);
        let g = guess(&mut Continue::new("continue:0.5".into(), 0.5), &contacts, &history);
        assert!((g[0].normal - 1.045).abs() < 1e-6 && (g[0].tangent - 0.091).abs() < 1e-6, "{g:?}");
        assert_eq!(g[1], imp(0.0, 0.0), "a negative normal is projected to 0 (and its tangent with it)");
        assert_eq!(g[2], imp(0.0, 0.0), "a new contact starts at 0");
        // A solve at its cap converges at a rate near 1: the factor stays bounded.
        assert!(Continue::factor(1.0, 1.0).is_finite() && Continue::factor(1.0, 1.0) <= 200.0);
        assert_eq!(Continue::factor(1.0, 0.0), 0.0);
    }
}
