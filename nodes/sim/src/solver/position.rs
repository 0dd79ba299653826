//! Box2D 2.3's position pass: after the positions were integrated, non-linear Gauss-Seidel on
//! the contacts' separations pushes penetrations back to the linear slop.

use super::rows::cross;
use rapier2d::math::Vec2;

/// How the position pass measures one contact's separation from the current poses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PositionGeometry {
    /// Two discs centred on their bodies' origins (Box2D `e_circles`): the normal follows the centres.
    Circles {
        /// Radius of body a's disc.
        radius_a: f32,
        /// Radius of body b's disc.
        radius_b: f32,
    },
    /// A reference face fixed in one body's frame and a clip point fixed in the other's (Box2D
    /// `e_faceA` / `e_faceB`); a disc's clip point is its centre with its radius.
    Face {
        /// Whether body a carries the reference face (else body b).
        reference_is_a: bool,
        /// Outward normal of the reference face, in the reference body's frame.
        local_normal: Vec2,
        /// A point on the reference face, in the reference body's frame.
        local_plane_point: Vec2,
        /// The incident point, in the other body's frame.
        local_clip_point: Vec2,
        /// Radius around the clip point (a disc's radius, else 0).
        clip_radius: f32,
    },
}

/// One contact point as the position pass needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionRow {
    /// Index of body a.
    pub body_a: u32,
    /// Index of body b.
    pub body_b: u32,
    /// How its separation is measured.
    pub geometry: PositionGeometry,
}

/// Parameters of the position pass (Box2D 2.3's values by default).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionParams {
    /// Fraction of the overlap removed per iteration (`b2_baumgarte`).
    pub baumgarte: f32,
    /// Overlap allowed to remain, so contacts persist (`b2_linearSlop`).
    pub slop: f32,
    /// Largest correction per point and iteration (`b2_maxLinearCorrection`).
    pub max_correction: f32,
    /// Iterations (`positionIterations`); stops early once every overlap is within 3 slops.
    pub iterations: u32,
}

impl Default for PositionParams {
    fn default() -> Self {
        PositionParams { baumgarte: 0.2, slop: 0.0005, max_correction: 0.2, iterations: 3 }
    }
}

/// A body's pose as the position pass moves it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PoseBody {
    /// Position of the centre of mass.
    pub x: Vec2,
    /// Orientation, radians.
    pub angle: f32,
    /// Inverse mass (0: not moved).
    pub inv_mass: f32,
    /// Inverse moment of inertia.
    pub inv_inertia: f32,
}

#[inline]
pub(crate) fn rotate(angle: f32, v: Vec2) -> Vec2 {
    let (s, c) = angle.sin_cos();
    Vec2::new(c * v.x - s * v.y, s * v.x + c * v.y)
}

/// Normal (a to b), contact point and separation of a position row at the current poses.
pub fn measure(row: &PositionRow, poses: &[PoseBody]) -> (Vec2, Vec2, f32) {
    let a = &poses[row.body_a as usize];
    let b = &poses[row.body_b as usize];
    match row.geometry {
        PositionGeometry::Circles { radius_a, radius_b } => {
            let d = b.x - a.x;
            let len = d.length();
            let n = if len > f32::EPSILON { d / len } else { Vec2::Y };
            let pa = a.x + n * radius_a;
            let pb = b.x - n * radius_b;
            (n, (pa + pb) * 0.5, len - radius_a - radius_b)
        }
        PositionGeometry::Face { reference_is_a, local_normal, local_plane_point, local_clip_point, clip_radius } => {
            let (r, i) = if reference_is_a { (a, b) } else { (b, a) };
            let n_ref = rotate(r.angle, local_normal);
            let plane = r.x + rotate(r.angle, local_plane_point);
            let clip = i.x + rotate(i.angle, local_clip_point);
            let sep = (clip - plane).dot(n_ref) - clip_radius;
            let point = clip - n_ref * clip_radius;
            let n = if reference_is_a { n_ref } else { -n_ref };
            (n, point, sep)
        }
    }
}

/// Box2D 2.3's position pass (`SolvePositionConstraints`): non-linear Gauss-Seidel on the
/// separations, each point pushing its overlap beyond the slop back by a Baumgarte fraction.
/// Returns the smallest separation seen in the last iteration.
pub fn correct_positions(rows: &[PositionRow], poses: &mut [PoseBody], params: &PositionParams) -> f32 {
    let mut min_separation = 0.0f32;
    for _ in 0..params.iterations {
        min_separation = 0.0;
        for row in rows {
            let (n, point, sep) = measure(row, poses);
            let (ia, ib) = (row.body_a as usize, row.body_b as usize);
            let (a, b) = (poses[ia], poses[ib]);
            let ra = point - a.x;
            let rb = point - b.x;
            min_separation = min_separation.min(sep);
            let c = (params.baumgarte * (sep + params.slop)).clamp(-params.max_correction, 0.0);
            let rna = cross(ra, n);
            let rnb = cross(rb, n);
            let k = a.inv_mass + b.inv_mass + a.inv_inertia * rna * rna + b.inv_inertia * rnb * rnb;
            let impulse = if k > 0.0 { -c / k } else { 0.0 };
            let p = n * impulse;
            let pa = &mut poses[ia];
            pa.x -= p * pa.inv_mass;
            pa.angle -= pa.inv_inertia * cross(ra, p);
            let pb = &mut poses[ib];
            pb.x += p * pb.inv_mass;
            pb.angle += pb.inv_inertia * cross(rb, p);
        }
        if min_separation >= -3.0 * params.slop {
            break;
        }
    }
    min_separation
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn position_pass_pushes_overlap_back_to_the_slop() {
        let mut poses = [
            PoseBody { x: Vec2::ZERO, angle: 0.0, inv_mass: 0.0, inv_inertia: 0.0 },
            PoseBody { x: Vec2::new(0.0, 0.9), angle: 0.0, inv_mass: 1.0, inv_inertia: 2.0 },
        ];
        let row =
            PositionRow { body_a: 0, body_b: 1, geometry: PositionGeometry::Circles { radius_a: 0.5, radius_b: 0.5 } };
        let params = PositionParams { iterations: 100, ..Default::default() };
        correct_positions(&[row], &mut poses, &params);
        let (_, _, sep) = measure(&row, &poses);
        assert!(sep <= 0.0 && sep >= -3.0 * params.slop, "separation {sep}");
    }
}
