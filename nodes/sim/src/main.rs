//! `dc-sim`: the simulator node. Runs simulations in sequence and publishes bodies, contacts (with
//! their final impulses), solver statistics and control messages every step; models that another
//! node serves read their grids or warm starts from the bus. The studies (solvers side by side,
//! the real-time regime, the benchmark) are `dc study`.

use anyhow::{bail, Context, Result};
use sim::bus::{NodeRun, Publishers};
use sim::cli::{required_duration, SceneArgs, SolveArgs};
use sim::run::RunSpec;
use sim::source::Waits;
use sim::{ModelFiles, ModelSpec, SolveParams};
use std::time::Duration;

/// A grid deadline; `None` is lockstep. A newtype because clap reads `Option<T>` as "flag may be absent".
#[derive(Debug, Clone, Copy)]
struct Deadline(Option<Duration>);

/// Simulator node parameters.
#[derive(clap::Parser, Debug)]
#[command(name = "dc-sim", about = "Deep Contact simulator node (the studies: `dc study`)")]
struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    solve: SolveArgs,
    /// The real-time regime: exactly K sweeps a step, stopping earlier only when the natural
    /// residual is already at most --tolerance (the same as `--max-sweeps K --stop natural`);
    /// the statistics' natural residual says how accurate each step was.
    #[arg(long, value_name = "K", conflicts_with_all = ["max_sweeps", "stop"], value_parser = sim::cli::budget)]
    budget: Option<u32>,
    /// Warm-start model, `name` or `name:param` (`blend:0.75`).
    #[arg(
        long,
        default_value = "builtin",
        value_parser = |s: &str| s.parse::<ModelSpec>(),
        long_help = msgs::models::option_help("Warm-start model, `name` or `name:param` (`blend:0.75`).")
    )]
    model: ModelSpec,
    /// Several models, each run in turn as its own run (`none,builtin,copy`); overrides --model.
    #[arg(long, value_delimiter = ',', value_parser = |s: &str| s.parse::<ModelSpec>())]
    models: Vec<ModelSpec>,
    /// Model standing in when a grid is late (a local model).
    #[arg(long, default_value = "builtin", value_parser = |s: &str| s.parse::<ModelSpec>())]
    fallback: ModelSpec,
    /// The contact-graph network's model file (`dc-gnn`), for the `gnn` model.
    #[arg(long)]
    gnn_model: Option<std::path::PathBuf>,
    /// Publish each step's velocity problem on `problem/bodies` and `problem/contacts` (what a
    /// learned warm start trains on).
    #[arg(long)]
    publish_problem: bool,
    /// With --publish-problem: label each problem with a reference solution solved from
    /// builtin's warm start to this tolerance (cap: --oracle-max-sweeps), e.g. 1e-6 for training
    /// recordings.
    #[arg(long, value_parser = sim::cli::positive_f32, requires = "publish_problem")]
    label_tolerance: Option<f32>,
    /// Also solve every step from builtin's warm start on scratch velocities and log, per
    /// simulation, what builtin would have cost on this model's states (`shadow_builtin_sweeps`).
    #[arg(long)]
    shadow_builtin: bool,
    /// Also split each step's warm-start error (against the step's exact solution) into its
    /// smooth, pile-wide part and the rest, beside builtin's on the same step, and measure what
    /// the run's sweeps leave of each (the statistics' `split_*` fields; the report's "which part
    /// of builtin's error each model removes"). Three more solves per step on scratch
    /// velocities, outside the step's time.
    #[arg(long)]
    error_split: bool,
    /// Real-time pacing: start a step no sooner than this after the previous one (`10ms` for
    /// 100 steps/s, the simulated rate), so a graph can be watched live (`dc topic hz`,
    /// Foxglove); default: as fast as it solves.
    #[arg(long, value_parser = required_duration)]
    step_period: Option<Duration>,
    /// How long to wait for a grid: `none` (lockstep) or a duration (20ms, 0.5s).
    #[arg(long, default_value = "none", value_parser = |s: &str| sim::parse_deadline(s).map(Deadline))]
    deadline: Deadline,
    /// In lockstep, how long a grid may take before its producer counts as lost (a host gone
    /// without a launcher to say so): the step falls back and later steps wait only
    /// --resume-patience until grids flow again.
    #[arg(long, default_value = "30s", value_parser = required_duration)]
    lockstep_timeout: Duration,
    /// After the grid producer came back (or was lost), how long a step waits for its grid before
    /// falling back; the wait is unbounded again (lockstep) once a grid arrives.
    #[arg(long, default_value = "2s", value_parser = required_duration)]
    resume_patience: Duration,
    /// Run id stamped on every message (0: derived from the clock).
    #[arg(long, default_value_t = 0)]
    run_id: u64,
}

impl Args {
    /// The run of `model_index` (its id follows the first run's) over `seeds`.
    fn run_spec(&self, seeds: &[u64], first_run_id: u64, model_index: usize) -> RunSpec {
        let params = self.solve.world_params(self.budget);
        RunSpec {
            scene: self.scene.scene_config(seeds[0]),
            params,
            seeds: seeds.to_vec(),
            steps: self.scene.steps,
            run_id: first_run_id + model_index as u64,
            problems: self.publish_problem,
            // Labels are the oracle's solve to their own tolerance.
            label: self.label_tolerance.map(|tolerance| SolveParams { tolerance, ..params.oracle }),
            shadow_builtin: self.shadow_builtin,
            error_split: self.error_split,
        }
    }

    fn models(&self) -> Vec<ModelSpec> {
        if self.models.is_empty() {
            vec![self.model]
        } else {
            self.models.clone()
        }
    }

    fn files(&self) -> ModelFiles {
        ModelFiles { gnn: self.gnn_model.clone() }
    }
}

/// Everything that would fail once the run started, checked before it starts (and when the
/// launcher checks a launch file): seeds, world parameters, the models (a learned model's file),
/// the scene.
fn check(args: &Args) -> Result<()> {
    let seeds = args.scene.checked_seeds(args.solve.world_params(args.budget))?;
    args.run_spec(&seeds, 0, 0).validate()?;
    if args.fallback.is_grid_based() {
        bail!("--fallback must be a local model, not `{}`", args.fallback.name());
    }
    for m in args.models() {
        if m.served_on().is_none() {
            m.build_with(args.scene.seed, sim::warm::Served::default(), &args.files())?;
        }
    }
    sim::Scene::build(&args.scene.scene_config(seeds[0])).context("building the scene")?;
    Ok(())
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(args) = runtime::parse_args_checked::<Args, _>(check) else { return Ok(()) };
    runtime::init_logging();
    args.solve.start_threads().with_context(|| format!("--threads {}", args.solve.threads))?;
    let seeds = args.scene.seeds()?;
    let models = args.models();

    let node = runtime::Node::from_env("dc-sim")?;
    // `gnn-node` and `gnn-pipelined` send problems to their node themselves.
    let problems = args.publish_problem || models.iter().any(|m| m.kind.sends_problems());
    let mut pubs = Publishers::open(&node, problems)?;
    // Runs whose model reads another node open its subscribers for the run only (see `sim::bus::run`).
    for model in &models {
        if let Some(topic) = model.served_on() {
            node.will_subscribe(topic);
            node.will_subscribe(msgs::topics::CONTROL.name);
        }
    }
    if !node.ready()? {
        return Ok(());
    }
    let first_run_id = if args.run_id != 0 {
        args.run_id
    } else {
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH)?.as_nanos() as u64
    };
    let how = NodeRun {
        waits: Waits {
            deadline: args.deadline.0,
            lockstep_timeout: args.lockstep_timeout,
            resume_patience: args.resume_patience,
        },
        files: args.files(),
        seed: args.scene.seed,
        fallback: args.fallback,
        publish_problem: args.publish_problem,
        step_period: args.step_period,
    };
    for (i, &model) in models.iter().enumerate() {
        if node.is_shutdown() {
            break;
        }
        // Each model is its own run, so downstream nodes can tell them apart.
        let summary = sim::bus::run(&node, &mut pubs, model, &args.run_spec(&seeds, first_run_id, i), &how)?;
        // The run's totals on stdout (benchmarks read them).
        println!("{}", summary.line());
    }
    Ok(())
}
