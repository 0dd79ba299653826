//! Scenes: seeded, deterministic descriptions of the bodies of a simulation (shapes, initial poses,
//! which bodies move), built before any physics runs.
//!
//! - `ball-box`: the thesis scene, N balls in a closed static box, initial positions from a 2D
//!   Gaussian around the centre with rejection of wall-near and overlapping samples;
//! - `drum`: the same box rotating about its centre at a set angular speed (kinematic walls);
//! - `mixed`: balls of several radii, boxes and regular polygons, with static obstacles inside the box.
//!
//! The box side defaults to `15 * sqrt(N / 100)` so that every N has the thesis scene's density; the
//! Gaussian's sigma scales with the side for the same reason (with the thesis's
//! `sqrt(15 / 2) * 1.2` at side 15, bit for bit).

use crate::error::SimError;
use crate::rng::{NumpyRandomState, Sampler, Xoshiro};
use std::str::FromStr;

/// Which scene to build.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneKind {
    /// Balls in a static box (the thesis scene).
    BallBox,
    /// Balls in a box rotating about its centre ("washing machine").
    Drum,
    /// Balls, boxes and polygons of several sizes with static obstacles inside the box.
    Mixed,
}

impl SceneKind {
    /// The scene's name on the command line and in messages.
    pub fn name(self) -> &'static str {
        match self {
            SceneKind::BallBox => "ball-box",
            SceneKind::Drum => "drum",
            SceneKind::Mixed => "mixed",
        }
    }
}

impl FromStr for SceneKind {
    type Err = SimError;
    fn from_str(s: &str) -> Result<Self, SimError> {
        match s {
            "ball-box" | "ballbox" | "balls" => Ok(SceneKind::BallBox),
            "drum" => Ok(SceneKind::Drum),
            "mixed" => Ok(SceneKind::Mixed),
            _ => Err(SimError::UnknownScene(s.to_string())),
        }
    }
}

/// Which random generator samples the initial world.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SamplerKind {
    /// xoshiro256++ (fast, the default).
    Native,
    /// numpy's legacy `RandomState(seed)`, reproducing the original Python code's worlds exactly.
    Numpy,
}

impl FromStr for SamplerKind {
    type Err = SimError;
    fn from_str(s: &str) -> Result<Self, SimError> {
        match s {
            "native" => Ok(SamplerKind::Native),
            "numpy" => Ok(SamplerKind::Numpy),
            _ => Err(SimError::UnknownSampler(s.to_string())),
        }
    }
}

/// Parameters of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneConfig {
    /// Which scene.
    pub kind: SceneKind,
    /// Number of dynamic bodies.
    pub n: usize,
    /// Seed of the initial world.
    pub seed: u64,
    /// Generator of the initial world.
    pub sampler: SamplerKind,
    /// Side of the square interior; `None`: `15 * sqrt(n / 100)`.
    pub side: Option<f32>,
    /// Ball radius (ball-box and drum).
    pub radius: f32,
    /// Density of every dynamic body.
    pub density: f32,
    /// Friction coefficient of every collider.
    pub friction: f32,
    /// Restitution of every collider (the solver has no restitution term: only 0 is supported).
    pub restitution: f32,
    /// Angular speed of the drum, rad/s (counter-clockwise).
    pub drum_omega: f32,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            kind: SceneKind::BallBox,
            n: 100,
            seed: 0,
            sampler: SamplerKind::Native,
            side: None,
            radius: 0.5,
            density: 1.0,
            friction: 0.5,
            restitution: 0.0,
            drum_omega: 1.0,
        }
    }
}

/// How a body moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BodyKind {
    /// Moved by gravity and contacts.
    Dynamic,
    /// Never moves (walls, obstacles).
    Static,
    /// Moved by a prescribed motion, unaffected by contacts (drum walls).
    Kinematic,
}

/// The shape of a body, in its local frame (centre of mass at the origin).
#[derive(Debug, Clone, PartialEq)]
pub enum ShapeSpec {
    /// A disc.
    Ball {
        /// Radius.
        radius: f32,
    },
    /// A rectangle.
    Cuboid {
        /// Half extents.
        half: [f32; 2],
    },
    /// A convex polygon, vertices counter-clockwise, centroid at the origin.
    Polygon {
        /// Vertices.
        vertices: Vec<[f32; 2]>,
    },
}

impl ShapeSpec {
    /// Radius of the smallest origin-centred disc holding the shape (for placement tests).
    pub fn bounding_radius(&self) -> f32 {
        match self {
            ShapeSpec::Ball { radius } => *radius,
            ShapeSpec::Cuboid { half } => (half[0] * half[0] + half[1] * half[1]).sqrt(),
            ShapeSpec::Polygon { vertices } => {
                vertices.iter().map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt()).fold(0.0, f32::max)
            }
        }
    }

    /// The `msgs::Shape` code and size fields of a body message.
    pub fn msg_shape(&self, kind: BodyKind) -> (msgs::Shape, [f32; 2]) {
        match (self, kind) {
            (ShapeSpec::Cuboid { half }, BodyKind::Static | BodyKind::Kinematic) => (msgs::Shape::Wall, *half),
            (ShapeSpec::Ball { radius }, _) => (msgs::Shape::Ball, [*radius, *radius]),
            (ShapeSpec::Cuboid { half }, _) => (msgs::Shape::Box, *half),
            (ShapeSpec::Polygon { .. }, _) => {
                let r = self.bounding_radius();
                (msgs::Shape::Polygon, [r, r])
            }
        }
    }
}

/// One body of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct BodySpec {
    /// How it moves.
    pub kind: BodyKind,
    /// Its shape.
    pub shape: ShapeSpec,
    /// Initial position of the centre of mass.
    pub position: [f32; 2],
    /// Initial orientation, radians.
    pub angle: f32,
}

/// A built scene: every body (dynamic ones first, so body id = index and dynamic ids are 0..n),
/// the box geometry, and the prescribed motion of kinematic bodies.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The configuration it was built from.
    pub config: SceneConfig,
    /// Side of the square interior, which spans (0, 0) to (side, side).
    pub side: f32,
    /// All bodies; the first `config.n` are dynamic.
    pub bodies: Vec<BodySpec>,
    /// Angular speed of kinematic bodies about `centre` (0 unless drum).
    pub omega: f32,
    /// Centre of the box, the drum's rotation axis.
    pub centre: [f32; 2],
}

/// Consecutive rejected samples after which placement gives up (as in the original code).
pub const MAX_TRIES: usize = 10_000;

/// Most dynamic bodies of a scene: 100x the largest benchmark case (10,000). A world costs about
/// 2.5 KB a body (rapier's bodies, colliders and broad phase, the contacts, measured at 100,000
/// bodies: 250 MB), so this bound keeps one simulation within ~2.5 GB.
pub const MAX_BODIES: usize = 1_000_000;

/// Largest box side. Positions are `f32`: at 4096 their spacing (2^-11, about 4.9e-4) reaches
/// the position pass's default slop (5e-4), so a larger box could not resolve its contacts. The
/// default side of [`MAX_BODIES`] bodies (1500) is well inside.
pub const MAX_SIDE: f32 = 4096.0;

/// Most cells of the placement grid (`(side / cell)^2`, a cell the diameter of the largest body,
/// an empty cell list 24 bytes): 400 MB, what the largest side takes with the default radius 0.5.
/// The grid depends on the side and the radius together, so it is estimated before it exists.
pub const MAX_PLACER_CELLS: f64 = (1u64 << 24) as f64;

impl SceneConfig {
    /// Side of the box interior for this configuration.
    pub fn side(&self) -> f32 {
        self.side.unwrap_or_else(|| 15.0 * (self.n as f32 / 100.0).sqrt())
    }

    /// Checks the parameters; called by [`Scene::build`].
    pub fn validate(&self) -> Result<(), SimError> {
        let bad =
            |name, value: String, why: &str| Err(SimError::InvalidParameter { name, value, why: why.to_string() });
        if self.n == 0 {
            return bad("n", self.n.to_string(), "at least one body");
        }
        if self.n > MAX_BODIES {
            return bad("n", self.n.to_string(), &format!("at most {MAX_BODIES} bodies (sim::scene::MAX_BODIES)"));
        }
        let side = self.side();
        if !(side.is_finite() && side > 0.0) {
            return bad("side", side.to_string(), "must be positive");
        }
        if side > MAX_SIDE {
            return bad(
                "side",
                side.to_string(),
                &format!("at most {MAX_SIDE} (sim::scene::MAX_SIDE: f32 positions get coarser than the contact slop)"),
            );
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return bad("radius", self.radius.to_string(), "must be positive");
        }
        if !(self.density.is_finite() && self.density > 0.0) {
            return bad("density", self.density.to_string(), "must be positive");
        }
        if !(self.friction.is_finite() && self.friction >= 0.0) {
            return bad("friction", self.friction.to_string(), "must be >= 0");
        }
        if self.restitution != 0.0 {
            return bad("restitution", self.restitution.to_string(), "only 0 is supported");
        }
        if !self.drum_omega.is_finite() {
            return bad("drum-omega", self.drum_omega.to_string(), "must be finite");
        }
        let cells = placer_cols(side, self.placer_radius()).powi(2);
        if cells > MAX_PLACER_CELLS {
            return bad(
                "side",
                side.to_string(),
                &format!(
                    "with bodies of radius {} the placement grid needs {cells:.3e} cells, more than \
                     {MAX_PLACER_CELLS:.3e} (sim::scene::MAX_PLACER_CELLS); use a smaller --side",
                    self.placer_radius()
                ),
            );
        }
        // Random close packing of discs covers ~82% of the plane; a Gaussian fill with rejection
        // gets nowhere near that, so refuse early rather than spin through MAX_TRIES.
        let r = self.typical_body_radius();
        let needed = self.n as f32 * std::f32::consts::PI * r * r;
        let interior = (side - 2.0 * r).max(0.0).powi(2);
        if needed > 0.5 * interior {
            return Err(SimError::SceneTooDense(format!(
                "{} bodies of radius up to {r} cover {needed:.1} of a {side}x{side} box's \
                 usable {interior:.1} (at most half can be filled); use a larger --side or a smaller --n",
                self.n
            )));
        }
        Ok(())
    }

    /// The largest bounding radius of the dynamic bodies: the placement grid's cells are its diameter.
    fn placer_radius(&self) -> f64 {
        match self.kind {
            SceneKind::Mixed => MIXED_MAX_RADIUS as f64,
            _ => self.radius as f64,
        }
    }

    /// A representative bounding radius of the dynamic bodies, for the density check.
    fn typical_body_radius(&self) -> f32 {
        match self.kind {
            SceneKind::Mixed => 0.5,
            _ => self.radius,
        }
    }
}

/// Largest bounding radius of a mixed-scene body (a 0.5 x 0.5 half-extent box).
const MIXED_MAX_RADIUS: f32 = 0.71;

/// The placement grid's cell size for bodies up to `max_radius`.
fn placer_cell(max_radius: f64) -> f64 {
    (2.0 * max_radius).max(1e-3)
}

/// Columns (and rows) of the placement grid of a `side` box, as a float: [`SceneConfig::validate`]
/// bounds it before [`Placer::new`] allocates it.
fn placer_cols(side: f32, max_radius: f64) -> f64 {
    (side as f64 / placer_cell(max_radius)).ceil().max(1.0)
}

/// Thickness of the box walls: thick enough that nothing crosses one in a step.
fn wall_half_thickness(side: f32) -> f32 {
    0.5 * (side / 15.0).max(2.0)
}

/// Gaussian placement with rejection, the original code's `fill` generalised to any bounding radii.
///
/// Reproduces `genworld_numpy.fill` exactly with the numpy sampler: the radii are drawn first
/// (`rand(n)`, even when they are all equal), each sample is cast to `f32`, the wall test runs on
/// `f32` differences compared in `f64`, the overlap test in `f64`. A uniform cell grid replaces the
/// all-pairs overlap test; it visits every body that could overlap, so the accept/reject decisions
/// are the same.
struct Placer {
    lo: [f32; 2],
    hi: [f32; 2],
    mu: [f64; 2],
    sigma: [f64; 2],
    cell: f64,
    cols: usize,
    grid: Vec<Vec<usize>>,
    placed: Vec<([f64; 2], f64)>,
}

impl Placer {
    fn new(side: f32, max_radius: f64) -> Placer {
        let lo = [0.0f32, 0.0];
        let hi = [side, side];
        let mu = [((hi[0] + lo[0]) / 2.0) as f64, ((hi[1] + lo[1]) / 2.0) as f64];
        // The thesis: sigma = sqrt((hi - lo) / 2) * 1.2 at side 15; scaled with the side beyond.
        let scale = (side / 15.0) as f64;
        let sigma = [
            (((hi[0] - lo[0]) / 2.0) as f64 / scale).sqrt() * 1.2 * scale,
            (((hi[1] - lo[1]) / 2.0) as f64 / scale).sqrt() * 1.2 * scale,
        ];
        let cell = placer_cell(max_radius);
        let cols = placer_cols(side, max_radius) as usize;
        Placer { lo, hi, mu, sigma, cell, cols, grid: vec![Vec::new(); cols * cols], placed: Vec::new() }
    }

    fn cell_of(&self, p: [f64; 2]) -> (usize, usize) {
        let c = ((p[0] / self.cell).floor().max(0.0) as usize).min(self.cols - 1);
        let r = ((p[1] / self.cell).floor().max(0.0) as usize).min(self.cols - 1);
        (c, r)
    }

    /// Whether a body of bounding radius `rad` fits at `p` (walls and earlier bodies).
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(a < b)` on purpose: NaN counts as overlapping
    fn fits(&self, p: [f32; 2], rad: f64) -> bool {
        let walls = [self.hi[0] - p[0], self.hi[1] - p[1], p[0] - self.lo[0], p[1] - self.lo[1]];
        if walls.iter().any(|&d| (d as f64) < rad) {
            return false;
        }
        let q = [p[0] as f64, p[1] as f64];
        let (c, r) = self.cell_of(q);
        for rr in r.saturating_sub(1)..=(r + 1).min(self.cols - 1) {
            for cc in c.saturating_sub(1)..=(c + 1).min(self.cols - 1) {
                for &j in &self.grid[rr * self.cols + cc] {
                    let (pj, rj) = self.placed[j];
                    let dx = pj[0] - q[0];
                    let dy = pj[1] - q[1];
                    let dist = (dx * dx + dy * dy).sqrt();
                    if !(rj + rad < dist) {
                        return false;
                    }
                }
            }
        }
        true
    }

    fn add(&mut self, p: [f32; 2], rad: f64) {
        let q = [p[0] as f64, p[1] as f64];
        let (c, r) = self.cell_of(q);
        self.grid[r * self.cols + c].push(self.placed.len());
        self.placed.push((q, rad));
    }

    /// Places one body of bounding radius `rad`; `None` after [`MAX_TRIES`] rejections in a row.
    fn place(&mut self, rng: &mut dyn Sampler, rad: f64) -> Option<[f32; 2]> {
        for _ in 0..=MAX_TRIES {
            let p = [rng.normal(self.mu[0], self.sigma[0]) as f32, rng.normal(self.mu[1], self.sigma[1]) as f32];
            if self.fits(p, rad) {
                self.add(p, rad);
                return Some(p);
            }
        }
        None
    }
}

fn too_dense(config: &SceneConfig, placed: usize) -> SimError {
    SimError::SceneTooDense(format!(
        "placed only {placed} of {} bodies in a {}x{} box before {MAX_TRIES} rejections in a row",
        config.n,
        config.side(),
        config.side()
    ))
}

fn walls(side: f32, kind: BodyKind) -> Vec<BodySpec> {
    let t = wall_half_thickness(side);
    let h = side / 2.0;
    let long = h + 2.0 * t;
    [([h, -t], [long, t]), ([h, side + t], [long, t]), ([-t, h], [t, long]), ([side + t, h], [t, long])]
        .into_iter()
        .map(|(position, half)| BodySpec { kind, shape: ShapeSpec::Cuboid { half }, position, angle: 0.0 })
        .collect()
}

/// A regular polygon of `k` vertices and circumradius `r`, counter-clockwise, centred at the origin.
fn regular_polygon(k: usize, r: f32) -> Vec<[f32; 2]> {
    (0..k)
        .map(|i| {
            let a = std::f32::consts::TAU * i as f32 / k as f32 + std::f32::consts::FRAC_PI_2;
            [r * a.cos(), r * a.sin()]
        })
        .collect()
}

/// The static obstacles of the mixed scene: two tilted shelves and a central peg.
fn mixed_obstacles(side: f32) -> Vec<BodySpec> {
    let s = side;
    vec![
        BodySpec {
            kind: BodyKind::Static,
            shape: ShapeSpec::Cuboid { half: [0.12 * s, 0.02 * s] },
            position: [0.25 * s, 0.35 * s],
            angle: -0.35,
        },
        BodySpec {
            kind: BodyKind::Static,
            shape: ShapeSpec::Cuboid { half: [0.12 * s, 0.02 * s] },
            position: [0.75 * s, 0.35 * s],
            angle: 0.35,
        },
        BodySpec {
            kind: BodyKind::Static,
            shape: ShapeSpec::Polygon { vertices: regular_polygon(3, 0.06 * s) },
            position: [0.5 * s, 0.18 * s],
            angle: 0.0,
        },
    ]
}

impl Scene {
    /// Body `id` as rapier's rigid body and collider (density, friction, no restitution), both
    /// carrying `id` as user data.
    pub fn rapier_body(&self, id: usize) -> (rapier2d::prelude::RigidBody, rapier2d::prelude::Collider) {
        use rapier2d::math::{Pose, Vec2};
        use rapier2d::prelude::{ColliderBuilder, RigidBodyBuilder};
        let spec = &self.bodies[id];
        let builder = match spec.kind {
            BodyKind::Dynamic => RigidBodyBuilder::dynamic(),
            BodyKind::Static => RigidBodyBuilder::fixed(),
            BodyKind::Kinematic => RigidBodyBuilder::kinematic_position_based(),
        };
        let rb = builder.pose(Pose::new(Vec2::from(spec.position), spec.angle)).user_data(id as u128).build();
        let collider = match &spec.shape {
            ShapeSpec::Ball { radius } => ColliderBuilder::ball(*radius),
            ShapeSpec::Cuboid { half } => ColliderBuilder::cuboid(half[0], half[1]),
            ShapeSpec::Polygon { vertices } => {
                ColliderBuilder::convex_polyline(vertices.iter().map(|v| Vec2::from(*v)).collect())
                    .expect("scene polygons are convex with at least 3 vertices")
            }
        }
        .density(self.config.density)
        .friction(self.config.friction)
        .restitution(0.0)
        .user_data(id as u128)
        .build();
        (rb, collider)
    }

    /// Builds the scene described by `config` (deterministic in the config).
    pub fn build(config: &SceneConfig) -> Result<Scene, SimError> {
        config.validate()?;
        let side = config.side();
        let mut rng: Box<dyn Sampler> = match config.sampler {
            SamplerKind::Numpy => {
                let seed = u32::try_from(config.seed).map_err(|_| SimError::InvalidParameter {
                    name: "seed",
                    value: config.seed.to_string(),
                    why: "the numpy sampler takes seeds in 0..2^32".into(),
                })?;
                Box::new(NumpyRandomState::new(seed))
            }
            SamplerKind::Native => Box::new(Xoshiro::new(config.seed)),
        };
        let mut bodies = Vec::with_capacity(config.n + 8);
        let (omega, wall_kind) = match config.kind {
            SceneKind::Drum => (config.drum_omega, BodyKind::Kinematic),
            _ => (0.0, BodyKind::Static),
        };
        match config.kind {
            SceneKind::BallBox | SceneKind::Drum => {
                // The original code draws the radii first: `min_r + rand(n) * (max_r - min_r)`.
                let r = config.radius as f64;
                // `max_r - min_r` is 0 here, but the draw must happen: it moves the generator.
                #[allow(clippy::eq_op)]
                let radii: Vec<f64> = (0..config.n).map(|_| r + rng.uniform() * (r - r)).collect();
                let mut placer = Placer::new(side, config.placer_radius());
                for (i, &rad) in radii.iter().enumerate() {
                    let p = placer.place(rng.as_mut(), rad).ok_or_else(|| too_dense(config, i))?;
                    bodies.push(BodySpec {
                        kind: BodyKind::Dynamic,
                        shape: ShapeSpec::Ball { radius: rad as f32 },
                        position: p,
                        angle: 0.0,
                    });
                }
                bodies.extend(walls(side, wall_kind));
            }
            SceneKind::Mixed => {
                let obstacles = mixed_obstacles(side);
                let mut placer = Placer::new(side, config.placer_radius());
                // Obstacles block placement through their bounding discs.
                for o in &obstacles {
                    placer.add(o.position, o.shape.bounding_radius() as f64);
                }
                for i in 0..config.n {
                    let pick = rng.uniform();
                    let size = 0.25 + 0.25 * rng.uniform() as f32;
                    let shape = if pick < 0.5 {
                        ShapeSpec::Ball { radius: size + 0.1 }
                    } else if pick < 0.75 {
                        let aspect = 0.5 + 0.5 * rng.uniform() as f32;
                        ShapeSpec::Cuboid { half: [size, size * aspect] }
                    } else {
                        let k = 3 + (rng.uniform() * 4.0) as usize; // 3..=6 vertices
                        ShapeSpec::Polygon { vertices: regular_polygon(k, size + 0.1) }
                    };
                    let angle = (std::f64::consts::TAU * rng.uniform()) as f32;
                    let rad = shape.bounding_radius() as f64;
                    let p = placer.place(rng.as_mut(), rad).ok_or_else(|| too_dense(config, i))?;
                    bodies.push(BodySpec { kind: BodyKind::Dynamic, shape, position: p, angle });
                }
                bodies.extend(walls(side, wall_kind));
                bodies.extend(obstacles);
            }
        }
        Ok(Scene { config: config.clone(), side, bodies, omega, centre: [side / 2.0, side / 2.0] })
    }

    /// Number of dynamic bodies (ids `0..n`).
    pub fn dynamic_count(&self) -> usize {
        self.config.n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ball_box_places_every_ball_inside_without_overlap() {
        let scene = Scene::build(&SceneConfig { seed: 3, ..Default::default() }).unwrap();
        let balls: Vec<_> = scene.bodies[..100].iter().map(|b| b.position).collect();
        for (i, p) in balls.iter().enumerate() {
            assert!(p[0] >= 0.5 && p[0] <= 14.5 && p[1] >= 0.5 && p[1] <= 14.5, "{p:?}");
            for q in &balls[..i] {
                let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
                assert!(d > 1.0, "overlap {p:?} {q:?}");
            }
        }
        assert_eq!(scene.bodies.len(), 104);
    }

    #[test]
    fn scaled_box_has_the_thesis_density() {
        let c = SceneConfig { n: 1000, ..Default::default() };
        assert!((c.side() - 15.0 * 10f32.sqrt()).abs() < 1e-4);
        let scene = Scene::build(&c).unwrap();
        assert_eq!(scene.dynamic_count(), 1000);
    }

    #[test]
    fn too_many_balls_for_the_box_is_a_clear_error() {
        let c = SceneConfig { n: 400, side: Some(15.0), ..Default::default() };
        let e = Scene::build(&c).unwrap_err();
        assert!(matches!(e, SimError::SceneTooDense(_)), "{e}");
        assert!(e.to_string().contains("--side"), "{e}");
    }

    #[test]
    fn counts_and_sizes_beyond_their_bounds_are_refused_before_allocating() {
        let e = Scene::build(&SceneConfig { n: 100_000_000, ..Default::default() }).unwrap_err();
        assert_eq!(e.to_string(), "invalid parameter `n` = 100000000: at most 1000000 bodies (sim::scene::MAX_BODIES)");
        for side in [1e6, 1e12, f32::MAX] {
            let e = Scene::build(&SceneConfig { side: Some(side), ..Default::default() }).unwrap_err();
            assert!(matches!(e, SimError::InvalidParameter { name: "side", .. }), "{e}");
            assert!(e.to_string().contains("at most 4096"), "{e}");
        }
        // The grid depends on side and radius together: tiny bodies in a legal box.
        let e = SceneConfig { radius: 1e-3, side: Some(4000.0), n: 10, ..Default::default() }.validate().unwrap_err();
        assert!(matches!(e, SimError::InvalidParameter { name: "side", .. }), "{e}");
        assert!(e.to_string().contains("MAX_PLACER_CELLS"), "{e}");
        // The bounds themselves are usable.
        assert!(SceneConfig { n: MAX_BODIES, ..Default::default() }.validate().is_ok());
        assert!(SceneConfig { side: Some(MAX_SIDE), ..Default::default() }.validate().is_ok());
    }

    #[test]
    fn unknown_scene_is_a_clear_error() {
        let e = "washer".parse::<SceneKind>().unwrap_err();
        assert_eq!(e.to_string(), "unknown scene `washer` (known: ball-box, drum, mixed)");
    }

    #[test]
    fn mixed_scene_has_several_shapes_and_obstacles() {
        let scene = Scene::build(&SceneConfig { kind: SceneKind::Mixed, ..Default::default() }).unwrap();
        let dynamic = &scene.bodies[..100];
        assert!(dynamic.iter().any(|b| matches!(b.shape, ShapeSpec::Ball { .. })));
        assert!(dynamic.iter().any(|b| matches!(b.shape, ShapeSpec::Cuboid { .. })));
        assert!(dynamic.iter().any(|b| matches!(b.shape, ShapeSpec::Polygon { .. })));
        let statics = scene.bodies.iter().filter(|b| b.kind == BodyKind::Static).count();
        assert_eq!(statics, 4 + 3);
    }
}
