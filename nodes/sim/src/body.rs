//! One body's state and mass properties: the world's source of truth (rapier only mirrors poses).

use crate::scene::{BodyKind, ShapeSpec};
use rapier2d::math::Vec2;

/// The state and mass properties of one body.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyState {
    /// How it moves.
    pub kind: BodyKind,
    /// Its shape.
    pub shape: ShapeSpec,
    /// Position of the centre of mass.
    pub x: Vec2,
    /// Orientation.
    pub angle: f32,
    /// Linear velocity.
    pub v: Vec2,
    /// Angular velocity.
    pub w: f32,
    /// Mass (0 for static and kinematic bodies).
    pub mass: f32,
    /// Moment of inertia about the centre of mass (0 for static and kinematic bodies).
    pub inertia: f32,
    /// Initial pose, from which kinematic bodies' prescribed poses are computed without drift.
    pub x0: Vec2,
    /// Initial orientation.
    pub angle0: f32,
}

impl BodyState {
    /// Inverse mass (0 for infinite mass).
    pub fn inv_mass(&self) -> f32 {
        if self.mass > 0.0 {
            1.0 / self.mass
        } else {
            0.0
        }
    }
    /// Inverse moment of inertia (0 for infinite inertia).
    pub fn inv_inertia(&self) -> f32 {
        if self.inertia > 0.0 {
            1.0 / self.inertia
        } else {
            0.0
        }
    }
}
