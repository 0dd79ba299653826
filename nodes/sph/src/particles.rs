//! Particles: positions with a fixed number of named values each, built from bodies or contacts.
//! Values are checked on the way in, so a NaN from the simulator is an error that names the body
//! instead of a grid that silently turns NaN around it.

use crate::error::SphError;
use msgs::{Body, Contact, Shape};

/// Grid channels of the bodies: the U-Net's 5-channel input.
pub const BODY_CHANNELS: [&str; 5] = ["vx", "vy", "omega", "mass", "inertia"];
/// Grid channels of the contacts: the impulses, named as the simulator's grid models read them.
pub const CONTACT_CHANNELS: [&str; 2] = ["normal", "tangent"];
/// The contact channels when appended to the bodies grid (the 7-channel temporal input).
pub const TEMPORAL_CHANNELS: [&str; 2] = ["prev_normal", "prev_tangent"];
/// Name of the optional channel holding the summed kernel weight of each node (0 = no particle
/// within reach).
pub const WEIGHT_CHANNEL: &str = "weight";

pub use crate::error::Source;

/// Particles with `channels().len()` values each, stored particle-major (`values[i * C + c]`) so
/// that a particle's values are contiguous when it is splatted.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ParticleSet {
    names: Vec<String>,
    sources: Vec<Source>,
    positions: Vec<[f32; 2]>,
    values: Vec<f32>,
}

impl ParticleSet {
    /// An empty set with the given channel names.
    pub fn new(channels: &[&str]) -> ParticleSet {
        ParticleSet { names: channels.iter().map(|s| s.to_string()).collect(), ..Default::default() }
    }

    /// Adds a particle; fails, naming `source` and the channel, when a value or the position is
    /// not finite, and when `values` has the wrong length.
    pub fn push(&mut self, source: Source, position: [f32; 2], values: &[f32]) -> Result<(), SphError> {
        if values.len() != self.names.len() {
            return Err(SphError::ChannelCount { expected: self.names.len(), got: values.len() });
        }
        if let Some(c) = values.iter().position(|v| !v.is_finite()) {
            return Err(SphError::NonFinite { particle: source, what: self.names[c].clone(), value: values[c] });
        }
        if let Some(axis) = position.iter().position(|v| !v.is_finite()) {
            return Err(SphError::NonFinite {
                particle: source,
                what: ["x", "y"][axis].to_string(),
                value: position[axis],
            });
        }
        self.sources.push(source);
        self.positions.push(position);
        self.values.extend_from_slice(values);
        Ok(())
    }

    /// The dynamic bodies as particles with [`BODY_CHANNELS`]; walls are skipped (they are the
    /// box the grid covers, not particles in it, and static bodies carry no meaningful mass).
    pub fn from_bodies(bodies: &[Body]) -> Result<ParticleSet, SphError> {
        let mut set = ParticleSet::new(&BODY_CHANNELS);
        set.reserve(bodies.len());
        for b in bodies.iter().filter(|b| Shape::from_u32(b.shape) != Some(Shape::Wall)) {
            set.push(Source::Body(b.id), [b.x, b.y], &[b.vx, b.vy, b.omega, b.mass, b.inertia])?;
        }
        Ok(set)
    }

    /// The contacts as particles at their points with [`CONTACT_CHANNELS`] (normal and tangent
    /// impulse).
    pub fn from_contacts(contacts: &[Contact]) -> Result<ParticleSet, SphError> {
        let mut set = ParticleSet::new(&CONTACT_CHANNELS);
        set.reserve(contacts.len());
        for c in contacts {
            let source = Source::Contact { body_a: c.body_a, body_b: c.body_b };
            set.push(source, [c.x, c.y], &[c.normal_impulse, c.tangent_impulse])?;
        }
        Ok(set)
    }

    /// Room for `n` more particles.
    pub fn reserve(&mut self, n: usize) {
        self.sources.reserve(n);
        self.positions.reserve(n);
        self.values.reserve(n * self.names.len());
    }

    /// Channel names.
    pub fn channels(&self) -> Vec<&str> {
        self.names.iter().map(String::as_str).collect()
    }

    /// Number of channels (values per particle).
    pub fn channel_count(&self) -> usize {
        self.names.len()
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are no particles.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Positions, one per particle.
    pub fn positions(&self) -> &[[f32; 2]] {
        &self.positions
    }

    /// What each particle stands for.
    pub fn sources(&self) -> &[Source] {
        &self.sources
    }

    /// All values, particle-major.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// The values of particle `i`.
    pub fn particle_values(&self, i: usize) -> &[f32] {
        let c = self.names.len();
        &self.values[i * c..(i + 1) * c]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_body_value_is_rejected_naming_the_body() {
        let bodies = [
            Body { id: 3, shape: Shape::Ball as u32, mass: 1.0, ..Default::default() },
            Body { id: 42, shape: Shape::Ball as u32, omega: f32::NAN, ..Default::default() },
        ];
        let err = ParticleSet::from_bodies(&bodies).unwrap_err().to_string();
        assert!(err.contains("body 42") && err.contains("omega"), "{err}");
    }

    #[test]
    fn nan_contact_position_is_rejected_naming_both_bodies() {
        let c = Contact { body_a: 7, body_b: 9, x: f32::NAN, ..Default::default() };
        let err = ParticleSet::from_contacts(&[c]).unwrap_err().to_string();
        assert!(err.contains("bodies 7 and 9") && err.contains('x'), "{err}");
    }

    #[test]
    fn walls_are_not_particles() {
        let bodies = [
            Body { id: 0, shape: Shape::Ball as u32, vx: 2.0, ..Default::default() },
            Body { id: 1, shape: Shape::Wall as u32, mass: f32::INFINITY, ..Default::default() },
        ];
        let set = ParticleSet::from_bodies(&bodies).unwrap();
        assert_eq!(set.len(), 1);
        assert_eq!(set.particle_values(0)[0], 2.0);
        assert_eq!(set.sources()[0], Source::Body(0));
    }
}
