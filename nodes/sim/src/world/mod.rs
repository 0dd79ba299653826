//! The simulated world: body states (ours), rapier2d for shapes and collision detection, our
//! contact solver for the dynamics.
//!
//! One step, Box2D 2.3's order (`b2Island::Solve`), each stage a method of [`World::step`]:
//! 1. collide: collision detection on the current poses ([`collide`]) -> contact points, sorted
//!    by [`ContactKey`](crate::ContactKey) so that Gauss-Seidel visits them in an order
//!    independent of rapier's internal storage;
//! 2. external forces: `v += dt * g` for dynamic bodies, the solver's rows;
//! 3. warm start: an impulse for every contact from the active model (or its fallback);
//! 4. solve: the velocity solve to tolerance from that warm start;
//! 5. integrate: `x += dt * v`, `angle += dt * omega` (Box2D's per-step translation/rotation caps);
//! 6. correct positions: the position pass; the new poses go back to rapier for the next
//!    detection.
//!
//! Measurement (the oracle's exact solve, the shadow builtin solve, problem capture) lives in
//! [`instruments`]; the stages call it, outside the step's timings except where a model reads it.
//!
//! Our body states are the source of truth; rapier only mirrors poses. Everything that affects the
//! physics is iterated in sorted order, so a run is bit-identical given the same scene and models.

mod collide;
mod instruments;
mod params;

pub use crate::body::BodyState;
pub use instruments::MenuSolve;
pub use params::WorldParams;

use crate::contact::{ContactPoint, ImpulseHistory, SolveTrail};
use crate::error::SimError;
use crate::problem::{per_step_bound, Problem};
use crate::scene::{BodyKind, Scene, SceneConfig};
use crate::solver::position::rotate;
use crate::solver::{
    correct_positions, ContactRow, ContactSolver, Impulse, PoseBody, PositionRow, SolveParams, SolveReport, SolverBody,
};
use crate::warm::{ModelKind, SolvedStep, StepRows, WarmStartInput, WarmStarter};
use collide::Collision;
use instruments::{Instruments, StepView};
use msgs::StepStats;
use rapier2d::math::Vec2;
use std::time::Instant;

/// The step as the instruments read it, borrowed field by field (so the instruments themselves
/// can be borrowed mutably beside it).
macro_rules! step_view {
    ($world:expr) => {
        StepView {
            header: msgs::StepHeader { run_id: $world.run_id, simulation: $world.simulation, step: $world.step },
            contacts: &$world.contacts,
            rows: &$world.rows,
            bodies: &$world.solver_bodies,
            history: &$world.history,
        }
    };
}

/// A simulation: scene, body states, rapier's collision structures, the solver and its buffers.
pub struct World {
    scene: Scene,
    params: WorldParams,
    bodies: Vec<BodyState>,
    collision: Collision,
    step: u32,
    run_id: u64,
    simulation: u32,
    // Per-step buffers, reused.
    contacts: Vec<ContactPoint>,
    rows: Vec<ContactRow>,
    position_rows: Vec<PositionRow>,
    solver_bodies: Vec<SolverBody>,
    poses: Vec<PoseBody>,
    warm: Vec<Impulse>,
    solver: ContactSolver,
    history: ImpulseHistory,
    stats: StepStats,
    min_separation: f32,
    instruments: Instruments,
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
        let (collision, bodies) = Collision::new(&scene);
        let mut world = World {
            scene,
            params,
            bodies,
            collision,
            step: 0,
            run_id: 0,
            simulation: 0,
            contacts: Vec::new(),
            rows: Vec::new(),
            position_rows: Vec::new(),
            solver_bodies: Vec::new(),
            poses: Vec::new(),
            warm: Vec::new(),
            solver: ContactSolver::new(),
            history: ImpulseHistory::default(),
            stats: StepStats::default(),
            min_separation: 0.0,
            instruments: Instruments::default(),
        };
        world.set_kinematic_state(0.0);
        world.collision.mirror_poses(&world.bodies);
        world
    }

    /// From the next step on, also solve each step from builtin's warm start on scratch
    /// velocities (not part of the step's time): the step statistics' `builtin_sweeps`.
    pub fn shadow_builtin(&mut self, on: bool) {
        self.instruments.shadow_builtin = on;
    }

    /// From the next step on, also split each step's warm-start error against the step's exact
    /// solution, beside builtin's on the same step (not part of the step's time): the step
    /// statistics' `split_*` fields, [`World::last_split`].
    pub fn error_split(&mut self, on: bool) {
        self.instruments.error_split = on;
    }

    /// The last step's warm-start error split, when splitting (none for a step without contacts).
    pub fn last_split(&self) -> Option<&msgs::ErrorSplit> {
        self.instruments.split()
    }

    /// From the next step on, solve with `setting` (the rest of the stopping rule unchanged): a
    /// per-step choice of solver.
    pub fn set_solver(&mut self, setting: crate::solver::SolverSetting) {
        self.params.solve = self.params.solve.with_setting(setting);
    }

    /// From the next step on, also solve each step with every solver of `menu` from builtin's
    /// warm start, on scratch velocities and outside the step's time ([`World::menu_solves`]).
    pub fn solver_menu(&mut self, menu: Vec<SolveParams>) {
        self.instruments.menu = menu;
    }

    /// The last step's solves by the menu's solvers, in the menu's order.
    pub fn menu_solves(&self) -> &[MenuSolve] {
        self.instruments.menu_solves()
    }

    /// From the next step on, capture each step's velocity problem before solving it
    /// ([`World::problem`]); with `reference`, also solve it from builtin's warm start with those
    /// parameters (the label a learned model trains on; outside the step's timings).
    pub fn capture_problems(&mut self, reference: Option<SolveParams>) {
        self.instruments.capture = Some(reference);
    }

    /// The velocity problem of the last step, when capturing.
    pub fn problem(&self) -> Option<&Problem> {
        self.instruments.capture.is_some().then(|| self.instruments.problem())
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
        self.instruments.exact_report()
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

    /// Advances the world by one step, taking the warm start from `warm`.
    pub fn step(&mut self, warm: &mut WarmStarter) -> &StepStats {
        let t_step = Instant::now();
        let solved_step = self.step;
        self.collide();
        self.apply_external_forces();

        // The problem as data, before anything changes the velocities (not part of the step's time).
        let t_capture = Instant::now();
        if let Some(reference) = self.instruments.capture {
            self.instruments.capture_problem(step_view!(self), &self.params.solve, reference);
        }
        let capture_time = t_capture.elapsed();

        let t_warm = Instant::now();
        let fallback = self.warm_start(warm);
        let warm_start_us = t_warm.elapsed().as_secs_f32() * 1e6;

        // The relative rule's tolerance comes from builtin's start (the previous step's impulses),
        // whatever the model's, so that every model of a run is held to the same accuracy.
        let builtin_start = self.history.previous_each(self.contacts.iter().map(|c| &c.key));
        let solve = self.params.solve.relative_to(builtin_start.map(Option::unwrap_or_default));

        // builtin on this same problem, when asked (a builtin step is its own answer); not part
        // of the step's time.
        let t_shadow = Instant::now();
        let shadow = (self.instruments.shadow_builtin && warm.used_name(fallback) != ModelKind::Builtin.name())
            .then(|| self.instruments.builtin_sweeps(step_view!(self), &solve));
        if !self.instruments.menu.is_empty() {
            self.instruments.solve_menu(step_view!(self));
        }
        if self.instruments.error_split {
            self.instruments.split_error(step_view!(self), &self.warm, &solve, &self.params.oracle);
        } else {
            self.instruments.clear_split();
        }
        let shadow_time = t_shadow.elapsed();

        let t_solve = Instant::now();
        let report = self.solver.solve(&self.rows, &mut self.solver_bodies, &self.warm, &solve);
        let solve_us = t_solve.elapsed().as_secs_f32() * 1e6;
        let builtin_sweeps = self.instruments.shadow_builtin.then(|| shadow.unwrap_or(report.sweeps));

        self.integrate();
        self.min_separation = self.correct_positions();
        // A model working ahead sends the step now (its time is the warm start's).
        let t_ahead = Instant::now();
        self.after_step(warm, solved_step);
        let warm_start_us = warm_start_us + t_ahead.elapsed().as_secs_f32() * 1e6;

        let timings = StepTimings {
            solve_us,
            warm_start_us,
            step_us: t_step.elapsed().saturating_sub(capture_time + shadow_time).as_secs_f32() * 1e6,
        };
        self.record(warm, warm.used_name(fallback), fallback, report, builtin_sweeps, timings);
        &self.stats
    }

    /// Stage 1: contacts on the current poses.
    fn collide(&mut self) {
        let (prediction, margin) = (self.params.prediction, self.params.contact_margin);
        self.collision.detect(&self.bodies, prediction, margin, &mut self.contacts, &mut self.position_rows);
    }

    /// Stage 2: velocities after external forces (kinematic bodies carry their prescribed
    /// velocity) and the solver's rows of the contacts.
    fn apply_external_forces(&mut self) {
        let dt = self.params.dt;
        let g = Vec2::from(self.params.gravity);
        self.solver_bodies.clear();
        for b in &self.bodies {
            let v = if b.kind == BodyKind::Dynamic { b.v + g * dt } else { b.v };
            self.solver_bodies.push(SolverBody { v, w: b.w, inv_mass: b.inv_mass(), inv_inertia: b.inv_inertia() });
        }
        self.rows.clear();
        let friction = self.params.solve.friction;
        let pasts = self.history.pasts(self.contacts.iter().map(|c| &c.key));
        for ((c, pr), past) in self.contacts.iter().zip(&self.position_rows).zip(pasts) {
            let (a, b) = (&self.bodies[pr.body_a as usize], &self.bodies[pr.body_b as usize]);
            let previous = past.previous;
            self.rows.push(ContactRow {
                body_a: pr.body_a,
                body_b: pr.body_b,
                ra: c.point - a.x,
                rb: c.point - b.x,
                normal: c.normal,
                friction: c.friction,
                height: c.point.y,
                friction_bound: per_step_bound(
                    friction,
                    previous.is_some(),
                    c.friction,
                    previous.map_or(0.0, |p| p.normal),
                ),
            });
        }
    }

    /// Stage 3: the warm start into `self.warm`, with what the model needs computed first (part
    /// of the warm start's time: a model that reads the problem pays for its capture, and a
    /// reference pays for its oracle). Returns whether the model fell back.
    fn warm_start(&mut self, warm: &mut WarmStarter) -> bool {
        let needs = warm.needs();
        if needs.problem && self.instruments.capture.is_none() {
            self.instruments.capture_problem(step_view!(self), &self.params.solve, None);
        }
        if needs.exact {
            self.instruments.solve_exact(step_view!(self), &self.params.oracle);
        } else {
            self.instruments.clear_exact();
        }
        self.warm.clear();
        self.warm.resize(self.contacts.len(), Impulse::default());
        let input = WarmStartInput {
            run_id: self.run_id,
            simulation: self.simulation,
            step: self.step,
            contacts: &self.contacts,
            history: &self.history,
            problem: needs.problem.then(|| self.instruments.problem()),
            rows: needs.rows.then_some(StepRows {
                rows: &self.rows,
                bodies: &self.solver_bodies,
                compliance: self.params.solve.compliance,
            }),
            exact: needs.exact.then(|| self.instruments.exact()),
        };
        warm.warm_start(&input, &mut self.warm)
    }

    /// Stage 7: the done step to a model that predicts the next step's warm start meanwhile.
    fn after_step(&mut self, warm: &mut WarmStarter, step: u32) {
        let needs = warm.needs();
        let g = Vec2::from(self.params.gravity) * self.params.dt;
        warm.after_step(&SolvedStep {
            run_id: self.run_id,
            simulation: self.simulation,
            step,
            problem: needs.problem.then(|| self.instruments.problem()),
            impulses: self.solver.impulses(),
            bodies: &self.bodies,
            geometry: &self.position_rows,
            poses: &self.poses,
            gravity_dt: [g.x, g.y],
        });
    }

    /// Stage 5: positions from the solved velocities (dynamic bodies, Box2D's caps; kinematic ones
    /// follow their prescribed motion), into the poses the position pass moves.
    fn integrate(&mut self) {
        let dt = self.params.dt;
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
    }

    /// Stage 6: the position pass, then the poses mirrored into rapier for the next detection.
    /// Returns the smallest separation the pass saw.
    fn correct_positions(&mut self) -> f32 {
        let min_separation = correct_positions(&self.position_rows, &mut self.poses, &self.params.position);
        for (b, p) in self.bodies.iter_mut().zip(&self.poses) {
            if b.kind == BodyKind::Dynamic {
                b.x = p.x;
                b.angle = p.angle;
            }
        }
        self.collision.mirror_poses(&self.bodies);
        min_separation
    }

    /// The step's statistics and the impulse history for the next step's warm start.
    fn record(
        &mut self,
        warm: &WarmStarter,
        used: &str,
        fallback: bool,
        report: SolveReport,
        builtin_sweeps: Option<u32>,
        timings: StepTimings,
    ) {
        let final_impulses = self.solver.impulses();
        let persisting =
            self.history.pasts(self.contacts.iter().map(|c| &c.key)).filter(|p| p.previous.is_some()).count();
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
        // The pile after the position pass (bookkeeping, after the step's timer stopped).
        let ((penetration_max, penetration_mean), (pile_height, pile_spread)) = (self.penetration(), self.pile());
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
            solve_us: timings.solve_us,
            warm_start_us: timings.warm_start_us,
            step_us: timings.step_us,
            kinetic_energy: 0.0,
            max_speed: 0.0,
            builtin_sweeps: builtin_sweeps.unwrap_or(0),
            builtin_measured: builtin_sweeps.is_some(),
            natural_max: report.natural.max,
            natural_rms: report.natural.rms,
            penetration_max,
            penetration_mean,
            pile_height,
            pile_spread,
            ..StepStats::default()
        };
        self.stats.set_split(self.instruments.split(), self.params.solve.max_sweeps);
        // Measured after the step's timer stopped: bookkeeping, not simulation.
        (self.stats.kinetic_energy, self.stats.max_speed) = self.motion();
    }

    /// Overlap the position pass left, over the last step's contacts: the largest and the mean
    /// (m; 0 without contacts), measured on the corrected poses.
    pub fn penetration(&self) -> (f32, f32) {
        let (mut max, mut sum) = (0.0f32, 0.0f64);
        for row in &self.position_rows {
            let depth = (-crate::solver::position::measure(row, &self.poses).2).max(0.0);
            max = max.max(depth);
            sum += depth as f64;
        }
        (max, (sum / self.position_rows.len().max(1) as f64) as f32)
    }

    /// The dynamic bodies' centre-of-mass height and their spread about the centre of mass (the
    /// mass-weighted RMS distance from it), m.
    pub fn pile(&self) -> (f32, f32) {
        let dynamic = || self.bodies.iter().filter(|b| b.kind == BodyKind::Dynamic);
        let mass: f64 = dynamic().map(|b| b.mass as f64).sum();
        if mass <= 0.0 {
            return (0.0, 0.0);
        }
        let (mut cx, mut cy) = (0.0f64, 0.0f64);
        for b in dynamic() {
            cx += b.mass as f64 * b.x.x as f64;
            cy += b.mass as f64 * b.x.y as f64;
        }
        (cx, cy) = (cx / mass, cy / mass);
        let spread: f64 =
            dynamic().map(|b| b.mass as f64 * ((b.x.x as f64 - cx).powi(2) + (b.x.y as f64 - cy).powi(2))).sum();
        (cy as f32, (spread / mass).sqrt() as f32)
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

/// The step's measured times, microseconds.
#[derive(Debug, Clone, Copy)]
struct StepTimings {
    solve_us: f32,
    warm_start_us: f32,
    /// The whole step less the instruments' time.
    step_us: f32,
}
