//! The simulated world: body states (ours), rapier2d for shapes, broad and narrow phase, our
//! contact solver for the dynamics.
//!
//! One step, Box2D 2.3's order (`b2Island::Solve`):
//! 1. collision detection on the current poses (rapier's `CollisionPipeline`) -> contact points,
//!    sorted by [`ContactKey`] so that Gauss-Seidel visits them in an order independent of rapier's
//!    internal storage;
//! 2. `v += dt * g` for dynamic bodies;
//! 3. a warm start for every contact from the active model (or its fallback);
//! 4. the velocity solve to tolerance from that warm start;
//! 5. `x += dt * v`, `angle += dt * omega` (Box2D's per-step translation/rotation caps);
//! 6. the position pass; the new poses go back to rapier for the next detection.
//!
//! Our body states are the source of truth; rapier only mirrors poses. Everything that affects the
//! physics is iterated in sorted order, so a run is bit-identical given the same scene and models.

use crate::contact::{feature_key, ContactKey, ContactPoint, ImpulseHistory, SolveTrail};
use crate::error::SimError;
use crate::problem::Problem;
use crate::scene::{BodyKind, Scene, SceneConfig, ShapeSpec};
use crate::solver::{
    correct_positions, rotate, ContactRow, ContactSolver, Impulse, PoseBody, PositionGeometry, PositionParams,
    PositionRow, SolveParams, SolveReport, SolverBody,
};
use crate::warm::{ModelKind, WarmStartInput, WarmStarter};
use msgs::{ProblemBody, ProblemContact, ProblemHeader, StepStats};
use rapier2d::math::{Pose, Vec2};
use rapier2d::prelude::{ColliderBuilder, PhysicsWorld, RigidBodyBuilder, RigidBodyHandle};
use std::time::Instant;

/// Parameters of the time stepping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldParams {
    /// Time step, seconds.
    pub dt: f32,
    /// Gravity.
    pub gravity: [f32; 2],
    /// Velocity solve stopping rule.
    pub solve: SolveParams,
    /// The oracle's stopping rule (`copy` and the ablations): solved from builtin's warm start to
    /// a tolerance far below the run's, so that `copy` needs ~0 sweeps. 2e-6, not lower: the
    /// impulses are f32, and a sweep's change stalls near their resolution on deep piles.
    pub oracle: SolveParams,
    /// Position pass parameters.
    pub position: PositionParams,
    /// rapier's prediction distance: manifolds are kept this far apart, so features are tracked
    /// while contacts open and close.
    pub prediction: f32,
    /// A manifold point becomes a contact row when its signed distance is at most this (0: touching
    /// or overlapping, as Box2D's discs; a positive margin would stop bodies short of touching).
    pub contact_margin: f32,
    /// Largest translation of a body in one step (`b2_maxTranslation`).
    pub max_translation: f32,
    /// Largest rotation of a body in one step (`b2_maxRotation`).
    pub max_rotation: f32,
}

impl Default for WorldParams {
    fn default() -> Self {
        WorldParams {
            dt: 1.0 / 100.0,
            gravity: [0.0, -9.81],
            solve: SolveParams::default(),
            oracle: SolveParams { tolerance: 2e-6, max_sweeps: 10_000, ..SolveParams::default() },
            position: PositionParams::default(),
            prediction: 0.02,
            contact_margin: 0.0,
            max_translation: 2.0,
            max_rotation: 0.5 * std::f32::consts::PI,
        }
    }
}

impl WorldParams {
    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad =
            |name, value: String, why: &str| Err(SimError::InvalidParameter { name, value, why: why.to_string() });
        if !(self.solve.tolerance.is_finite() && self.solve.tolerance > 0.0) {
            return bad("tolerance", self.solve.tolerance.to_string(), "must be > 0");
        }
        if self.solve.max_sweeps == 0 {
            return bad("max-sweeps", "0".into(), "must be >= 1");
        }
        for c in [self.solve.compliance, self.oracle.compliance] {
            if !SolveParams::valid_compliance(c) {
                return bad("compliance", c.to_string(), &format!("must be {}", SolveParams::compliance_range()));
            }
        }
        for w in [self.solve.relaxation, self.oracle.relaxation] {
            if !SolveParams::valid_relaxation(w) {
                return bad("relaxation", w.to_string(), &format!("must be {}", SolveParams::relaxation_range()));
            }
        }
        if !(self.oracle.tolerance.is_finite() && self.oracle.tolerance > 0.0) || self.oracle.max_sweeps == 0 {
            return bad("oracle", format!("{:?}", self.oracle), "tolerance > 0 and max sweeps >= 1");
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return bad("dt", self.dt.to_string(), "must be > 0");
        }
        if !(self.position.slop >= 0.0 && self.position.baumgarte >= 0.0 && self.position.baumgarte <= 1.0) {
            return bad("baumgarte/slop", format!("{:?}", self.position), "baumgarte in [0, 1], slop >= 0");
        }
        Ok(())
    }
}

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
    fn inv_mass(&self) -> f32 {
        if self.mass > 0.0 {
            1.0 / self.mass
        } else {
            0.0
        }
    }
    fn inv_inertia(&self) -> f32 {
        if self.inertia > 0.0 {
            1.0 / self.inertia
        } else {
            0.0
        }
    }
}

/// A simulation: scene, body states, rapier's collision structures, the solver and its buffers.
pub struct World {
    scene: Scene,
    params: WorldParams,
    bodies: Vec<BodyState>,
    rapier: PhysicsWorld,
    handles: Vec<RigidBodyHandle>,
    /// Per body: infinite mass (static or kinematic).
    fixed: Vec<bool>,
    step: u32,
    run_id: u64,
    simulation: u32,
    // Per-step buffers, reused.
    contacts: Vec<ContactPoint>,
    rows: Vec<ContactRow>,
    position_rows: Vec<PositionRow>,
    solver_bodies: Vec<SolverBody>,
    scratch_bodies: Vec<SolverBody>,
    poses: Vec<PoseBody>,
    warm: Vec<Impulse>,
    solver: ContactSolver,
    oracle_solver: ContactSolver,
    history: ImpulseHistory,
    staging: Vec<(ContactKey, ContactPoint, PositionRow)>,
    stats: StepStats,
    min_separation: f32,
    oracle_report: Option<SolveReport>,
    /// Capture each step's velocity problem (and solve a reference with these parameters).
    capture: Option<Capture>,
    /// Also solve each step from builtin's warm start (see [`World::shadow_builtin`]).
    shadow_on: bool,
    shadow_warm: Vec<Impulse>,
    problem: Problem,
}

/// What [`World::capture_problems`] asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Capture {
    /// The reference solve's stopping rule (from builtin's warm start), if labelled.
    reference: Option<SolveParams>,
}

impl World {
    /// Builds the scene of `config` and a world that simulates it with `params`.
    pub fn new(config: &SceneConfig, params: WorldParams) -> Result<World, SimError> {
        params.validate()?;
        let scene = Scene::build(config)?;
        Ok(World::from_scene(scene, params))
    }

    /// A world simulating an already built scene (tests build custom scenes this way).
    pub fn from_scene(scene: Scene, params: WorldParams) -> World {
        let mut rapier = PhysicsWorld::new();
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        let mut handles = Vec::with_capacity(scene.bodies.len());
        let friction = scene.config.friction;
        for (id, spec) in scene.bodies.iter().enumerate() {
            let builder = match spec.kind {
                BodyKind::Dynamic => RigidBodyBuilder::dynamic(),
                BodyKind::Static => RigidBodyBuilder::fixed(),
                BodyKind::Kinematic => RigidBodyBuilder::kinematic_position_based(),
            };
            let pose = Pose::new(Vec2::from(spec.position), spec.angle);
            let rb = builder.pose(pose).user_data(id as u128).build();
            let collider = match &spec.shape {
                ShapeSpec::Ball { radius } => ColliderBuilder::ball(*radius),
                ShapeSpec::Cuboid { half } => ColliderBuilder::cuboid(half[0], half[1]),
                ShapeSpec::Polygon { vertices } => {
                    ColliderBuilder::convex_polyline(vertices.iter().map(|v| Vec2::from(*v)).collect())
                        .expect("scene polygons are convex with at least 3 vertices")
                }
            }
            .density(scene.config.density)
            .friction(friction)
            .restitution(0.0)
            .user_data(id as u128)
            .build();
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
        let fixed = bodies.iter().map(|b| b.mass == 0.0).collect();
        let mut world = World {
            scene,
            params,
            bodies,
            rapier,
            handles,
            fixed,
            step: 0,
            run_id: 0,
            simulation: 0,
            contacts: Vec::new(),
            rows: Vec::new(),
            position_rows: Vec::new(),
            solver_bodies: Vec::new(),
            scratch_bodies: Vec::new(),
            poses: Vec::new(),
            warm: Vec::new(),
            solver: ContactSolver::new(),
            oracle_solver: ContactSolver::new(),
            history: ImpulseHistory::default(),
            staging: Vec::new(),
            stats: StepStats::default(),
            min_separation: 0.0,
            oracle_report: None,
            capture: None,
            shadow_on: false,
            shadow_warm: Vec::new(),
            problem: Problem::default(),
        };
        world.set_kinematic_state(0.0);
        world.sync_rapier();
        world
    }

    /// From the next step on, also solve each step from builtin's warm start on scratch
    /// velocities (not part of the step's time): the step statistics' `builtin_sweeps`.
    pub fn shadow_builtin(&mut self, on: bool) {
        self.shadow_on = on;
    }

    /// From the next step on, capture each step's velocity problem before solving it
    /// ([`World::problem`]); with `reference`, also solve it from builtin's warm start with those
    /// parameters (the label a learned model trains on; outside the step's timings).
    pub fn capture_problems(&mut self, reference: Option<SolveParams>) {
        self.capture = Some(Capture { reference });
    }

    /// The velocity problem of the last step, when capturing.
    pub fn problem(&self) -> Option<&Problem> {
        self.capture.is_some().then_some(&self.problem)
    }

    /// Labels the messages and grid requests of this world (run id and simulation index).
    pub fn set_ids(&mut self, run_id: u64, simulation: u32) {
        self.run_id = run_id;
        self.simulation = simulation;
    }

    /// The scene simulated.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The stepping parameters.
    pub fn params(&self) -> &WorldParams {
        &self.params
    }

    /// Body states (index = body id).
    pub fn bodies(&self) -> &[BodyState] {
        &self.bodies
    }

    /// Steps taken so far.
    pub fn steps_taken(&self) -> u32 {
        self.step
    }

    /// Contacts of the last step (sorted by key).
    pub fn contacts(&self) -> &[ContactPoint] {
        &self.contacts
    }

    /// Final impulses of the last step, one per contact.
    pub fn impulses(&self) -> &[Impulse] {
        self.solver.impulses()
    }

    /// Warm start used in the last step, one per contact.
    pub fn warm_start_used(&self) -> &[Impulse] {
        &self.warm
    }

    /// Residual after every sweep of the last solve.
    pub fn residuals(&self) -> &[f32] {
        self.solver.residuals()
    }

    /// Velocity-solver rows of the last step (for independent checks of the solution).
    pub fn rows(&self) -> &[ContactRow] {
        &self.rows
    }

    /// The solver's view of the bodies after the last velocity solve (before position integration).
    pub fn solver_bodies(&self) -> &[SolverBody] {
        &self.solver_bodies
    }

    /// Report of the oracle's solve (from builtin's warm start) in the last step, if the model
    /// asked for it (`copy`, the ablations).
    pub fn oracle_report(&self) -> Option<SolveReport> {
        self.oracle_report
    }

    /// Statistics of the last step (what `stats/solve` carries).
    pub fn stats(&self) -> &StepStats {
        &self.stats
    }

    /// Smallest separation after the last step's position pass (negative: overlap).
    pub fn min_separation(&self) -> f32 {
        self.min_separation
    }

    /// Kinetic energy (linear + rotational) and largest speed of the dynamic bodies.
    pub fn motion(&self) -> (f32, f32) {
        let (mut energy, mut max_speed) = (0.0f64, 0.0f32);
        for b in self.bodies.iter().filter(|b| b.kind == BodyKind::Dynamic) {
            energy += 0.5 * b.mass as f64 * b.v.length_squared() as f64 + 0.5 * b.inertia as f64 * (b.w as f64).powi(2);
            max_speed = max_speed.max(b.v.length());
        }
        (energy as f32, max_speed)
    }

    /// Total mechanical energy of the dynamic bodies: kinetic, rotational and gravitational
    /// (zero potential at y = 0).
    pub fn energy(&self) -> f64 {
        let g = Vec2::from(self.params.gravity);
        self.bodies
            .iter()
            .filter(|b| b.kind == BodyKind::Dynamic)
            .map(|b| {
                let m = b.mass as f64;
                0.5 * m * b.v.length_squared() as f64 + 0.5 * b.inertia as f64 * (b.w as f64).powi(2)
                    - m * g.dot(b.x) as f64
            })
            .sum()
    }

    /// Prescribed pose and velocity of the kinematic bodies at time `t` (rotation about the centre).
    fn set_kinematic_state(&mut self, t: f64) {
        let omega = self.scene.omega;
        let c = Vec2::from(self.scene.centre);
        let theta = (omega as f64 * t) as f32;
        for b in self.bodies.iter_mut().filter(|b| b.kind == BodyKind::Kinematic) {
            b.x = c + rotate(theta, b.x0 - c);
            b.angle = b.angle0 + theta;
            let r = b.x - c;
            b.v = Vec2::new(-omega * r.y, omega * r.x);
            b.w = omega;
        }
    }

    /// Mirrors the poses of moving bodies into rapier (marks them modified for the narrow phase).
    fn sync_rapier(&mut self) {
        for (b, h) in self.bodies.iter().zip(&self.handles) {
            if b.kind == BodyKind::Static {
                continue;
            }
            if let Some(rb) = self.rapier.bodies.get_mut(*h) {
                rb.set_position(Pose::new(b.x, b.angle), true);
            }
        }
    }

    /// Runs rapier's collision detection and gathers the contact points, sorted by key.
    fn detect_contacts(&mut self) {
        let r = &mut self.rapier;
        r.collision_pipeline.step(
            self.params.prediction,
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
            let (b1, b2) = (&self.bodies[id1 as usize], &self.bodies[id2 as usize]);
            if b1.mass == 0.0 && b2.mass == 0.0 {
                continue;
            }
            // Canonical order: a is the lower id, so keys do not depend on rapier's pair order.
            let swap = id1 > id2;
            let (ia, ib) = if swap { (id2, id1) } else { (id1, id2) };
            let (ba, bb) = (&self.bodies[ia as usize], &self.bodies[ib as usize]);
            for manifold in pair.manifolds() {
                let friction = manifold.data.friction;
                let (ln_a, ln_b) =
                    if swap { (manifold.local_n2, manifold.local_n1) } else { (manifold.local_n1, manifold.local_n2) };
                let normal = if swap { -manifold.data.normal } else { manifold.data.normal };
                for p in &manifold.points {
                    if p.dist > self.params.contact_margin {
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
                    let geometry = match (&ba.shape, &bb.shape) {
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
                    };
                    self.staging.push((key, point, PositionRow { body_a: ia, body_b: ib, geometry }));
                }
            }
        }
        // Stable sort: equal keys (never expected for convex shapes) keep rapier's order.
        self.staging.sort_by_key(|a| a.0);
        self.contacts.clear();
        self.position_rows.clear();
        self.contacts.extend(self.staging.iter().map(|s| s.1));
        self.position_rows.extend(self.staging.iter().map(|s| s.2));
    }

    /// Fills [`World::problem`] from the current rows, bodies and history.
    fn capture_problem(&mut self, capture: Capture) {
        let p = &mut self.problem;
        p.bodies.clear();
        p.bodies.extend(self.solver_bodies.iter().map(|b| ProblemBody {
            v: b.v.into(),
            w: b.w,
            inv_mass: b.inv_mass,
            inv_inertia: b.inv_inertia,
        }));
        p.contacts.clear();
        for (c, r) in self.contacts.iter().zip(&self.rows) {
            let pair = |i: Option<Impulse>| i.map_or([0.0; 2], |i| [i.normal, i.tangent]);
            p.contacts.push(ProblemContact {
                body_a: r.body_a,
                body_b: r.body_b,
                feature: c.key.feature,
                age: self.history.age(&c.key),
                ra: r.ra.into(),
                rb: r.rb.into(),
                normal: r.normal.into(),
                friction: r.friction,
                penetration: c.penetration,
                previous: pair(self.history.previous(&c.key)),
                before_previous: pair(self.history.before_previous(&c.key)),
                reference: [f32::NAN; 2],
            });
        }
        p.header = ProblemHeader {
            step: msgs::StepHeader { run_id: self.run_id, simulation: self.simulation, step: self.step },
            bodies: p.bodies.len() as u32,
            tolerance: self.params.solve.tolerance,
            max_sweeps: self.params.solve.max_sweeps,
            compliance: self.params.solve.compliance,
            relaxation: self.params.solve.relaxation,
            ..ProblemHeader::default()
        };
        if let Some(params) = capture.reference {
            self.scratch_bodies.clear();
            self.scratch_bodies.extend_from_slice(&self.solver_bodies);
            let start = crate::problem::builtin_warm_start(&p.contacts);
            let report = self.oracle_solver.solve(&self.rows, &mut self.scratch_bodies, &start, &params);
            for (c, l) in p.contacts.iter_mut().zip(self.oracle_solver.impulses()) {
                c.reference = [l.normal, l.tangent];
            }
            p.header.reference_tolerance = params.tolerance;
            p.header.reference_sweeps = report.sweeps;
            p.header.reference_converged = report.converged as u32;
        }
    }

    /// Advances the world by one step, taking the warm start from `warm`.
    pub fn step(&mut self, warm: &mut WarmStarter) -> &StepStats {
        let t_step = Instant::now();
        let dt = self.params.dt;
        self.detect_contacts();

        // Velocities after external forces (kinematic bodies carry their prescribed velocity).
        let g = Vec2::from(self.params.gravity);
        self.solver_bodies.clear();
        for b in &self.bodies {
            let v = if b.kind == BodyKind::Dynamic { b.v + g * dt } else { b.v };
            self.solver_bodies.push(SolverBody { v, w: b.w, inv_mass: b.inv_mass(), inv_inertia: b.inv_inertia() });
        }
        self.rows.clear();
        for (c, pr) in self.contacts.iter().zip(&self.position_rows) {
            let (a, b) = (&self.bodies[pr.body_a as usize], &self.bodies[pr.body_b as usize]);
            self.rows.push(ContactRow {
                body_a: pr.body_a,
                body_b: pr.body_b,
                ra: c.point - a.x,
                rb: c.point - b.x,
                normal: c.normal,
                friction: c.friction,
            });
        }

        // The problem as data, before anything changes the velocities (not part of the step's time).
        let t_capture = Instant::now();
        if let Some(capture) = self.capture {
            self.capture_problem(capture);
        }
        let model_reads_problem = warm.wants_problem();
        let capture_time = t_capture.elapsed();

        // Warm start.
        let t_warm = Instant::now();
        // A model that reads the problem gets it as part of its own time (when the run does not
        // capture problems anyway).
        if model_reads_problem && self.capture.is_none() {
            self.capture_problem(Capture { reference: None });
        }
        self.warm.clear();
        self.warm.resize(self.contacts.len(), Impulse::default());
        self.oracle_report = None;
        let fallback = {
            let oracle_report = &mut self.oracle_report;
            let rows = &self.rows;
            let bodies = &self.solver_bodies;
            let scratch = &mut self.scratch_bodies;
            let oracle_solver = &mut self.oracle_solver;
            let solve = self.params.oracle;
            let (contacts, history) = (&self.contacts, &self.history);
            let mut oracle = |out: &mut [Impulse]| {
                scratch.clear();
                scratch.extend_from_slice(bodies);
                // From builtin's warm start, written where the answer goes.
                history.fill_previous(contacts, out);
                *oracle_report = Some(oracle_solver.solve(rows, scratch, out, &solve));
                out.copy_from_slice(oracle_solver.impulses());
            };
            let mut input = WarmStartInput {
                run_id: self.run_id,
                simulation: self.simulation,
                step: self.step,
                contacts: &self.contacts,
                history: &self.history,
                fixed: &self.fixed,
                problem: model_reads_problem.then_some(&self.problem),
                rows,
                bodies,
                compliance: self.params.solve.compliance,
                oracle: &mut oracle,
            };
            warm.warm_start(&mut input, &mut self.warm)
        };
        let warm_start_us = t_warm.elapsed().as_secs_f32() * 1e6;
        let used = if fallback { warm.fallback.name() } else { warm.model.name() };
        // builtin on this same problem, when asked (a builtin step is its own answer); not part
        // of the step's time.
        let t_shadow = Instant::now();
        let shadow = (self.shadow_on && used != ModelKind::Builtin.name()).then(|| {
            self.shadow_warm.clear();
            self.shadow_warm.resize(self.contacts.len(), Impulse::default());
            self.history.fill_previous(&self.contacts, &mut self.shadow_warm);
            self.scratch_bodies.clear();
            self.scratch_bodies.extend_from_slice(&self.solver_bodies);
            self.oracle_solver.solve(&self.rows, &mut self.scratch_bodies, &self.shadow_warm, &self.params.solve).sweeps
        });
        let shadow_time = t_shadow.elapsed();

        // Velocity solve.
        let t_solve = Instant::now();
        let report = self.solver.solve(&self.rows, &mut self.solver_bodies, &self.warm, &self.params.solve);
        let solve_us = t_solve.elapsed().as_secs_f32() * 1e6;
        let builtin_sweeps = self.shadow_on.then(|| shadow.unwrap_or(report.sweeps));

        // Integrate positions (dynamic bodies; kinematic ones follow their prescribed motion).
        self.poses.clear();
        for (b, sb) in self.bodies.iter_mut().zip(&self.solver_bodies) {
            if b.kind == BodyKind::Dynamic {
                let mut v = sb.v;
                let mut w = sb.w;
                let tr = v * dt;
                if tr.length_squared() > self.params.max_translation * self.params.max_translation {
                    v *= self.params.max_translation / tr.length();
                }
                if (w * dt).abs() > self.params.max_rotation {
                    w *= self.params.max_rotation / (w * dt).abs();
                }
                b.v = v;
                b.w = w;
                b.x += v * dt;
                b.angle += w * dt;
            }
            self.poses.push(PoseBody { x: b.x, angle: b.angle, inv_mass: sb.inv_mass, inv_inertia: sb.inv_inertia });
        }
        self.step += 1;
        let t_next = self.step as f64 * dt as f64;
        if self.scene.omega != 0.0 {
            self.set_kinematic_state(t_next);
            for (p, b) in self.poses.iter_mut().zip(&self.bodies) {
                if b.kind == BodyKind::Kinematic {
                    p.x = b.x;
                    p.angle = b.angle;
                }
            }
        }

        // Position pass, then mirror the poses into rapier for the next detection.
        let min_separation = correct_positions(&self.position_rows, &mut self.poses, &self.params.position);
        for (b, p) in self.bodies.iter_mut().zip(&self.poses) {
            if b.kind == BodyKind::Dynamic {
                b.x = p.x;
                b.angle = p.angle;
            }
        }
        self.sync_rapier();

        // Statistics and history.
        let final_impulses = self.solver.impulses();
        let persisting = self.contacts.iter().filter(|c| self.history.previous(&c.key).is_some()).count();
        let (mut n_mse, mut n_max, mut t_mse, mut t_max) = (0.0f64, 0.0f32, 0.0f64, 0.0f32);
        for (w, f) in self.warm.iter().zip(final_impulses) {
            let dn = w.normal - f.normal;
            let dtn = w.tangent - f.tangent;
            n_mse += (dn as f64).powi(2);
            t_mse += (dtn as f64).powi(2);
            n_max = n_max.max(dn.abs());
            t_max = t_max.max(dtn.abs());
        }
        let count = self.contacts.len().max(1) as f64;
        let trail = SolveTrail { changes: self.solver.trail(), rate: self.solver.convergence_rate() };
        self.history.push(self.contacts.iter().map(|c| c.key), final_impulses, trail);
        // The names' strings are reused from step to step (no allocation on the step path).
        let (mut model, mut used_model) =
            (std::mem::take(&mut self.stats.model), std::mem::take(&mut self.stats.used_model));
        model.clear();
        model.push_str(warm.model.name());
        used_model.clear();
        used_model.push_str(used);
        self.stats = StepStats {
            run_id: self.run_id,
            simulation: self.simulation,
            step: self.step - 1,
            model,
            used_model,
            contacts: self.contacts.len() as u32,
            persisting_contacts: persisting as u32,
            sweeps: report.sweeps,
            converged: report.converged,
            fallback,
            fallbacks_total: warm.fallbacks_total(),
            final_residual: report.final_residual,
            warm_error_normal_mse: (n_mse / count) as f32,
            warm_error_normal_max: n_max,
            warm_error_tangent_mse: (t_mse / count) as f32,
            warm_error_tangent_max: t_max,
            solve_us,
            warm_start_us,
            step_us: t_step.elapsed().saturating_sub(capture_time + shadow_time).as_secs_f32() * 1e6,
            kinetic_energy: 0.0,
            max_speed: 0.0,
            builtin_sweeps: builtin_sweeps.unwrap_or(0),
            builtin_measured: builtin_sweeps.is_some(),
        };
        self.min_separation = min_separation;
        // Measured after the step's timer stopped: bookkeeping, not simulation.
        (self.stats.kinetic_energy, self.stats.max_speed) = self.motion();
        &self.stats
    }

    /// The bodies as messages.
    pub fn body_msgs(&self, out: &mut Vec<msgs::Body>) {
        out.clear();
        out.extend(self.bodies.iter().enumerate().map(|(id, b)| {
            let (shape, size) = b.shape.msg_shape(b.kind);
            msgs::Body {
                id: id as u32,
                shape: shape as u32,
                size,
                mass: b.mass,
                inertia: b.inertia,
                x: b.x.x,
                y: b.x.y,
                angle: b.angle,
                vx: b.v.x,
                vy: b.v.y,
                omega: b.w,
            }
        }));
    }

    /// The last step's contacts with their final impulses, as messages.
    pub fn contact_msgs(&self, out: &mut Vec<msgs::Contact>) {
        out.clear();
        out.extend(self.contacts.iter().zip(self.solver.impulses()).map(|(c, l)| msgs::Contact {
            body_a: c.key.body_a,
            body_b: c.key.body_b,
            feature: c.key.feature,
            x: c.point.x,
            y: c.point.y,
            nx: c.normal.x,
            ny: c.normal.y,
            penetration: c.penetration,
            friction: c.friction,
            normal_impulse: l.normal,
            tangent_impulse: l.tangent,
        }));
    }
}
