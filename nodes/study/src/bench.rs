//! The simulator benchmark: ms/step of our world (rapier collision detection + our solver iterated
//! to tolerance) beside rapier's own full `PhysicsPipeline` on the same scene.
//!
//! The ratio is the figure of merit: what iterating to a tolerance (the thesis's setting) costs
//! over a production solver with a fixed, small iteration count. Both run single-threaded.

use rapier2d::math::{Pose, Vec2};
use rapier2d::prelude::PhysicsWorld;
use sim::error::SimError;
use sim::scene::{BodyKind, Scene, SceneConfig};
use sim::warm::ModelKind;
use sim::world::{World, WorldParams};
use std::time::Instant;

/// One measured configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchRow {
    /// Dynamic bodies.
    pub n: usize,
    /// Steps simulated.
    pub steps: u32,
    /// Warm-start model.
    pub model: &'static str,
    /// Mean wall time per step of our world, ms.
    pub ms_per_step: f64,
    /// Mean wall time per step of the velocity solve alone, ms.
    pub solve_ms_per_step: f64,
    /// Median sweeps per step (over steps with contacts).
    pub median_sweeps: u32,
    /// Steps that hit the sweep cap.
    pub unconverged_steps: u32,
    /// Mean contacts per step.
    pub mean_contacts: f64,
    /// Mean wall time per step of rapier's `PhysicsPipeline` on the same scene, ms.
    pub rapier_ms_per_step: f64,
}

impl BenchRow {
    /// Our time over rapier's.
    pub fn ratio(&self) -> f64 {
        self.ms_per_step / self.rapier_ms_per_step
    }
}

/// Mean ms/step of rapier's full pipeline (default integration parameters, same dt and gravity)
/// on `scene` over `steps` steps.
pub fn rapier_ms_per_step(scene: &Scene, params: &WorldParams, steps: u32) -> f64 {
    let mut w = PhysicsWorld::new();
    w.gravity = Vec2::from(params.gravity);
    w.integration_parameters.dt = params.dt;
    let mut kinematic = Vec::new();
    for (id, spec) in scene.bodies.iter().enumerate() {
        let (rb, co) = scene.rapier_body(id);
        let (h, _) = w.insert(rb, co);
        if spec.kind == BodyKind::Kinematic {
            kinematic.push((h, Vec2::from(spec.position), spec.angle));
        }
    }
    let c = Vec2::from(scene.centre);
    let t = Instant::now();
    for k in 0..steps {
        // The drum's walls: prescribed rotation about the box centre, as in our world.
        let theta = scene.omega * params.dt * (k + 1) as f32;
        let (s, co) = theta.sin_cos();
        for &(h, x0, a0) in &kinematic {
            let r = x0 - c;
            let x = c + Vec2::new(co * r.x - s * r.y, s * r.x + co * r.y);
            if let Some(rb) = w.bodies.get_mut(h) {
                rb.set_next_kinematic_position(Pose::new(x, a0 + theta));
            }
        }
        w.step();
    }
    t.elapsed().as_secs_f64() * 1e3 / steps.max(1) as f64
}

/// Runs `model` on the scene of `config` for `steps` steps and measures it (rapier's time is
/// filled in by [`run`]).
pub fn measure(config: &SceneConfig, params: WorldParams, model: ModelKind, steps: u32) -> Result<BenchRow, SimError> {
    let mut world = World::new(config, params)?;
    let mut warm = model.starter(config.seed)?;
    warm.begin_simulation(0, config.seed);
    let mut sweeps = Vec::with_capacity(steps as usize);
    let (mut solve_us, mut contacts, mut unconverged) = (0.0f64, 0u64, 0u32);
    let t = Instant::now();
    for _ in 0..steps {
        let s = world.step(&mut warm);
        if s.contacts > 0 {
            sweeps.push(s.sweeps);
        }
        unconverged += (!s.converged) as u32;
        solve_us += s.solve_us as f64;
        contacts += s.contacts as u64;
    }
    let ms = t.elapsed().as_secs_f64() * 1e3 / steps.max(1) as f64;
    sweeps.sort_unstable();
    Ok(BenchRow {
        n: config.n,
        steps,
        model: model.name(),
        ms_per_step: ms,
        solve_ms_per_step: solve_us / 1e3 / steps.max(1) as f64,
        median_sweeps: sweeps.get(sweeps.len() / 2).copied().unwrap_or(0),
        unconverged_steps: unconverged,
        mean_contacts: contacts as f64 / steps.max(1) as f64,
        rapier_ms_per_step: f64::NAN,
    })
}

/// The benchmark: for every `(n, steps)` case and model, our ms/step beside rapier's. Rows are
/// passed to `report` as they are measured (the large cases take a while).
pub fn run(
    base: &SceneConfig,
    params: WorldParams,
    cases: &[(usize, u32)],
    models: &[ModelKind],
    mut report: impl FnMut(&BenchRow),
) -> Result<Vec<BenchRow>, SimError> {
    let mut rows = Vec::new();
    for &(n, steps) in cases {
        let config = SceneConfig { n, side: None, ..base.clone() };
        let scene = Scene::build(&config)?;
        let rapier_ms = rapier_ms_per_step(&scene, &params, steps);
        for &model in models {
            let mut row = measure(&config, params, model, steps)?;
            row.rapier_ms_per_step = rapier_ms;
            report(&row);
            rows.push(row);
        }
    }
    Ok(rows)
}

/// Header line of [`format_row`]'s table.
pub const TABLE_HEADER: &str =
    "     n  steps  model      ms/step  solve ms  rapier ms   ratio  median sweeps  capped  contacts";

/// One line of the benchmark table.
pub fn format_row(r: &BenchRow) -> String {
    format!(
        "{:>6} {:>6}  {:<9} {:>8.3} {:>9.3} {:>10.3} {:>7.1} {:>14} {:>7} {:>9.0}",
        r.n,
        r.steps,
        r.model,
        r.ms_per_step,
        r.solve_ms_per_step,
        r.rapier_ms_per_step,
        r.ratio(),
        r.median_sweeps,
        r.unconverged_steps,
        r.mean_contacts
    )
}
