//! `dc-sim`: the simulator node. Runs simulations in sequence and publishes bodies, contacts (with
//! their final impulses), solver statistics and control messages every step; grid-based warm-start
//! models read their grid from the bus. `dc-sim --bench` runs the benchmark instead (no bus).

use anyhow::{bail, Context, Result};
use msgs::{ControlMsg, StepHeader};
use sim::run::{RunSink, RunSpec, StepOutput};
use sim::source::{BusSource, Inbox, SharedSource, SourceHandle, StepFrame, Waits};
use sim::{
    bench, ModelKind, ModelSpec, SamplerKind, SceneConfig, SceneKind, SimError, SolveParams, WarmStarter, WorldParams,
};
use std::time::{Duration, Instant};

/// A number `ok` accepts, or an error saying what it `must` be.
fn f32_where(s: &str, ok: fn(f32) -> bool, must: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if ok(v) => Ok(v),
        Ok(v) => Err(format!("must be {must}, got {v}")),
        Err(e) => Err(e.to_string()),
    }
}

fn positive_f32(s: &str) -> Result<f32, String> {
    f32_where(s, |v| v.is_finite() && v > 0.0, "a finite number > 0")
}

/// A relative compliance (`SolveParams::valid_compliance`).
fn compliance(s: &str) -> Result<f32, String> {
    f32_where(s, SolveParams::valid_compliance, &format!("a number {}", SolveParams::compliance_range()))
}

/// An over-relaxation factor (`SolveParams::valid_relaxation`).
fn relaxation(s: &str) -> Result<f32, String> {
    f32_where(s, SolveParams::valid_relaxation, &format!("a number {}", SolveParams::relaxation_range()))
}

fn required_duration(s: &str) -> Result<Duration, String> {
    sim::parse_deadline(s).map_err(|e| e.to_string())?.ok_or_else(|| "a duration is required, not `none`".to_string())
}

/// A grid deadline; `None` is lockstep. A newtype because clap reads `Option<T>` as "flag may be absent".
#[derive(Debug, Clone, Copy)]
struct Deadline(Option<Duration>);

/// A list of solver settings. A newtype because clap reads `Option<Vec<T>>` as "many values".
#[derive(Debug, Clone)]
struct SolverMenu(Vec<sim::SolverSetting>);

/// Simulator node parameters.
#[derive(clap::Parser, Debug)]
#[command(name = "dc-sim", about = "Deep Contact simulator node")]
struct Args {
    /// Scene: ball-box, drum or mixed.
    #[arg(long, default_value = "ball-box", value_parser = |s: &str| s.parse::<SceneKind>())]
    scene: SceneKind,
    /// Seeds of the simulations (`0..30`, `0..=29`, `1,5,7`); overrides --seed/--simulations.
    #[arg(long)]
    seeds: Option<String>,
    /// First seed (with --simulations).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Number of simulations, seeds seed..seed+simulations.
    #[arg(long, default_value_t = 1)]
    simulations: u64,
    /// Steps per simulation.
    #[arg(long, default_value_t = 250)]
    steps: u32,
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
    /// The velocity solver: pgs (projected Gauss-Seidel, the thesis's), sor:W (projected SOR,
    /// W in (0, 2)), nncg or nncg:R (nonsmooth nonlinear conjugate gradient, restarting when
    /// beta > R; nncg = nncg:1); `/down` visits the rows top-down (sor:1.4/down). The oracle,
    /// labels and shadow solves use the same. The default, NNCG restarting above 1.2 with rows
    /// top-down, needs 0.34x PGS's sweeps and 0.36x its time to the same natural residual on the
    /// evaluation seeds (docs/solvers.md); `--solver pgs --stop change` is the thesis's solver.
    #[arg(long, default_value_t = sim::SolverSetting::RECOMMENDED, value_parser = |s: &str| s.parse::<sim::SolverSetting>())]
    solver: sim::SolverSetting,
    /// Row order of the solver's sweeps: recorded (contact keys) or down (by contact height, top
    /// first, every step); overrides the order --solver names.
    #[arg(long, value_parser = |s: &str| s.parse::<sim::RowOrder>())]
    order: Option<sim::RowOrder>,
    /// Stopping rule: change (the largest impulse change of a sweep <= --tolerance, the
    /// thesis's) or natural (the natural residual, what one projected Jacobi step would still
    /// change, <= --tolerance: the same accuracy for every solver).
    #[arg(long, default_value_t = sim::StopRule::RECOMMENDED, value_parser = |s: &str| s.parse::<sim::StopRule>())]
    stop: sim::StopRule,
    /// Convergence tolerance of the stopping rule, in impulse units.
    #[arg(long, default_value_t = 1e-4, value_parser = positive_f32)]
    tolerance: f32,
    /// Sweep cap.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..))]
    max_sweeps: u32,
    /// The real-time regime: exactly K sweeps a step, stopping earlier only when the natural
    /// residual is already at most --tolerance (the same as `--max-sweeps K --stop natural`);
    /// the statistics' natural residual says how accurate each step was.
    #[arg(long, value_name = "K", conflicts_with_all = ["max_sweeps", "stop"],
          value_parser = clap::value_parser!(u32).range(1..=sim::budget::MAX_BUDGET as i64))]
    budget: Option<u32>,
    /// Relative compliance of every contact row (0: rigid, the thesis's problem); the oracle,
    /// the labels and the shadow solves use the same. See `sim::SolveParams::compliance`.
    #[arg(long, default_value_t = 0.0, value_parser = compliance)]
    compliance: f32,
    /// Over-relaxation factor of the solver's row updates; in (0, 2). The same as
    /// `--solver sor:W`.
    #[arg(long, value_parser = relaxation, conflicts_with = "solver")]
    relaxation: Option<f32>,
    /// The oracle's tolerance (`copy` and the oracle ablations solve each step from builtin's
    /// warm start to it, with the run's solver and the change rule: the natural residual stalls
    /// at the f32 impulses' resolution long before 2e-6 on deep piles).
    #[arg(long, default_value_t = 2e-6, value_parser = positive_f32)]
    oracle_tolerance: f32,
    /// The oracle's sweep cap.
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u32).range(1..))]
    oracle_max_sweeps: u32,
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
    #[arg(long, value_parser = positive_f32, requires = "publish_problem")]
    label_tolerance: Option<f32>,
    /// Also solve every step from builtin's warm start on scratch velocities and log, per
    /// simulation, what builtin would have cost on this model's states (`shadow_builtin_sweeps`).
    #[arg(long)]
    shadow_builtin: bool,
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
    /// Initial-world sampler: native or numpy (the original code's worlds, exactly).
    #[arg(long, default_value = "native", value_parser = |s: &str| s.parse::<SamplerKind>())]
    sampler: SamplerKind,
    /// Dynamic bodies.
    #[arg(long, default_value_t = 100)]
    n: usize,
    /// Box side (default 15 * sqrt(n / 100)).
    #[arg(long, value_parser = positive_f32)]
    side: Option<f32>,
    /// Drum angular speed, rad/s.
    #[arg(long, default_value_t = 1.0)]
    drum_omega: f32,
    /// Linear slop of the position pass.
    #[arg(long, default_value_t = 0.0005)]
    slop: f32,
    /// Run id stamped on every message (0: derived from the clock).
    #[arg(long, default_value_t = 0)]
    run_id: u64,
    /// Compare solvers instead of running the node (no bus): every setting of this list
    /// (`pgs,sor:1.4,nncg,sor:1.4/down`) solves every step of --seeds from builtin's warm start
    /// to the same stopping rule (--stop, --tolerance), the trajectory driven by the first; prints
    /// and writes the side-by-side table (with the hindsight ceiling) and every step's figures.
    #[arg(long, value_parser = |s: &str| sim::solver::parse_settings(s).map(SolverMenu))]
    compare_solvers: Option<SolverMenu>,
    /// With --compare-solvers: train a per-step choice among the settings on these seeds'
    /// same states and judge it on --seeds (never the evaluation seeds 0..29).
    #[arg(long, requires = "compare_solvers")]
    train_seeds: Option<String>,
    /// With --compare-solvers: also run every seed with each setting (and the learned choice)
    /// driving its own trajectory.
    #[arg(long, requires = "compare_solvers")]
    whole_runs: bool,
    /// With --compare-solvers: the folder for `solvers.md`, `solver-steps.csv` and
    /// `solver-sweeps.png` (mean sweeps per step by solver); with --budget-study: for
    /// `budget.md`, `budget-steps.csv` and `budget-accuracy.png`.
    #[arg(long)]
    out: Option<std::path::PathBuf>,
    /// Study the real-time regime instead of running the node (no bus): at each budget of this
    /// list (`8` or `4,8`), every model of --models (default none, builtin, blend:0.25,
    /// blend:0.5, blend:0.75, and gnn with --gnn-model) runs every seed with that many sweeps a
    /// step, placed on builtin's curve of accuracy against budget (1, 2, 4, ... 16K), the pile
    /// compared per phase with a reference run solved to --reference-tolerance; prints and
    /// writes the tables (docs/budget.md explains them).
    #[arg(long, value_name = "K,...", value_delimiter = ',', conflicts_with_all = ["budget", "compare_solvers", "bench"],
          value_parser = clap::value_parser!(u32).range(1..=sim::budget::MAX_BUDGET as i64))]
    budget_study: Vec<u32>,
    /// With --budget-study: the reference run's tolerance (natural residual).
    #[arg(long, default_value_t = 1e-6, value_parser = positive_f32)]
    reference_tolerance: f32,
    /// Also split each step's warm-start error (against the step's exact solution) into its
    /// smooth, pile-wide part and the rest, beside builtin's on the same step, and measure what
    /// the run's sweeps leave of each (the statistics' `split_*` fields; the report's "which part
    /// of builtin's error each model removes"). Three more solves per step on scratch
    /// velocities, outside the step's time. With --budget-study: one more pass per judged run.
    #[arg(long)]
    error_split: bool,
    /// With --budget-study: time each seed's runs this many times, interleaved, and keep each
    /// step's median warm-start and solve time (the runs repeat the same steps; their timings
    /// move with the machine's load).
    #[arg(long, default_value_t = 1, requires = "budget_study", value_parser = clap::value_parser!(u32).range(1..=15))]
    timing_repeats: u32,
    /// Run the benchmark and print it instead of running the node.
    #[arg(long)]
    bench: bool,
    /// Benchmark cases `n:steps,...` (N=10,000 needs ~300 steps before its balls land).
    #[arg(long, default_value = "100:250,1000:250,10000:400")]
    bench_cases: String,
}

impl Args {
    fn seeds(&self) -> Result<Vec<u64>> {
        match &self.seeds {
            Some(s) => Ok(sim::parse_seeds(s)?),
            // The seed list's own bounds (count, largest seed), checked before it is built.
            None => msgs::parse_seeds(&format!("{}..{}", self.seed, self.seed.saturating_add(self.simulations)))
                .map_err(|why| {
                    anyhow::anyhow!("--seed = {} with --simulations = {}: {why}", self.seed, self.simulations)
                }),
        }
    }

    /// The run of `model_index` (its id follows the first run's) over `seeds`.
    fn run_spec(&self, seeds: &[u64], first_run_id: u64, model_index: usize) -> RunSpec {
        let params = self.world_params();
        RunSpec {
            scene: self.scene_config(seeds[0]),
            params,
            seeds: seeds.to_vec(),
            steps: self.steps,
            run_id: first_run_id + model_index as u64,
            problems: self.publish_problem,
            // Labels are the oracle's solve to their own tolerance.
            label: self.label_tolerance.map(|tolerance| SolveParams { tolerance, ..params.oracle }),
            shadow_builtin: self.shadow_builtin,
            error_split: self.error_split,
        }
    }

    /// The benchmark's `n:steps` cases.
    fn bench_cases(&self) -> Result<Vec<(usize, u32)>> {
        let mut cases = Vec::new();
        for part in self.bench_cases.split(',') {
            let (n, steps) = part.split_once(':').context("--bench-cases: expected n:steps,...")?;
            let n = n.trim().parse().with_context(|| format!("--bench-cases `{part}`: n"))?;
            let steps = steps.trim().parse().with_context(|| format!("--bench-cases `{part}`: steps"))?;
            cases.push((n, steps));
        }
        Ok(cases)
    }

    fn scene_config(&self, seed: u64) -> SceneConfig {
        SceneConfig {
            kind: self.scene,
            n: self.n,
            seed,
            sampler: self.sampler,
            side: self.side,
            drum_omega: self.drum_omega,
            ..SceneConfig::default()
        }
    }

    fn world_params(&self) -> WorldParams {
        let mut setting = self.solver;
        if let Some(w) = self.relaxation {
            setting.relaxation = w;
        }
        if let Some(order) = self.order {
            setting.order = order;
        }
        let solve = SolveParams {
            tolerance: self.tolerance,
            max_sweeps: self.budget.unwrap_or(self.max_sweeps),
            compliance: self.compliance,
            stop: if self.budget.is_some() { sim::StopRule::Natural } else { self.stop },
            ..SolveParams::default()
        }
        .with_setting(setting);
        // The oracle solves the same problem with the same solver, only further, to the change
        // rule (see --oracle-tolerance).
        let oracle = SolveParams {
            tolerance: self.oracle_tolerance,
            max_sweeps: self.oracle_max_sweeps,
            stop: sim::StopRule::Change,
            ..solve
        };
        let mut p = WorldParams { solve, oracle, ..WorldParams::default() };
        p.position.slop = self.slop;
        p
    }
}

/// The warm-start frames (grids, or per-contact warm starts) and control subscribers of a run whose
/// model reads another node, as its source reads them.
struct BusInbox<H: msgs::FrameHeader, T: msgs::FrameItem> {
    frames: runtime::Subscriber<H, T>,
    control: runtime::Subscriber<msgs::Control, u8>,
    shutdown: runtime::ShutdownSignal,
}

impl<H: msgs::FrameHeader, T: msgs::FrameItem> BusInbox<H, T> {
    /// `frames` with a control subscriber of its own (our own control messages arrive there too;
    /// the step loop drains it).
    fn open(node: &runtime::Node, frames: runtime::Subscriber<H, T>) -> Result<Self> {
        Ok(BusInbox { frames, control: node.subscriber(msgs::topics::CONTROL)?, shutdown: node.shutdown_signal() })
    }
}

impl<H: msgs::FrameHeader, T: msgs::FrameItem> Inbox<msgs::Frame<H, T>> for BusInbox<H, T> {
    fn topic(&self) -> &str {
        self.frames.topic()
    }
    fn try_frame(&mut self) -> Result<Option<msgs::Frame<H, T>>, String> {
        self.frames.try_recv().map(|g| g.map(|g| g.into_frame())).map_err(|e| e.to_string())
    }
    fn frame_timeout(&mut self, timeout: Duration) -> Result<Option<msgs::Frame<H, T>>, String> {
        self.frames.recv_timeout(timeout).map(|g| g.map(|g| g.into_frame())).map_err(|e| e.to_string())
    }
    fn try_control(&mut self) -> Result<Option<ControlMsg>, String> {
        self.control.try_recv().map(|c| c.map(|c| c.into_frame())).map_err(|e| e.to_string())
    }
    fn shutdown(&self) -> bool {
        self.shutdown.is_set()
    }
}

fn run_bench(args: &Args) -> Result<()> {
    let cases = args.bench_cases()?;
    let base = args.scene_config(args.seed);
    println!(
        "dc-sim benchmark: scene {}, seed {}, tolerance {}, max sweeps {}; rapier = its full PhysicsPipeline, default parameters",
        base.kind.name(),
        base.seed,
        args.tolerance,
        args.max_sweeps
    );
    println!("{}", bench::TABLE_HEADER);
    bench::run(&base, args.world_params(), &cases, &[ModelKind::None, ModelKind::Builtin], |r| {
        println!("{}", bench::format_row(r))
    })?;
    Ok(())
}

/// Seeds 0..29 are the evaluation's: nothing is trained on them.
const EVALUATION_SEEDS: std::ops::Range<u64> = 0..30;

/// A progress bar over `len` seeds, titled `what`.
fn seed_bar(len: usize, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} seeds, {elapsed}, ~{eta} left")
            .expect("a valid template"),
    );
    bar.set_message(what.to_string());
    bar
}

/// Writes `text` to `dir/name`, the error naming the file.
fn write_in(dir: &std::path::Path, name: &str, text: &str) -> Result<()> {
    let path = dir.join(name);
    std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))
}

/// `dc-sim --compare-solvers`: the same-states table, the chooser, whole runs.
fn compare_solvers(args: &Args, menu: &[sim::SolverSetting]) -> Result<()> {
    use sim::compare::{self, Choice, CompareSpec, SolverChooser};
    let seeds = args.seeds()?;
    let spec = CompareSpec {
        scene: args.scene_config(seeds[0]),
        params: args.world_params(),
        steps: args.steps,
        menu: menu.to_vec(),
    };
    let describe = format!(
        "{} steps, stop {} <= {}, cap {}, {} bodies",
        args.steps,
        spec.params.solve.stop.name(),
        spec.params.solve.tolerance,
        spec.params.solve.max_sweeps,
        args.n
    );
    let chooser = match &args.train_seeds {
        Some(list) => {
            let train = sim::parse_seeds(list)?;
            if let Some(s) = train.iter().find(|&&s| EVALUATION_SEEDS.contains(&s)) {
                bail!("--train-seeds {list}: seed {s} is an evaluation seed (0..29 are never trained on)");
            }
            let p = seed_bar(train.len(), "same states, training seeds");
            let steps = compare::same_states(&spec, &train, |_| p.inc(1))?;
            p.finish_and_clear();
            Some(SolverChooser::fit(menu, &steps)?)
        }
        None => None,
    };
    let p = seed_bar(seeds.len(), "same states");
    let steps = compare::same_states(&spec, &seeds, |_| p.inc(1))?;
    p.finish_and_clear();
    // The chooser pays, every step, its features' extraction and its pick (the median pick).
    let pick_us = chooser.as_ref().map(|c| c.median_pick_us(&steps));
    let rows = compare::same_states_table(menu, &steps, chooser.as_ref().zip(pick_us));
    let mut report = format!(
        "# Solvers on the same states\n\n`dc-sim {}`\n\nSeeds {}, {describe}; builtin's warm start; the trajectory is {}'s.\n\n{}",
        std::env::args().skip(1).collect::<Vec<_>>().join(" "),
        args.seeds.clone().unwrap_or_else(|| format!("{}..{}", args.seed, args.seed + args.simulations)),
        menu[0],
        compare::markdown(&rows)
    );
    if let (Some(c), Some(us)) = (&chooser, pick_us) {
        let shares: Vec<String> = menu.iter().zip(c.picks(&steps)).map(|(m, k)| format!("{m} {k}")).collect();
        let features_us = charts::median(&steps.iter().map(|s| s.features_us as f64).collect::<Vec<_>>());
        report += &format!(
            "\nThe learned choice's picks (steps): {}; per step {features_us:.2} us for the features and {us:.2} us for the pick (medians).\n",
            shares.join(", ")
        );
    }
    if args.whole_runs {
        let mut whole = Vec::new();
        let choices = menu.iter().map(|&s| (s.to_string(), Choice::Fixed(s)));
        for (name, choice) in
            choices.chain(chooser.as_ref().map(|c| ("learned choice".to_string(), Choice::Learned(c))))
        {
            let p = seed_bar(seeds.len(), &format!("whole runs, {name}"));
            whole.push((name, compare::whole_run(&spec, &seeds, choice, |_| p.inc(1))?));
            p.finish_and_clear();
        }
        report += &format!(
            "\n## Whole runs (each solver drives its own trajectory)\n\n{}",
            compare::whole_runs_markdown(&whole)
        );
    }
    println!("{report}");
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_in(dir, "solvers.md", &report)?;
        write_in(dir, "solver-steps.csv", &compare::csv(menu, &steps))?;
        compare::plot(&dir.join("solver-sweeps.png"), menu, &steps)?;
        eprintln!("wrote {}/solvers.md, solver-steps.csv and solver-sweeps.png", dir.display());
    }
    Ok(())
}

/// The study's spec: the models of --models, or the default set.
fn budget_spec(args: &Args, first_seed: u64) -> Result<sim::budget::BudgetSpec> {
    let models = if args.models.is_empty() {
        let mut names = vec!["none", "builtin", "blend:0.25", "blend:0.5", "blend:0.75"];
        if args.gnn_model.is_some() {
            names.push("gnn");
        }
        names.iter().map(|n| n.parse::<ModelSpec>().map_err(|e| anyhow::anyhow!("{e}"))).collect::<Result<_>>()?
    } else {
        args.models.clone()
    };
    Ok(sim::budget::BudgetSpec {
        scene: args.scene_config(first_seed),
        params: args.world_params(),
        steps: args.steps,
        budgets: args.budget_study.clone(),
        models,
        files: sim::ModelFiles { gnn: args.gnn_model.clone() },
        reference_tolerance: args.reference_tolerance,
        error_split: args.error_split,
        timing_repeats: args.timing_repeats,
    })
}

/// `dc-sim --budget-study`: the real-time regime's tables.
fn budget_study(args: &Args) -> Result<()> {
    use sim::budget;
    let seeds = args.seeds()?;
    let spec = budget_spec(args, seeds[0])?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let bar = seed_bar(seeds.len(), "budget study");
    let runs = budget::study(&spec, &seeds, |_| bar.inc(1))?;
    bar.finish_and_clear();
    let summaries = budget::summaries(&runs);
    let report = format!(
        "# The real-time regime: accuracy after a fixed sweep budget\n\n`dc-sim {}`\n\nSeeds {}, {} steps, {} bodies, solver {}, early stop when the natural residual <= {}; reference: {} to the natural residual <= {} (cap {}). Every run drives its own trajectory. Accuracy figures are means over the steps with contacts.\n\n{}",
        std::env::args().skip(1).collect::<Vec<_>>().join(" "),
        args.seeds.clone().unwrap_or_else(|| format!("{}..{}", args.seed, args.seed + args.simulations)),
        args.steps,
        args.n,
        spec.params.solve.setting(),
        spec.params.solve.tolerance,
        sim::SolverSetting::RECOMMENDED,
        spec.reference_tolerance,
        budget::REFERENCE_MAX_SWEEPS,
        budget::markdown(&summaries, &spec.budgets)
    );
    println!("{report}");
    if let Some(dir) = &args.out {
        write_in(dir, "budget.md", &report)?;
        write_in(dir, "budget-steps.csv", &budget::csv(&runs))?;
        budget::plot(&dir.join("budget-accuracy.png"), &summaries)?;
        eprintln!("wrote {}/budget.md, budget-steps.csv and budget-accuracy.png", dir.display());
    }
    Ok(())
}

/// Everything that would fail once the run started, checked before it starts (and when the
/// launcher checks a launch file): seeds, world parameters, the models (a learned model's file),
/// the scene.
fn check(args: &Args) -> Result<()> {
    if args.bench {
        // Each case is a run of its own size: the same bounds (counts, sizes, memory).
        for (n, steps) in args.bench_cases()? {
            let scene = SceneConfig { n, ..args.scene_config(args.seed) };
            RunSpec { scene, steps, ..args.run_spec(&[args.seed], 0, 0) }
                .validate()
                .with_context(|| format!("--bench-cases {n}:{steps}"))?;
        }
        return Ok(());
    }
    let seeds = args.seeds()?;
    // Counts, sizes and the memory they imply, before anything is allocated.
    args.run_spec(&seeds, 0, 0).validate()?;
    if args.out.is_some() && args.compare_solvers.is_none() && args.budget_study.is_empty() {
        bail!("--out is the folder of --compare-solvers or --budget-study; the node publishes on the bus");
    }
    if !args.budget_study.is_empty() {
        return Ok(budget_spec(args, seeds[0])?.validate()?);
    }
    if args.fallback.is_grid_based() {
        bail!("--fallback must be a local model, not `{}`", args.fallback.name());
    }
    let files = sim::ModelFiles { gnn: args.gnn_model.clone() };
    for m in if args.models.is_empty() { std::slice::from_ref(&args.model) } else { args.models.as_slice() } {
        if m.served_on().is_none() {
            m.build_with(args.seed, sim::warm::Served::default(), &files)?;
        }
    }
    sim::Scene::build(&args.scene_config(seeds[0])).context("building the scene")?;
    Ok(())
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(args) = runtime::parse_args_checked::<Args, _>(check) else { return Ok(()) };
    runtime::init_logging();
    if args.bench {
        return run_bench(&args);
    }
    if let Some(SolverMenu(menu)) = &args.compare_solvers {
        return compare_solvers(&args, menu);
    }
    if !args.budget_study.is_empty() {
        return budget_study(&args);
    }
    let seeds = args.seeds()?;

    let node = runtime::Node::from_env("dc-sim")?;
    let models = if args.models.is_empty() { vec![args.model] } else { args.models.clone() };
    let mut pubs = Publishers {
        bodies: node.publisher(msgs::topics::BODIES)?,
        contacts: node.publisher(msgs::topics::CONTACTS)?,
        stats: node.publisher(msgs::topics::SOLVE_STATS)?,
        control: node.publisher(msgs::topics::CONTROL)?,
        // `gnn-node` and `gnn-pipelined` send problems to their node themselves.
        problem: if args.publish_problem || models.iter().any(|m| m.kind.sends_problems()) {
            let pair = (node.publisher(msgs::topics::PROBLEM_BODIES)?, node.publisher(msgs::topics::PROBLEM_CONTACTS)?);
            Some(std::rc::Rc::new(std::cell::RefCell::new(pair)))
        } else {
            None
        },
    };
    // Runs whose model reads another node open its subscribers for the run only (see `run`).
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
    for (i, &model) in models.iter().enumerate() {
        if node.is_shutdown() {
            break;
        }
        // Each model is its own run, so downstream nodes can tell them apart.
        run(&args, &node, &mut pubs, model, &args.run_spec(&seeds, first_run_id, i))?;
    }
    Ok(())
}

/// The simulator's publishers.
struct Publishers {
    bodies: runtime::Publisher<StepHeader, msgs::Body>,
    contacts: runtime::Publisher<StepHeader, msgs::Contact>,
    stats: runtime::Publisher<msgs::SolveStatsHeader, f32>,
    control: runtime::Publisher<msgs::Control, u8>,
    /// With --publish-problem, or for `gnn-node` (which sends the problem before the solve).
    problem: Option<std::rc::Rc<std::cell::RefCell<ProblemPublishers>>>,
}

type ProblemPublishers =
    (runtime::Publisher<StepHeader, msgs::ProblemBody>, runtime::Publisher<msgs::ProblemHeader, msgs::ProblemContact>);

/// Publishes a step's problem (bodies first: a reader pairs them by step).
fn publish_problem(pubs: &mut ProblemPublishers, p: &sim::problem::Problem) -> Result<(), SimError> {
    let err = |topic: &str, e: runtime::Error| SimError::Output(format!("{topic}: {e}"));
    pubs.0.publish(&p.header.step, &p.bodies).map_err(|e| err("problem/bodies", e))?;
    pubs.1.publish(&p.header, &p.contacts).map_err(|e| err("problem/contacts", e))
}

/// What the step loop drains between steps: the source of a model that reads another node.
trait Drain {
    fn between_steps(&self, run_id: u64, simulation: u32, step: u32);
}

impl<F: StepFrame, I: Inbox<F>> Drain for SharedSource<I, F> {
    fn between_steps(&self, run_id: u64, simulation: u32, step: u32) {
        self.borrow_mut().between_steps(run_id, simulation, step);
    }
}

/// A run's outputs go to the bus; between steps the grid source (if any) drains its inbox.
struct BusSink<'a> {
    pubs: &'a mut Publishers,
    node: &'a runtime::Node,
    source: Option<Box<dyn Drain>>,
    run_id: u64,
    /// Publish each step's problem after it (--publish-problem; `gnn-node` sends it itself).
    publish_problem: bool,
    /// `--step-period`, and when the next step is due.
    pace: Option<(Duration, Instant)>,
}

impl RunSink for BusSink<'_> {
    fn control(&mut self, msg: &ControlMsg) -> Result<(), SimError> {
        self.pubs.control.publish_frame(msg).map_err(|e| SimError::Output(format!("control: {e}")))
    }
    fn before_step(&mut self, simulation: u32, step: u32) -> bool {
        if let Some((period, due)) = &mut self.pace {
            let now = Instant::now();
            if *due > now && !runtime::sleep_unless_shutdown(self.node, *due - now) {
                return false;
            }
            // Late steps do not bunch up to catch up: the next is due a period after this one.
            *due = (*due + *period).max(Instant::now());
        }
        if self.node.is_shutdown() {
            return false;
        }
        if let Some(source) = &self.source {
            source.between_steps(self.run_id, simulation, step);
        }
        true
    }
    fn step(&mut self, out: &StepOutput<'_>) -> Result<(), SimError> {
        let err = |topic: &str, e: runtime::Error| SimError::Output(format!("{topic}: {e}"));
        // The problem first: it is what the step started from.
        if let (true, Some(pubs), Some(p)) = (self.publish_problem, &self.pubs.problem, out.problem) {
            publish_problem(&mut pubs.borrow_mut(), p)?;
        }
        self.pubs.bodies.publish(&out.header, out.bodies).map_err(|e| err("bodies", e))?;
        self.pubs.contacts.publish(&out.header, out.contacts).map_err(|e| err("contacts", e))?;
        self.pubs.stats.publish(&out.stats.to_header(), out.residuals).map_err(|e| err("stats/solve", e))
    }
}

/// One run: every seed with one warm-start model.
fn run(args: &Args, node: &runtime::Node, pubs: &mut Publishers, model_kind: ModelSpec, spec: &RunSpec) -> Result<()> {
    // The grid subscriber exists only during a grid-based run: a grid producer publishes with
    // back-pressure, and a subscriber nobody reads (another model's run) would fill up and stall
    // the producer, which stalls the simulator in turn (a deadlock seen in `dc eval`). In lockstep
    // at most one grid is outstanding, so the loop cannot fill it.
    let waits = Waits {
        deadline: args.deadline.0,
        lockstep_timeout: args.lockstep_timeout,
        resume_patience: args.resume_patience,
    };
    let simulations: Vec<u32> = spec.seeds.iter().map(|&s| s as u32).collect();
    let files = sim::ModelFiles { gnn: args.gnn_model.clone() };
    // The models another node serves read the bus through a source that the run drains.
    macro_rules! open_source {
        ($topic:expr) => {
            std::rc::Rc::new(std::cell::RefCell::new(BusSource::new(
                BusInbox::open(node, node.subscriber($topic)?)?,
                waits,
                simulations,
            )))
        };
    }
    let (served, source): (sim::warm::Served, Option<Box<dyn Drain>>) = match (model_kind.grid_topic(), model_kind.kind)
    {
        (Some(topic), _) => {
            let source = open_source!(topic);
            (
                sim::warm::Served { grid: Some(Box::new(SourceHandle(source.clone()))), contact: None },
                Some(Box::new(source)),
            )
        }
        (None, kind) if kind.sends_problems() => {
            let source = open_source!(msgs::topics::WARM_GNN);
            let pubs = pubs.problem.clone().expect("opened for gnn-node");
            let send: sim::warm::ProblemSender =
                Box::new(move |p| publish_problem(&mut pubs.borrow_mut(), p).map_err(|e| e.to_string()));
            let contact = Some((send, Box::new(SourceHandle(source.clone())) as Box<dyn sim::warm::ContactWarmSource>));
            (sim::warm::Served { grid: None, contact }, Some(Box::new(source)))
        }
        (None, _) => (sim::warm::Served::default(), None),
    };
    let model = model_kind.build_with(args.seed, served, &files)?;
    let mut warm = WarmStarter::new(model, args.fallback.build(args.seed)?);
    let publish_problem = args.publish_problem && !model_kind.kind.sends_problems();
    let pace = args.step_period.map(|p| (p, Instant::now()));
    let mut sink = BusSink { pubs, node, source, run_id: spec.run_id, publish_problem, pace };
    let summary = sim::run::run(spec, &mut warm, &mut sink)?;
    // The run's totals on stdout (benchmarks read them).
    println!("{}", summary.line());
    Ok(())
}
