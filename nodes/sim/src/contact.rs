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

/// The final impulses of the last two steps, sorted by key, for temporal models.
#[derive(Debug, Clone, Default)]
pub struct ImpulseHistory {
    previous: Vec<(ContactKey, Impulse)>,
    before_previous: Vec<(ContactKey, Impulse)>,
}

impl ImpulseHistory {
    /// The impulse of contact `key` in the previous step, if it existed then.
    pub fn previous(&self, key: &ContactKey) -> Option<Impulse> {
        lookup(&self.previous, key)
    }

    /// The impulse of contact `key` two steps ago, if it existed then.
    pub fn before_previous(&self, key: &ContactKey) -> Option<Impulse> {
        lookup(&self.before_previous, key)
    }

    /// Records the step's final impulses (`keys` sorted) and shifts the older step back.
    pub fn push(&mut self, keys: impl Iterator<Item = ContactKey>, impulses: &[Impulse]) {
        std::mem::swap(&mut self.previous, &mut self.before_previous);
        self.previous.clear();
        self.previous.extend(keys.zip(impulses.iter().copied()));
        debug_assert!(self.previous.windows(2).all(|w| w[0].0 <= w[1].0), "keys must be sorted");
    }

    /// Forgets everything (a new simulation).
    pub fn clear(&mut self) {
        self.previous.clear();
        self.before_previous.clear();
    }
}

fn lookup(list: &[(ContactKey, Impulse)], key: &ContactKey) -> Option<Impulse> {
    list.binary_search_by(|(k, _)| k.cmp(key)).ok().map(|i| list[i].1)
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
