//! Oracle ablations: warm starts made from the step's exact solution (the oracle, solved from
//! builtin's warm start to a tight tolerance) and builtin's guess, to map how much of builtin's
//! error a model must remove, and which part of it, to save sweeps — the accuracy -> sweeps curve
//! any learned model is judged on. Not usable in a real simulator (the oracle *is* the solve).

use crate::contact::{smooth_over_contacts, ContactKey, SMOOTHING_PASSES};
use crate::rng::{Sampler, Xoshiro};
use crate::solver::rows::Impulse;
use crate::warm::model::{exact_solution, Needs, Unavailable, WarmStartInput, WarmStartModel};

/// What an ablation does with the oracle's solution and builtin's guess.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Ablation {
    /// `copy-persisting`: exact on persisting contacts, 0 on new ones.
    CopyPersisting,
    /// `copy-new`: builtin on persisting contacts, exact on new ones.
    CopyNew,
    /// `copy-previous`: the previous step's exact solution on persisting contacts, 0 on new ones:
    /// builtin as it would be if every solve were finished, not stopped at the tolerance.
    CopyPrevious,
    /// `blend:F`: builtin + F (exact - builtin).
    Blend(f32),
    /// `noise:S`: exact + Gaussian noise of S x builtin's RMS error of the step.
    Noise(f32),
    /// `smooth-error`: exact + the smooth part of builtin's error.
    SmoothError,
    /// `rough-error`: exact + builtin's error minus its smooth part.
    RoughError,
}

/// An ablation model.
pub struct OracleAblation {
    name: String,
    ablation: Ablation,
    seed: u64,
    rng: Xoshiro,
    exact: Vec<Impulse>,
    error: Vec<Impulse>,
    smooth: Vec<Impulse>,
    /// Per body: infinite mass (static or kinematic), from the step's solver bodies.
    fixed: Vec<bool>,
    /// The previous step's exact solution, sorted by key (`copy-previous`).
    previous_exact: Vec<(ContactKey, Impulse)>,
}

impl OracleAblation {
    pub fn new(name: String, ablation: Ablation, seed: u64) -> OracleAblation {
        OracleAblation {
            name,
            ablation,
            seed,
            rng: Xoshiro::new(seed),
            exact: Vec::new(),
            error: Vec::new(),
            smooth: Vec::new(),
            fixed: Vec::new(),
            previous_exact: Vec::new(),
        }
    }
}

impl WarmStartModel for OracleAblation {
    fn name(&self) -> &str {
        &self.name
    }

    fn needs(&self) -> Needs {
        // The smoothing links contacts through moving bodies: it reads which bodies are fixed.
        Needs::EXACT.union(Needs::ROWS)
    }

    fn begin_simulation(&mut self, _simulation: u32, seed: u64) {
        // Its own stream per simulation, apart from the scene sampler's and `random`'s.
        self.rng = Xoshiro::new(self.seed ^ seed.wrapping_mul(0xd1b5_4a32_d192_ed03) ^ 0xab1a);
        self.previous_exact.clear();
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let n = input.contacts.len();
        self.exact.clear();
        self.exact.extend_from_slice(exact_solution(input)?);
        input.history.fill_previous(input.contacts, out);
        // builtin's error, exact - builtin... stored as builtin - exact (what the guess adds).
        self.error.clear();
        self.error.extend(
            out.iter()
                .zip(&self.exact)
                .map(|(b, e)| Impulse { normal: b.normal - e.normal, tangent: b.tangent - e.tangent }),
        );
        match self.ablation {
            Ablation::CopyPersisting => {
                for ((c, o), e) in input.contacts.iter().zip(out.iter_mut()).zip(&self.exact) {
                    *o = if input.history.previous(&c.key).is_some() { *e } else { Impulse::default() };
                }
            }
            Ablation::CopyNew => {
                for ((c, o), e) in input.contacts.iter().zip(out.iter_mut()).zip(&self.exact) {
                    if input.history.previous(&c.key).is_none() {
                        *o = *e;
                    }
                }
            }
            Ablation::CopyPrevious => {
                for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
                    *o = match self.previous_exact.binary_search_by(|(k, _)| k.cmp(&c.key)) {
                        Ok(i) if input.history.previous(&c.key).is_some() => self.previous_exact[i].1,
                        _ => Impulse::default(),
                    };
                }
                self.previous_exact.clear();
                self.previous_exact.extend(input.contacts.iter().map(|c| c.key).zip(self.exact.iter().copied()));
            }
            Ablation::Blend(f) => {
                for (o, e) in out.iter_mut().zip(&self.exact) {
                    o.normal += f * (e.normal - o.normal);
                    o.tangent += f * (e.tangent - o.tangent);
                }
            }
            Ablation::Noise(s) => {
                let rms = |f: fn(&Impulse) -> f32| {
                    let sum: f64 = self.error.iter().map(|e| (f(e) as f64).powi(2)).sum();
                    (sum / n.max(1) as f64).sqrt()
                };
                let (sn, st) = (s as f64 * rms(|e| e.normal), s as f64 * rms(|e| e.tangent));
                for (o, e) in out.iter_mut().zip(&self.exact) {
                    o.normal = e.normal + (sn * self.rng.gauss()) as f32;
                    o.tangent = e.tangent + (st * self.rng.gauss()) as f32;
                }
            }
            Ablation::SmoothError | Ablation::RoughError => {
                self.fixed.clear();
                if let Some(step) = input.rows {
                    self.fixed.extend(step.bodies.iter().map(|b| b.inv_mass == 0.0));
                }
                smooth_over_contacts(input.contacts, &self.fixed, &self.error, SMOOTHING_PASSES, &mut self.smooth);
                let rough = self.ablation == Ablation::RoughError;
                for (((o, e), err), sm) in out.iter_mut().zip(&self.exact).zip(&self.error).zip(&self.smooth) {
                    let (dn, dt) = if rough {
                        (err.normal - sm.normal, err.tangent - sm.tangent)
                    } else {
                        (sm.normal, sm.tangent)
                    };
                    *o = Impulse { normal: e.normal + dn, tangent: e.tangent + dt };
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::{ContactKey, ContactPoint};
    use rapier2d::math::Vec2;

    fn contact(a: u32, b: u32) -> ContactPoint {
        ContactPoint {
            key: ContactKey { body_a: a, body_b: b, feature: 0 },
            point: Vec2::ZERO,
            normal: Vec2::Y,
            penetration: 0.0,
            friction: 0.5,
        }
    }

    #[test]
    fn smoothing_keeps_constants_and_damps_alternation() {
        // A chain of bodies 1-2-3-4-5 on a fixed floor 0: contacts (1,2), (2,3), (3,4), (4,5) and
        // each body on the floor.
        let mut contacts: Vec<ContactPoint> = (1..5).map(|i| contact(i, i + 1)).collect();
        contacts.extend((1..6).map(|i| contact(0, i)));
        let fixed = [true, false, false, false, false, false];
        let constant = vec![Impulse { normal: 2.0, tangent: -1.0 }; contacts.len()];
        let mut out = Vec::new();
        smooth_over_contacts(&contacts, &fixed, &constant, 4, &mut out);
        assert!(out.iter().all(|o| (o.normal - 2.0).abs() < 1e-6 && (o.tangent + 1.0).abs() < 1e-6));
        let alternating: Vec<Impulse> = (0..contacts.len())
            .map(|i| Impulse { normal: if i % 2 == 0 { 1.0 } else { -1.0 }, tangent: 0.0 })
            .collect();
        smooth_over_contacts(&contacts, &fixed, &alternating, 4, &mut out);
        let energy = |v: &[Impulse]| v.iter().map(|o| o.normal * o.normal).sum::<f32>();
        assert!(energy(&out) < 0.2 * energy(&alternating), "{out:?}");
    }

    #[test]
    fn copy_previous_starts_persisting_contacts_from_the_last_exact_solution() {
        use crate::contact::ImpulseHistory;
        let imp = |n: f32| Impulse { normal: n, tangent: 0.0 };
        let mut model = OracleAblation::new("copy-previous".into(), Ablation::CopyPrevious, 0);
        model.begin_simulation(0, 0);
        let mut history = ImpulseHistory::default();
        let mut step = |contacts: &[ContactPoint], exact: &[Impulse], history: &ImpulseHistory| {
            crate::warm::model::harness::guess_with_exact(&mut model, contacts, history, exact)
        };
        let first = [contact(0, 1), contact(0, 2)];
        assert_eq!(step(&first, &[imp(1.0), imp(2.0)], &history), [imp(0.0), imp(0.0)], "no past: zero");
        // The run's own solve stopped short of the exact 1.0 and 2.0.
        history.push(first.iter().map(|c| c.key), &[imp(0.9), imp(1.8)], ImpulseHistory::no_trail());
        let second = [contact(0, 1), contact(0, 3)];
        assert_eq!(step(&second, &[imp(5.0), imp(6.0)], &history), [imp(1.0), imp(0.0)]);
    }

    #[test]
    fn the_fixed_floor_links_nothing() {
        // Two separate bodies on the floor: their contacts never mix.
        let contacts = [contact(0, 1), contact(0, 2)];
        let field = [Impulse { normal: 1.0, tangent: 0.0 }, Impulse { normal: 5.0, tangent: 0.0 }];
        let mut out = Vec::new();
        smooth_over_contacts(&contacts, &[true, false, false], &field, 3, &mut out);
        assert_eq!(out, field);
    }
}
