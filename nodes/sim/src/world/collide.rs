//! Collision detection: rapier2d's shapes, broad and narrow phase (its `CollisionPipeline` only)
//! on the bodies' current poses, into contact points sorted by key and the rows the position pass
//! measures them by. rapier holds only a mirror of the poses; the bodies are ours.

use crate::body::BodyState;
use crate::contact::{feature_key, ContactKey, ContactPoint};
use crate::scene::{BodyKind, Scene, ShapeSpec};
use crate::solver::position::rotate;
use crate::solver::{PositionGeometry, PositionRow};
use rapier2d::math::{Pose, Vec2};
use rapier2d::prelude::{PhysicsWorld, RigidBodyHandle};

/// rapier's collision structures for one scene, and the detection's scratch.
pub(crate) struct Collision {
    rapier: PhysicsWorld,
    handles: Vec<RigidBodyHandle>,
    staging: Vec<(ContactKey, ContactPoint, PositionRow)>,
}

impl Collision {
    /// rapier's bodies and colliders for `scene`, and our body states (at rest, mass properties
    /// from rapier's colliders).
    pub(crate) fn new(scene: &Scene) -> (Collision, Vec<BodyState>) {
        let mut rapier = PhysicsWorld::new();
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        let mut handles = Vec::with_capacity(scene.bodies.len());
        for (id, spec) in scene.bodies.iter().enumerate() {
            let (rb, collider) = scene.rapier_body(id);
            let pose = Pose::new(Vec2::from(spec.position), spec.angle);
            let (mass, inertia) = if spec.kind == BodyKind::Dynamic {
                let mp = collider.mass_properties();
                (1.0 / mp.inv_mass, 1.0 / mp.inv_principal_inertia)
            } else {
                (0.0, 0.0)
            };
            handles.push(rapier.insert(rb, collider).0);
            bodies.push(BodyState {
                kind: spec.kind,
                shape: spec.shape.clone(),
                x: pose.translation,
                angle: spec.angle,
                v: Vec2::ZERO,
                w: 0.0,
                mass,
                inertia,
                x0: pose.translation,
                angle0: spec.angle,
            });
        }
        (Collision { rapier, handles, staging: Vec::new() }, bodies)
    }

    /// Mirrors the poses of moving bodies into rapier (marks them modified for the narrow phase).
    pub(crate) fn mirror_poses(&mut self, bodies: &[BodyState]) {
        for (b, h) in bodies.iter().zip(&self.handles) {
            if b.kind == BodyKind::Static {
                continue;
            }
            if let Some(rb) = self.rapier.bodies.get_mut(*h) {
                rb.set_position(Pose::new(b.x, b.angle), true);
            }
        }
    }

    /// Runs rapier's collision detection with manifolds kept `prediction` apart, and writes the
    /// manifold points at most `margin` apart as contacts sorted by key, with their position rows.
    pub(crate) fn detect(
        &mut self,
        bodies: &[BodyState],
        prediction: f32,
        margin: f32,
        contacts: &mut Vec<ContactPoint>,
        position_rows: &mut Vec<PositionRow>,
    ) {
        let r = &mut self.rapier;
        r.collision_pipeline.step(
            prediction,
            &mut r.islands,
            &mut r.broad_phase,
            &mut r.narrow_phase,
            &mut r.bodies,
            &mut r.colliders,
            &(),
            &(),
        );
        self.staging.clear();
        for pair in r.narrow_phase.contact_pairs() {
            let (Some(c1), Some(c2)) = (r.colliders.get(pair.collider1), r.colliders.get(pair.collider2)) else {
                continue;
            };
            let (id1, id2) = (c1.user_data as u32, c2.user_data as u32);
            let (b1, b2) = (&bodies[id1 as usize], &bodies[id2 as usize]);
            if b1.mass == 0.0 && b2.mass == 0.0 {
                continue;
            }
            // Canonical order: a is the lower id, so keys do not depend on rapier's pair order.
            let swap = id1 > id2;
            let (ia, ib) = if swap { (id2, id1) } else { (id1, id2) };
            let (ba, bb) = (&bodies[ia as usize], &bodies[ib as usize]);
            for manifold in pair.manifolds() {
                let friction = manifold.data.friction;
                let (ln_a, ln_b) =
                    if swap { (manifold.local_n2, manifold.local_n1) } else { (manifold.local_n1, manifold.local_n2) };
                let normal = if swap { -manifold.data.normal } else { manifold.data.normal };
                for p in &manifold.points {
                    if p.dist > margin {
                        continue;
                    }
                    let (lp_a, lp_b, f_a, f_b) = if swap {
                        (p.local_p2, p.local_p1, p.fid2, p.fid1)
                    } else {
                        (p.local_p1, p.local_p2, p.fid1, p.fid2)
                    };
                    let wa = ba.x + rotate(ba.angle, lp_a);
                    let wb = bb.x + rotate(bb.angle, lp_b);
                    let key = ContactKey { body_a: ia, body_b: ib, feature: feature_key(f_a, f_b) };
                    let point = ContactPoint { key, point: (wa + wb) * 0.5, normal, penetration: -p.dist, friction };
                    let geometry = position_geometry(&ba.shape, &bb.shape, (ln_a, lp_a), (ln_b, lp_b));
                    self.staging.push((key, point, PositionRow { body_a: ia, body_b: ib, geometry }));
                }
            }
        }
        // Stable sort: equal keys (never expected for convex shapes) keep rapier's order.
        self.staging.sort_by_key(|a| a.0);
        contacts.clear();
        position_rows.clear();
        contacts.extend(self.staging.iter().map(|s| s.1));
        position_rows.extend(self.staging.iter().map(|s| s.2));
    }
}

/// How the position pass measures a contact between shapes `a` and `b`, from each body's local
/// manifold normal and point (Box2D's `e_circles`, `e_faceA`, `e_faceB`).
fn position_geometry(
    a: &ShapeSpec,
    b: &ShapeSpec,
    (ln_a, lp_a): (Vec2, Vec2),
    (ln_b, lp_b): (Vec2, Vec2),
) -> PositionGeometry {
    match (a, b) {
        (ShapeSpec::Ball { radius: ra }, ShapeSpec::Ball { radius: rb }) => {
            PositionGeometry::Circles { radius_a: *ra, radius_b: *rb }
        }
        // A disc never carries the reference face: its normal follows the other body.
        (ShapeSpec::Ball { radius }, _) => PositionGeometry::Face {
            reference_is_a: false,
            local_normal: ln_b,
            local_plane_point: lp_b,
            local_clip_point: Vec2::ZERO,
            clip_radius: *radius,
        },
        (_, ShapeSpec::Ball { radius }) => PositionGeometry::Face {
            reference_is_a: true,
            local_normal: ln_a,
            local_plane_point: lp_a,
            local_clip_point: Vec2::ZERO,
            clip_radius: *radius,
        },
        _ => PositionGeometry::Face {
            reference_is_a: true,
            local_normal: ln_a,
            local_plane_point: lp_a,
            local_clip_point: lp_b,
            clip_radius: 0.0,
        },
    }
}
