//! The contacts of a step and how they are matched across steps: [`ContactKey`] (body pair and
//! feature pair), [`ContactPoint`] (one point of the current step) and [`ImpulseHistory`] (the final
//! impulses of the last two steps). Shared by the world, which makes them, and the warm-start
//! models, which read them.

use crate::solver::{Impulse, TRAIL_SWEEPS};
use rapier2d::math::Vec2;
use rapier2d::parry::shape::PackedFeatureId;

/// Identifies a contact across steps: the body pair (a < b) and the feature pair within it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct ContactKey {
    /// The lower body id.
    pub body_a: u32,
    /// The higher body id.
    pub body_b: u32,
    /// The packed feature ids of both bodies (see [`feature_key`]).
    pub feature: u32,
}

/// The final impulses of the last two steps, sorted by key, for temporal models; with each
/// contact's age (consecutive steps it has existed) and where the previous solve was still going.
#[derive(Debug, Clone, Default)]
pub struct ImpulseHistory {
    previous: Vec<Entry>,
    before_previous: Vec<Entry>,
    /// The previous solve's convergence rate ([`crate::solver::ContactSolver::convergence_rate`]).
    previous_rate: f32,
}

/// One contact of a past step.
#[derive(Debug, Clone, Copy)]
struct Entry {
    key: ContactKey,
    /// Final impulse.
    impulse: Impulse,
    /// Age in that step: 0 when it was new then.
    age: u32,
    /// The impulse changes of that solve's last sweeps, most recent first.
    trail: [Impulse; TRAIL_SWEEPS],
}

/// How a solve ended, per contact row and overall: what [`ImpulseHistory::push`] keeps beside the
/// impulses.
#[derive(Debug, Clone, Copy)]
pub struct SolveTrail<'a> {
    /// Each row's impulse changes in the last sweeps, most recent first
    /// ([`crate::solver::ContactSolver::trail`]).
    pub changes: &'a [[Impulse; TRAIL_SWEEPS]],
    /// The solve's convergence rate.
    pub rate: f32,
}

impl ImpulseHistory {
    /// The impulse of contact `key` in the previous step, if it existed then.
    pub fn previous(&self, key: &ContactKey) -> Option<Impulse> {
        lookup(&self.previous, key).map(|e| e.impulse)
    }

    /// The impulse change of the previous solve's last sweep for contact `key`, if it existed then.
    pub fn previous_last_change(&self, key: &ContactKey) -> Option<Impulse> {
        lookup(&self.previous, key).map(|e| e.trail[0])
    }

    /// The impulse changes of the previous solve's last sweeps for contact `key` (most recent
    /// first), if it existed then.
    pub fn previous_trail(&self, key: &ContactKey) -> Option<&[Impulse; TRAIL_SWEEPS]> {
        lookup(&self.previous, key).map(|e| &e.trail)
    }

    /// The previous solve's convergence rate (0 before the first step).
    pub fn previous_rate(&self) -> f32 {
        self.previous_rate
    }

    /// The impulse of contact `key` two steps ago, if it existed then.
    pub fn before_previous(&self, key: &ContactKey) -> Option<Impulse> {
        lookup(&self.before_previous, key).map(|e| e.impulse)
    }

    /// builtin's warm start: each contact's impulse in the previous step, 0 for new ones.
    pub fn fill_previous(&self, contacts: &[ContactPoint], out: &mut [Impulse]) {
        for (o, previous) in out.iter_mut().zip(self.previous_each(contacts.iter().map(|c| &c.key))) {
            *o = previous.unwrap_or_default();
        }
    }

    /// Each contact's impulse in the previous step (None: new), in order: one walk along the
    /// previous step only (what [`Self::pasts`] does for both past steps).
    pub fn previous_each<'a>(
        &'a self,
        keys: impl Iterator<Item = &'a ContactKey> + 'a,
    ) -> impl Iterator<Item = Option<Impulse>> + 'a {
        let mut previous = Cursor::new(&self.previous);
        keys.map(move |key| previous.find(key).map(|e| e.impulse))
    }

    /// Each contact's past, in order: its age, its impulse in the previous step and in the one
    /// before. A step's contacts come sorted by key, and so are the past steps: one walk along
    /// both instead of three searches per contact (any order is still answered right).
    pub fn pasts<'a>(&'a self, keys: impl Iterator<Item = &'a ContactKey> + 'a) -> impl Iterator<Item = Past> + 'a {
        let (mut previous, mut before) = (Cursor::new(&self.previous), Cursor::new(&self.before_previous));
        keys.map(move |key| {
            let last = previous.find(key);
            Past {
                age: last.map_or(0, |e| e.age + 1),
                previous: last.map(|e| e.impulse),
                before_previous: before.find(key).map(|e| e.impulse),
            }
        })
    }

    /// How many consecutive steps contact `key` has existed before the current one (0: new).
    pub fn age(&self, key: &ContactKey) -> u32 {
        lookup(&self.previous, key).map_or(0, |e| e.age + 1)
    }

    /// Records the step's final impulses (`keys` sorted) and how its solve ended, and shifts the
    /// older step back.
    pub fn push(&mut self, keys: impl Iterator<Item = ContactKey>, impulses: &[Impulse], trail: SolveTrail<'_>) {
        let mut next = std::mem::take(&mut self.before_previous);
        next.clear();
        // Both lists are sorted by key: one merge walk finds each contact's age (every step, for
        // every model, so no search per contact).
        let mut old = self.previous.iter().peekable();
        let changes = trail.changes.iter().copied().chain(std::iter::repeat([Impulse::default(); TRAIL_SWEEPS]));
        for ((key, impulse), trail) in keys.zip(impulses.iter().copied()).zip(changes) {
            while old.next_if(|o| o.key < key).is_some() {}
            let age = old.next_if(|o| o.key == key).map_or(0, |o| o.age + 1);
            next.push(Entry { key, impulse, age, trail });
        }
        debug_assert!(next.windows(2).all(|w| w[0].key <= w[1].key), "keys must be sorted");
        self.before_previous = std::mem::replace(&mut self.previous, next);
        self.previous_rate = trail.rate;
    }

    /// Forgets everything (a new simulation).
    pub fn clear(&mut self) {
        self.previous.clear();
        self.before_previous.clear();
        self.previous_rate = 0.0;
    }

    /// A trail of a solve that said nothing about how it ended (tests, recorded impulses).
    pub fn no_trail() -> SolveTrail<'static> {
        SolveTrail { changes: &[], rate: 0.0 }
    }
}

/// A contact's past (see [`ImpulseHistory::pasts`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Past {
    /// Consecutive steps it has existed before the current one (0: new).
    pub age: u32,
    pub previous: Option<Impulse>,
    pub before_previous: Option<Impulse>,
}

fn lookup<'a>(list: &'a [Entry], key: &ContactKey) -> Option<&'a Entry> {
    list.binary_search_by(|e| e.key.cmp(key)).ok().map(|i| &list[i])
}

/// Finds keys in a sorted list by walking it forward, for keys asked in sorted order; a key
/// asked out of order (one the walk may have passed) is searched for.
struct Cursor<'a> {
    list: &'a [Entry],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn new(list: &'a [Entry]) -> Cursor<'a> {
        Cursor { list, at: 0 }
    }

    fn find(&mut self, key: &ContactKey) -> Option<&'a Entry> {
        if self.at > 0 && self.list[self.at - 1].key >= *key {
            return lookup(self.list, key);
        }
        while self.list.get(self.at).is_some_and(|e| e.key < *key) {
            self.at += 1;
        }
        self.list.get(self.at).filter(|e| e.key == *key)
    }
}

/// One contact point of the current step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactPoint {
    /// Identifies the contact across steps.
    pub key: ContactKey,
    /// World contact point (midway between the two surfaces).
    pub point: Vec2,
    /// Unit normal from body a to body b.
    pub normal: Vec2,
    /// Overlap depth (positive when overlapping).
    pub penetration: f32,
    /// Friction coefficient.
    pub friction: f32,
}

/// Packs one feature id into 16 bits: 2 bits of type (vertex/face), 14 bits of index.
fn pack_feature(f: PackedFeatureId) -> u32 {
    ((f.0 >> 30) << 14) | (f.0 & 0x3fff)
}

/// The feature part of a [`ContactKey`]: body a's feature in the high half, body b's in the low.
pub fn feature_key(fa: PackedFeatureId, fb: PackedFeatureId) -> u32 {
    (pack_feature(fa) << 16) | pack_feature(fb)
}

/// Jacobi passes of the contact-graph average that define the "smooth part" of an error field.
pub const SMOOTHING_PASSES: usize = 4;

/// `passes` Jacobi passes of averaging `field` over the contact graph: a contact's value becomes the
/// mean of itself and the contacts it shares a moving body with (bodies of infinite mass, `fixed`,
/// do not link their contacts: the floor would smooth across the whole pile). What survives a few
/// passes is the pile-wide, low-frequency part of the field.
pub fn smooth_over_contacts(
    contacts: &[ContactPoint],
    fixed: &[bool],
    field: &[Impulse],
    passes: usize,
    out: &mut Vec<Impulse>,
) {
    let n = contacts.len();
    out.clear();
    out.extend_from_slice(field);
    if n == 0 {
        return;
    }
    // Contacts per moving body.
    let bodies = contacts.iter().map(|c| c.key.body_b.max(c.key.body_a) as usize + 1).max().unwrap_or(0);
    let mut per_body: Vec<Vec<u32>> = vec![Vec::new(); bodies];
    for (i, c) in contacts.iter().enumerate() {
        for b in [c.key.body_a, c.key.body_b] {
            if !fixed.get(b as usize).copied().unwrap_or(false) {
                per_body[b as usize].push(i as u32);
            }
        }
    }
    let mut next = vec![Impulse::default(); n];
    for _ in 0..passes {
        for (i, c) in contacts.iter().enumerate() {
            let (mut sn, mut st, mut k) = (out[i].normal as f64, out[i].tangent as f64, 1u32);
            for b in [c.key.body_a, c.key.body_b] {
                for &j in per_body.get(b as usize).map(Vec::as_slice).unwrap_or(&[]) {
                    if j as usize != i {
                        sn += out[j as usize].normal as f64;
                        st += out[j as usize].tangent as f64;
                        k += 1;
                    }
                }
            }
            next[i] = Impulse { normal: (sn / k as f64) as f32, tangent: (st / k as f64) as f32 };
        }
        out.copy_from_slice(&next);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_walk_finds_what_the_searches_find_in_any_order() {
        let k = |b, f| ContactKey { body_a: 1, body_b: b, feature: f };
        let imp = |n: f32| Impulse { normal: n, tangent: -n };
        let mut h = ImpulseHistory::default();
        let first = [k(2, 0), k(2, 1), k(3, 0), k(5, 0), k(7, 2)];
        h.push(first.iter().copied(), &first.map(|c| imp(c.body_b as f32)), ImpulseHistory::no_trail());
        let second = [k(2, 1), k(3, 0), k(4, 0), k(7, 2), k(9, 0)];
        h.push(second.iter().copied(), &second.map(|c| imp(10.0 + c.feature as f32)), ImpulseHistory::no_trail());
        let searched = |key: &ContactKey| Past {
            age: h.age(key),
            previous: h.previous(key),
            before_previous: h.before_previous(key),
        };
        // Sorted (a step's contacts), with keys absent from either step, then out of order and repeated.
        for keys in [
            vec![k(1, 0), k(2, 0), k(2, 1), k(3, 0), k(4, 0), k(6, 0), k(7, 2), k(9, 0), k(10, 0)],
            vec![k(9, 0), k(2, 1), k(7, 2), k(2, 1), k(3, 0), k(2, 0), k(10, 0), k(1, 0)],
        ] {
            let walked: Vec<Past> = h.pasts(keys.iter()).collect();
            let want: Vec<Past> = keys.iter().map(searched).collect();
            assert_eq!(walked, want, "{keys:?}");
            let points: Vec<ContactPoint> = keys
                .iter()
                .map(|&key| ContactPoint { key, point: Vec2::ZERO, normal: Vec2::Y, penetration: 0.0, friction: 0.5 })
                .collect();
            let mut out = vec![imp(99.0); keys.len()];
            h.fill_previous(&points, &mut out);
            assert_eq!(out, want.iter().map(|p| p.previous.unwrap_or_default()).collect::<Vec<_>>());
        }
        assert_eq!(searched(&k(7, 2)), Past { age: 2, previous: Some(imp(12.0)), before_previous: Some(imp(7.0)) });
    }

    #[test]
    fn ages_count_consecutive_steps() {
        let k = |b| ContactKey { body_a: 0, body_b: b, feature: 0 };
        let one = [Impulse { normal: 1.0, tangent: 0.0 }; 2];
        let mut h = ImpulseHistory::default();
        h.push([k(1), k(2)].into_iter(), &one, ImpulseHistory::no_trail());
        assert_eq!((h.age(&k(1)), h.age(&k(3))), (1, 0));
        h.push([k(1), k(3)].into_iter(), &one, ImpulseHistory::no_trail());
        assert_eq!((h.age(&k(1)), h.age(&k(2)), h.age(&k(3))), (2, 0, 1));
        assert!(h.before_previous(&k(2)).is_some() && h.previous(&k(2)).is_none());
        h.push([k(2)].into_iter(), &one[..1], ImpulseHistory::no_trail());
        assert_eq!(h.age(&k(2)), 1, "a contact that reappears starts again");
    }
}
