//! The contacts of a step and how they are matched across steps: [`ContactKey`] (body pair and
//! feature pair), [`ContactPoint`] (one point of the current step) and [`ImpulseHistory`] (the final
//! impulses of the last two steps). Shared by the world, which makes them, and the warm-start
//! models, which read them.

use crate::solver::Impulse;
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
/// contact's age (consecutive steps it has existed).
#[derive(Debug, Clone, Default)]
pub struct ImpulseHistory {
    /// (key, final impulse, age in that step: 0 when it was new then).
    previous: Vec<(ContactKey, Impulse, u32)>,
    before_previous: Vec<(ContactKey, Impulse, u32)>,
}

impl ImpulseHistory {
    /// The impulse of contact `key` in the previous step, if it existed then.
    pub fn previous(&self, key: &ContactKey) -> Option<Impulse> {
        lookup(&self.previous, key).map(|(i, _)| i)
    }

    /// The impulse of contact `key` two steps ago, if it existed then.
    pub fn before_previous(&self, key: &ContactKey) -> Option<Impulse> {
        lookup(&self.before_previous, key).map(|(i, _)| i)
    }

    /// builtin's warm start: each contact's impulse in the previous step, 0 for new ones.
    pub fn fill_previous(&self, contacts: &[ContactPoint], out: &mut [Impulse]) {
        for (c, o) in contacts.iter().zip(out.iter_mut()) {
            *o = self.previous(&c.key).unwrap_or_default();
        }
    }

    /// How many consecutive steps contact `key` has existed before the current one (0: new).
    pub fn age(&self, key: &ContactKey) -> u32 {
        lookup(&self.previous, key).map_or(0, |(_, age)| age + 1)
    }

    /// Records the step's final impulses (`keys` sorted) and shifts the older step back.
    pub fn push(&mut self, keys: impl Iterator<Item = ContactKey>, impulses: &[Impulse]) {
        let mut next = std::mem::take(&mut self.before_previous);
        next.clear();
        // Both lists are sorted by key: one merge walk finds each contact's age (every step, for
        // every model, so no search per contact).
        let mut old = self.previous.iter().peekable();
        for (k, i) in keys.zip(impulses.iter().copied()) {
            while old.next_if(|o| o.0 < k).is_some() {}
            let age = old.next_if(|o| o.0 == k).map_or(0, |o| o.2 + 1);
            next.push((k, i, age));
        }
        debug_assert!(next.windows(2).all(|w| w[0].0 <= w[1].0), "keys must be sorted");
        self.before_previous = std::mem::replace(&mut self.previous, next);
    }

    /// Forgets everything (a new simulation).
    pub fn clear(&mut self) {
        self.previous.clear();
        self.before_previous.clear();
    }
}

fn lookup(list: &[(ContactKey, Impulse, u32)], key: &ContactKey) -> Option<(Impulse, u32)> {
    list.binary_search_by(|(k, _, _)| k.cmp(key)).ok().map(|i| (list[i].1, list[i].2))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ages_count_consecutive_steps() {
        let k = |b| ContactKey { body_a: 0, body_b: b, feature: 0 };
        let one = [Impulse { normal: 1.0, tangent: 0.0 }; 2];
        let mut h = ImpulseHistory::default();
        h.push([k(1), k(2)].into_iter(), &one);
        assert_eq!((h.age(&k(1)), h.age(&k(3))), (1, 0));
        h.push([k(1), k(3)].into_iter(), &one);
        assert_eq!((h.age(&k(1)), h.age(&k(2)), h.age(&k(3))), (2, 0, 1));
        assert!(h.before_previous(&k(2)).is_some() && h.previous(&k(2)).is_none());
        h.push([k(2)].into_iter(), &one[..1]);
        assert_eq!(h.age(&k(2)), 1, "a contact that reappears starts again");
    }
}
