//! `dc-study` (`dc study`): the simulator's studies, in one process, no bus. `solvers`: settings
//! side by side on the same states; `budget`: the real-time regime; `bench`: our world against
//! rapier's full pipeline.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use sim::cli::{SceneArgs, SolveArgs, EVALUATION_SEEDS};
use sim::{ModelKind, ModelSpec, SolverSetting};
use std::path::{Path, PathBuf};
use study::{bench, budget, compare, threads};

#[derive(Parser, Debug)]
#[command(name = "dc-study", about = "Deep Contact studies of the simulator (no bus): solvers, budget, bench")]
struct Cli {
    #[command(subcommand)]
    study: Study,
}

#[derive(Subcommand, Debug)]
enum Study {
    /// Solvers side by side: every setting of SETTINGS solves every step of --seeds from
    /// builtin's warm start to the same stopping rule (--stop, --tolerance), the trajectory driven
    /// by the first; prints and writes the side-by-side table (with the hindsight ceiling) and
    /// every step's figures (docs/solvers.md).
    Solvers(SolversArgs),
    /// The real-time regime: at each budget of BUDGETS (`8` or `4,8`), every model of --models
    /// runs every seed with that many sweeps a step, placed on builtin's curve of accuracy
    /// against budget (1, 2, 4, ... 16K), the pile compared per phase with a reference run
    /// solved to --reference-tolerance; prints and writes the tables (docs/budget.md).
    Budget(BudgetArgs),
    /// The benchmark: ms/step of our world beside rapier's full pipeline on the same scenes.
    Bench(BenchArgs),
    /// What threads buy: every setting of SETTINGS solves the sampled steps' problems of --seeds
    /// (the trajectory --solver's) on every thread count of --counts, the median of --repeats
    /// timings kept; the answers compared across counts bit for bit (docs/solvers.md).
    Threads(ThreadsArgs),
}

#[derive(clap::Args, Debug)]
struct ThreadsArgs {
    /// The settings timed (`pgs/colour,nncg:1.2/colour,nncg:1.2/down`).
    #[arg(value_name = "SETTINGS", value_parser = |s: &str| sim::solver::parse_settings(s).map(SolverMenu))]
    menu: SolverMenu,
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    solve: SolveArgs,
    /// Thread counts, the first each setting's reference (default: 1 and the machine's cores).
    #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u32).range(1..=sim::solver::MAX_THREADS as i64))]
    counts: Vec<u32>,
    /// Time the solves of every E-th step only (from --sample-from).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..))]
    sample_every: u32,
    /// The first timed step.
    #[arg(long, default_value_t = 0)]
    sample_from: u32,
    /// Timings per solve (the median kept).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=15))]
    repeats: u32,
    /// The folder for `threads.md`.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// A list of solver settings. A newtype because clap reads `Vec<T>` as "many values".
#[derive(Debug, Clone)]
struct SolverMenu(Vec<SolverSetting>);

#[derive(clap::Args, Debug)]
struct SolversArgs {
    /// The settings, first the trajectory's (`pgs,sor:1.4,nncg,sor:1.4/down`).
    #[arg(value_name = "SETTINGS", value_parser = |s: &str| sim::solver::parse_settings(s).map(SolverMenu))]
    menu: SolverMenu,
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    solve: SolveArgs,
    /// Train a per-step choice among the settings on these seeds' same states and judge it on
    /// --seeds (never the evaluation seeds 0..29).
    #[arg(long)]
    train_seeds: Option<String>,
    /// Also run every seed with each setting (and the learned choice) driving its own trajectory.
    #[arg(long)]
    whole_runs: bool,
    /// Compare on every E-th step only (from --sample-from); the trajectory runs every step.
    /// For deep piles, where the slowest settings would take hours on every step.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    sample_every: u32,
    /// The first compared step.
    #[arg(long, default_value_t = 0)]
    sample_from: u32,
    /// The folder for `solvers.md`, `solver-steps.csv` and `solver-sweeps.png` (mean sweeps per
    /// step by solver).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct BudgetArgs {
    /// The budgets each model is judged at, sweeps per step (`8` or `4,8,16`).
    #[arg(value_name = "BUDGETS", required = true, value_delimiter = ',', value_parser = sim::cli::budget)]
    budgets: Vec<u32>,
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    solve: SolveArgs,
    /// The models judged (default none, builtin, blend:0.25, blend:0.5, blend:0.75, and gnn
    /// with --gnn-model); builtin always runs: it is the curve.
    #[arg(
        long,
        value_delimiter = ',',
        value_parser = |s: &str| s.parse::<ModelSpec>(),
        long_help = msgs::models::option_help("The models judged, `name` or `name:param`, comma-separated.")
    )]
    models: Vec<ModelSpec>,
    /// The contact-graph network's model file (`dc-gnn`), for the `gnn` model.
    #[arg(long)]
    gnn_model: Option<PathBuf>,
    /// The reference run's tolerance (natural residual).
    #[arg(long, default_value_t = 1e-6, value_parser = sim::cli::positive_f32)]
    reference_tolerance: f32,
    /// Also split each step's warm-start error into its smooth and rough parts beside
    /// builtin's on the same step (one more pass per judged run).
    #[arg(long)]
    error_split: bool,
    /// Time each seed's runs this many times, interleaved, and keep each step's median
    /// warm-start and solve time (the runs repeat the same steps; their timings move with the
    /// machine's load).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=15))]
    timing_repeats: u32,
    /// Also run builtin's curve with this solver (`nncg:1.2/down`) and place every model on it
    /// too: whether a learned start with --solver beats the better iteration at equal accuracy.
    #[arg(long, value_parser = |s: &str| s.parse::<SolverSetting>())]
    against: Option<SolverSetting>,
    /// The folder for `budget.md`, `budget-steps.csv` and `budget-accuracy.png`.
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct BenchArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    solve: SolveArgs,
    /// Benchmark cases `n:steps,...` (N=10,000 needs ~300 steps before its balls land).
    #[arg(long, default_value = "100:250,1000:250,10000:400")]
    cases: String,
}

impl BenchArgs {
    /// The `n:steps` cases.
    fn cases(&self) -> Result<Vec<(usize, u32)>> {
        let mut cases = Vec::new();
        for part in self.cases.split(',') {
            let (n, steps) = part.split_once(':').context("--cases: expected n:steps,...")?;
            let n = n.trim().parse().with_context(|| format!("--cases `{part}`: n"))?;
            let steps = steps.trim().parse().with_context(|| format!("--cases `{part}`: steps"))?;
            cases.push((n, steps));
        }
        Ok(cases)
    }
}

impl BudgetArgs {
    /// The study's spec: the models of --models, or the default set.
    fn spec(&self, first_seed: u64) -> Result<budget::BudgetSpec> {
        let models = if self.models.is_empty() {
            let mut names = vec!["none", "builtin", "blend:0.25", "blend:0.5", "blend:0.75"];
            if self.gnn_model.is_some() {
                names.push("gnn");
            }
            names.iter().map(|n| n.parse::<ModelSpec>().map_err(|e| anyhow::anyhow!("{e}"))).collect::<Result<_>>()?
        } else {
            self.models.clone()
        };
        Ok(budget::BudgetSpec {
            scene: self.scene.scene_config(first_seed),
            params: self.solve.world_params(None),
            steps: self.scene.steps,
            budgets: self.budgets.clone(),
            models,
            files: sim::ModelFiles { gnn: self.gnn_model.clone() },
            reference_tolerance: self.reference_tolerance,
            error_split: self.error_split,
            timing_repeats: self.timing_repeats,
            against: self.against,
        })
    }
}

/// The training seeds of --train-seeds, never an evaluation seed.
fn training_seeds(list: &str) -> Result<Vec<u64>> {
    let train = sim::parse_seeds(list)?;
    if let Some(s) = train.iter().find(|&&s| EVALUATION_SEEDS.contains(&s)) {
        bail!("--train-seeds {list}: seed {s} is an evaluation seed (0..29 are never trained on)");
    }
    Ok(train)
}

/// A sampled study's first step lies inside its runs, and its scene builds.
fn check_sampling(scene: &SceneArgs, sample_from: u32, first_seed: u64, what: &str) -> Result<()> {
    if sample_from >= scene.steps {
        bail!("--sample-from {sample_from}: the runs have {} steps, so no step would be {what}", scene.steps);
    }
    sim::Scene::build(&scene.scene_config(first_seed)).context("building the scene")?;
    Ok(())
}

/// Everything that would fail once the study started, checked before it starts.
fn check(cli: &Cli) -> Result<()> {
    match &cli.study {
        Study::Solvers(a) => {
            let seeds = a.scene.checked_seeds(a.solve.world_params(None))?;
            if let Some(list) = &a.train_seeds {
                training_seeds(list)?;
            }
            check_sampling(&a.scene, a.sample_from, seeds[0], "compared")?;
        }
        Study::Budget(a) => {
            let seeds = a.scene.checked_seeds(a.solve.world_params(None))?;
            a.spec(seeds[0])?.validate()?;
        }
        Study::Threads(a) => {
            let seeds = a.scene.checked_seeds(a.solve.world_params(None))?;
            check_sampling(&a.scene, a.sample_from, seeds[0], "timed")?;
        }
        Study::Bench(a) => {
            // Each case is a run of its own size: the same bounds (counts, sizes, memory).
            for (n, steps) in a.cases()? {
                let scene = SceneArgs { n, steps, seeds: None, simulations: 1, ..a.scene.clone() };
                scene.checked_seeds(a.solve.world_params(None)).with_context(|| format!("--cases {n}:{steps}"))?;
            }
        }
    }
    Ok(())
}

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
fn write_in(dir: &Path, name: &str, text: &str) -> Result<()> {
    let path = dir.join(name);
    std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))
}

/// The command line as the reports quote it.
fn command_line() -> String {
    std::env::args().skip(1).collect::<Vec<_>>().join(" ")
}

/// `dc study solvers`: the same-states table, the chooser, whole runs.
fn solvers(args: &SolversArgs) -> Result<()> {
    let menu = &args.menu.0;
    let seeds = args.scene.seeds()?;
    let spec = compare::CompareSpec {
        scene: args.scene.scene_config(seeds[0]),
        params: args.solve.world_params(None),
        steps: args.scene.steps,
        menu: menu.clone(),
        sampling: compare::Sampling { from: args.sample_from, every: args.sample_every },
    };
    let mut describe = format!(
        "{} steps, stop {} <= {}, cap {}, friction {}, {} bodies",
        args.scene.steps,
        spec.params.solve.stop.name(),
        spec.params.solve.tolerance,
        spec.params.solve.max_sweeps,
        spec.params.solve.friction,
        args.scene.n
    );
    if let Some(us) = spec.params.solve.time_budget_us {
        describe += &format!(", at most {:.3} ms a solve", us / 1e3);
    }
    if !spec.sampling.is_every_step() {
        describe += &format!(", compared on every {}th step from step {}", args.sample_every, args.sample_from);
    }
    let chooser = match &args.train_seeds {
        Some(list) => {
            let train = training_seeds(list)?;
            let p = seed_bar(train.len(), "same states, training seeds");
            let steps = compare::same_states(&spec, &train, |_| p.inc(1))?;
            p.finish_and_clear();
            Some(compare::SolverChooser::fit(menu, &steps)?)
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
        "# Solvers on the same states\n\n`dc study {}`\n\nSeeds {}, {describe}; builtin's warm start; the trajectory is {}'s.\n\n{}",
        command_line(),
        args.scene.seeds_label(),
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
    report += &format!("\nSettling: {}.\n", compare::settling(&steps, args.scene.steps));
    if args.whole_runs {
        let mut whole = Vec::new();
        let choices = menu.iter().map(|&s| (s.to_string(), compare::Choice::Fixed(s)));
        for (name, choice) in
            choices.chain(chooser.as_ref().map(|c| ("learned choice".to_string(), compare::Choice::Learned(c))))
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
    runtime::print_out(&format!("{report}\n"))?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_in(dir, "solvers.md", &report)?;
        write_in(dir, "solver-steps.csv", &compare::csv(menu, &steps))?;
        compare::plot(&dir.join("solver-sweeps.png"), menu, &steps)?;
        eprintln!("wrote {}/solvers.md, solver-steps.csv and solver-sweeps.png", dir.display());
    }
    Ok(())
}

/// `dc study budget`: the real-time regime's tables.
fn budget_study(args: &BudgetArgs) -> Result<()> {
    let seeds = args.scene.seeds()?;
    let spec = args.spec(seeds[0])?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let bar = seed_bar(seeds.len(), "budget study");
    let runs = budget::study(&spec, &seeds, |_| bar.inc(1))?;
    bar.finish_and_clear();
    let summaries = budget::summaries(&runs);
    let report = format!(
        "# The real-time regime: accuracy after a fixed sweep budget\n\n`dc study {}`\n\nSeeds {}, {} steps, {} bodies, solver {}, early stop when the natural residual <= {}; reference: {} to the natural residual <= {} (cap {}). Every run drives its own trajectory. Accuracy figures are means over the steps with contacts.\n\n{}",
        command_line(),
        args.scene.seeds_label(),
        args.scene.steps,
        args.scene.n,
        spec.params.solve.setting(),
        spec.params.solve.tolerance,
        SolverSetting::RECOMMENDED,
        spec.reference_tolerance,
        budget::REFERENCE_MAX_SWEEPS,
        budget::markdown(&summaries, &spec.budgets)
    );
    runtime::print_out(&format!("{report}\n"))?;
    if let Some(dir) = &args.out {
        write_in(dir, "budget.md", &report)?;
        write_in(dir, "budget-steps.csv", &budget::csv(&runs))?;
        budget::plot(&dir.join("budget-accuracy.png"), &summaries)?;
        eprintln!("wrote {}/budget.md, budget-steps.csv and budget-accuracy.png", dir.display());
    }
    Ok(())
}

/// `dc study threads`: what the colour order's threads buy on the same states.
fn threads_study(args: &ThreadsArgs) -> Result<()> {
    let seeds = args.scene.seeds()?;
    let counts: Vec<usize> = if args.counts.is_empty() {
        let cores = sim::solver::machine_cores();
        if cores > 1 {
            vec![1, cores]
        } else {
            vec![1]
        }
    } else {
        args.counts.iter().map(|&c| c as usize).collect()
    };
    let spec = threads::ThreadsSpec {
        scene: args.scene.scene_config(seeds[0]),
        params: args.solve.world_params(None),
        steps: args.scene.steps,
        settings: args.menu.0.clone(),
        counts: counts.clone(),
        from: args.sample_from,
        every: args.sample_every,
        repeats: args.repeats,
    };
    let bar = seed_bar(seeds.len(), "thread study");
    let table = threads::run(&spec, &seeds, || bar.inc(1))?;
    bar.finish_and_clear();
    let report = format!(
        "# Threads on the same states\n\n`dc study {}`\n\nSeeds {}, {} bodies, friction {}, stop {} <= {}, cap {}; every {}th step from {} of the trajectory ({}), solved from builtin's warm start; the median of {} timings per solve, summed over the problems; {} cores. Every setting gave the same answer on every thread count.\n\n{}",
        command_line(),
        args.scene.seeds_label(),
        args.scene.n,
        spec.params.solve.friction,
        spec.params.solve.stop.name(),
        spec.params.solve.tolerance,
        spec.params.solve.max_sweeps,
        args.sample_every,
        args.sample_from,
        spec.params.solve.setting(),
        args.repeats,
        sim::solver::machine_cores(),
        threads::markdown(&table)
    );
    runtime::print_out(&format!("{report}\n"))?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_in(dir, "threads.md", &report)?;
        eprintln!("wrote {}/threads.md", dir.display());
    }
    Ok(())
}

/// `dc study bench`: ms/step against rapier's pipeline.
fn run_bench(args: &BenchArgs) -> Result<()> {
    let cases = args.cases()?;
    let base = args.scene.scene_config(args.scene.seed);
    let params = args.solve.world_params(None);
    runtime::print_out(&format!(
        "dc study bench: scene {}, seed {}, tolerance {}, max sweeps {}; rapier = its full PhysicsPipeline, default parameters\n{}\n",
        base.kind.name(),
        base.seed,
        params.solve.tolerance,
        params.solve.max_sweeps,
        bench::TABLE_HEADER
    ))?;
    let mut printed = Ok(());
    bench::run(&base, params, &cases, &[ModelKind::None, ModelKind::Builtin], |r| {
        if printed.is_ok() {
            printed = runtime::print_out(&format!("{}\n", bench::format_row(r)));
        }
    })?;
    printed
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(cli) = runtime::parse_args_checked::<Cli, _>(check) else { return Ok(()) };
    runtime::init_logging();
    let solve = match &cli.study {
        Study::Solvers(a) => &a.solve,
        Study::Budget(a) => &a.solve,
        Study::Bench(a) => &a.solve,
        Study::Threads(a) => &a.solve,
    };
    solve.start_threads().with_context(|| format!("--threads {}", solve.threads))?;
    match &cli.study {
        Study::Solvers(a) => solvers(a),
        Study::Budget(a) => budget_study(a),
        Study::Bench(a) => run_bench(a),
        Study::Threads(a) => threads_study(a),
    }
}
