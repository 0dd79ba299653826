//! The simulator's step loop: every seed of a run with one warm-start model, the run's control
//! messages, and each step's bodies, contacts and statistics handed to a [`RunSink`]. `dc-sim`
//! publishes them on the bus; the one-process loop (`dc-loop-bench`) records them and computes
//! the next warm start itself. Both solve exactly the same steps.

use crate::error::SimError;
use crate::scene::SceneConfig;
use crate::warm::WarmStarter;
use crate::world::{World, WorldParams};
use msgs::{ControlKind, ControlMsg, RunParams, RunSummary, SceneInfo, StepHeader};
use std::time::Instant;

/// One run: a model over seeds.
#[derive(Debug, Clone)]
pub struct RunSpec {
    /// The scene; its seed is replaced by each seed of the run.
    pub scene: SceneConfig,
    pub params: WorldParams,
    pub seeds: Vec<u64>,
    pub steps: u32,
    pub run_id: u64,
    /// Hand each step's velocity problem to the sink (`--publish-problem`), labelled with a
    /// reference solution solved with `label` when given (`--label-tolerance`).
    pub problems: bool,
    pub label: Option<crate::solver::SolveParams>,
    /// Also solve every step from builtin's warm start, on scratch velocities (`--shadow-builtin`):
    /// what builtin would cost on the states this model leads to, logged per simulation beside
    /// the model's own sweeps. Separates a warm start's own effect from the trajectory's.
    pub shadow_builtin: bool,
    /// Also split every step's warm-start error against the step's exact solution, beside
    /// builtin's on the same step (`--error-split`): the statistics' `split_*` fields.
    pub error_split: bool,
}

/// Most steps of one simulation: 10^4 s simulated at the default 100 Hz. Nothing in the
/// simulator grows with the steps, but the metrics keep per-step series (bands by step) and a
/// recording every step's frames, so the step count sizes their memory and disk.
pub const MAX_STEPS: u32 = 1_000_000;

impl RunSpec {
    /// Checks every count and size of the run before anything is allocated: the seeds (at most
    /// [`msgs::MAX_SEEDS`], each at most [`msgs::MAX_SEED`]), the steps (at most [`MAX_STEPS`]),
    /// the scene ([`SceneConfig::validate`]) and the solver parameters.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |name, value: String, why: String| Err(SimError::InvalidParameter { name, value, why });
        if self.seeds.is_empty() || self.seeds.len() as u64 > msgs::MAX_SEEDS {
            let why = format!("from 1 to {} seeds (msgs::MAX_SEEDS)", msgs::MAX_SEEDS);
            return bad("seeds", format!("{} seeds", self.seeds.len()), why);
        }
        if let Some(&seed) = self.seeds.iter().find(|&&s| s > msgs::MAX_SEED) {
            return bad(
                "seeds",
                seed.to_string(),
                format!("at most {} (seeds are u32 simulation ids)", msgs::MAX_SEED),
            );
        }
        if self.steps > MAX_STEPS {
            return bad("steps", self.steps.to_string(), format!("at most {MAX_STEPS} (sim::run::MAX_STEPS)"));
        }
        self.scene.validate()?;
        self.params.validate()
    }
}

/// One step's outputs, borrowed from the world.
pub struct StepOutput<'a> {
    pub header: StepHeader,
    pub bodies: &'a [msgs::Body],
    pub contacts: &'a [msgs::Contact],
    pub stats: &'a msgs::StepStats,
    /// Residual after each sweep, at most [`msgs::MAX_RESIDUALS`].
    pub residuals: &'a [f32],
    /// The step's velocity problem, when the run captures them.
    pub problem: Option<&'a crate::problem::Problem>,
}

/// Where a run's messages go.
pub trait RunSink {
    /// Run and simulation start / end.
    fn control(&mut self, msg: &ControlMsg) -> Result<(), SimError>;
    /// Before step `step` of `simulation`: false stops the run (a shutdown).
    fn before_step(&mut self, _simulation: u32, _step: u32) -> bool {
        true
    }
    /// A solved step.
    fn step(&mut self, out: &StepOutput<'_>) -> Result<(), SimError>;
}

/// The run's parameters as its run start announces them.
pub fn run_params(spec: &RunSpec, warm: &WarmStarter) -> RunParams {
    RunParams {
        scene: spec.scene.kind.name().to_string(),
        n: spec.scene.n as u64,
        seeds: spec.seeds.clone(),
        steps: spec.steps,
        model: warm.model.name().to_string(),
        fallback: warm.fallback.name().to_string(),
        tolerance: spec.params.solve.tolerance,
        max_sweeps: spec.params.solve.max_sweeps,
        sampler: format!("{:?}", spec.scene.sampler).to_lowercase(),
        dt: spec.params.dt,
        compliance: spec.params.solve.compliance,
        relaxation: spec.params.solve.relaxation,
        solver: spec.params.solve.setting().to_string(),
        stop: spec.params.solve.stop.name().to_string(),
    }
}

/// Runs every seed of `spec` with `warm`, handing everything to `sink`; returns the run's totals.
pub fn run(spec: &RunSpec, warm: &mut WarmStarter, sink: &mut dyn RunSink) -> Result<RunSummary, SimError> {
    spec.validate()?;
    let run_id = spec.run_id;
    let run_header = StepHeader { run_id, simulation: 0, step: 0 };
    sink.control(&ControlMsg::run_start(run_header, &run_params(spec, warm)))?;
    tracing::info!(run_id, simulations = spec.seeds.len(), model = warm.model.name(), "run start");
    let mut summary = RunSummary {
        run_id,
        model: warm.model.name().to_string(),
        steps: 0,
        loop_secs: 0.0,
        total_sweeps: 0,
        fallbacks: 0,
    };
    let (mut bodies, mut contacts) = (Vec::new(), Vec::new());
    'run: for &seed in &spec.seeds {
        // At most msgs::MAX_SEED: checked by `spec.validate()` above.
        let simulation = seed as u32;
        let mut world = World::new(&SceneConfig { seed, ..spec.scene.clone() }, spec.params)?;
        world.set_ids(run_id, simulation);
        if spec.problems {
            world.capture_problems(spec.label);
        }
        world.shadow_builtin(spec.shadow_builtin);
        world.error_split(spec.error_split);
        warm.begin_simulation(simulation, seed);
        let sim_header = StepHeader { run_id, simulation, step: 0 };
        let scene = SceneInfo {
            seed,
            side: world.scene().side,
            bodies: world.bodies().len() as u64,
            dynamic: world.scene().dynamic_count() as u64,
            omega: world.scene().omega,
        };
        sink.control(&ControlMsg::simulation_start(sim_header, spec.steps, &scene))?;
        let (mut sweeps, mut unconverged, mut shadow) = (0u64, 0u32, 0u64);
        let started = Instant::now();
        let mut stopped = false;
        for step in 0..spec.steps {
            if !sink.before_step(simulation, step) {
                stopped = true;
                break;
            }
            world.step(warm);
            world.body_msgs(&mut bodies);
            world.contact_msgs(&mut contacts);
            let stats = world.stats();
            sweeps += stats.sweeps as u64;
            shadow += stats.builtin_sweeps as u64;
            unconverged += (!stats.converged) as u32;
            let residuals = &world.residuals()[..world.residuals().len().min(msgs::MAX_RESIDUALS)];
            let header = StepHeader { run_id, simulation, step };
            let problem = world.problem();
            sink.step(&StepOutput { header, bodies: &bodies, contacts: &contacts, stats, residuals, problem })?;
        }
        let steps = world.steps_taken();
        sink.control(&ControlMsg::simple(StepHeader { step: steps, ..sim_header }, ControlKind::SimulationEnd, steps))?;
        let secs = started.elapsed().as_secs_f64();
        tracing::info!(
            seed,
            steps,
            total_sweeps = sweeps,
            shadow_builtin_sweeps = spec.shadow_builtin.then_some(shadow),
            unconverged,
            fallbacks = warm.fallbacks_total(),
            secs,
            "simulation done"
        );
        summary.steps += steps as u64;
        summary.loop_secs += secs;
        summary.total_sweeps += sweeps;
        summary.fallbacks += warm.fallbacks_total() as u64;
        if stopped {
            break 'run;
        }
    }
    sink.control(&ControlMsg::simple(run_header, ControlKind::RunEnd, spec.seeds.len() as u32))?;
    tracing::info!(run_id, "run end");
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::warm::ModelKind;

    /// Keeps what a run hands out.
    #[derive(Default)]
    struct Collect {
        controls: Vec<ControlMsg>,
        steps: Vec<msgs::StepStats>,
        stop_at: Option<(u32, u32)>,
    }

    impl RunSink for Collect {
        fn control(&mut self, msg: &ControlMsg) -> Result<(), SimError> {
            self.controls.push(msg.clone());
            Ok(())
        }
        fn before_step(&mut self, simulation: u32, step: u32) -> bool {
            self.stop_at != Some((simulation, step))
        }
        fn step(&mut self, out: &StepOutput<'_>) -> Result<(), SimError> {
            assert_eq!(out.header, out.stats.step_header());
            assert!(out.residuals.len() <= msgs::MAX_RESIDUALS);
            self.steps.push(out.stats.clone());
            Ok(())
        }
    }

    fn spec(seeds: Vec<u64>, steps: u32) -> RunSpec {
        RunSpec {
            scene: SceneConfig { n: 20, ..SceneConfig::default() },
            params: WorldParams::default(),
            seeds,
            steps,
            run_id: 42,
            problems: false,
            label: None,
            shadow_builtin: false,
            error_split: false,
        }
    }

    #[test]
    fn a_run_beyond_its_bounds_is_refused_before_it_starts() {
        let mut sink = Collect::default();
        let mut warm = ModelKind::Builtin.starter(0).unwrap();
        let e = run(&spec(vec![0], MAX_STEPS + 1), &mut warm, &mut sink).unwrap_err();
        assert_eq!(e.to_string(), "invalid parameter `steps` = 1000001: at most 1000000 (sim::run::MAX_STEPS)");
        let e = spec((0..=msgs::MAX_SEEDS).collect(), 1).validate().unwrap_err();
        assert!(matches!(e, SimError::InvalidParameter { name: "seeds", .. }), "{e}");
        let e = spec(vec![1 << 32], 1).validate().unwrap_err();
        assert!(e.to_string().contains("at most 4294967295"), "{e}");
        let e = RunSpec { scene: SceneConfig { n: 10_000_000, ..SceneConfig::default() }, ..spec(vec![0], 1) }
            .validate()
            .unwrap_err();
        assert!(matches!(e, SimError::InvalidParameter { name: "n", .. }), "{e}");
        assert!(sink.controls.is_empty(), "nothing was announced");
    }

    #[test]
    fn a_run_announces_itself_and_sums_its_steps() {
        let mut warm = ModelKind::Builtin.starter(0).unwrap();
        let mut sink = Collect::default();
        let summary = run(&spec(vec![3, 5], 30), &mut warm, &mut sink).unwrap();
        let kinds: Vec<_> = sink.controls.iter().map(|c| c.header.kind().unwrap()).collect();
        use ControlKind::*;
        assert_eq!(kinds, [RunStart, SimulationStart, SimulationEnd, SimulationStart, SimulationEnd, RunEnd]);
        match sink.controls[0].details().unwrap() {
            msgs::ControlDetails::RunStart(p) => {
                assert_eq!((p.model.as_str(), p.seeds.as_slice(), p.steps), ("builtin", &[3u64, 5][..], 30));
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(sink.controls[1].details().unwrap(), msgs::ControlDetails::SimulationStart(s) if s.seed == 3));
        assert_eq!(sink.steps.len(), 60);
        assert_eq!(summary.steps, 60);
        assert_eq!(summary.total_sweeps, sink.steps.iter().map(|s| s.sweeps as u64).sum::<u64>());
        assert!(sink.steps.iter().all(|s| s.run_id == 42 && s.model == "builtin" && s.used_model == "builtin"));
        assert_eq!((sink.steps[30].simulation, sink.steps[30].step), (5, 0));
    }

    #[test]
    fn a_sink_can_stop_the_run() {
        let mut warm = ModelKind::None.starter(0).unwrap();
        let mut sink = Collect { stop_at: Some((0, 10)), ..Collect::default() };
        let summary = run(&spec(vec![0, 1], 30), &mut warm, &mut sink).unwrap();
        assert_eq!((summary.steps, sink.steps.len()), (10, 10));
        let ends: Vec<_> =
            sink.controls.iter().filter(|c| c.header.kind() == Some(ControlKind::SimulationEnd)).collect();
        assert_eq!((ends.len(), ends[0].header.count), (1, 10), "the stopped simulation ends with the steps it took");
        assert_eq!(sink.controls.last().unwrap().header.kind(), Some(ControlKind::RunEnd));
    }
}
