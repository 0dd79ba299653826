//! `dc-study` (`dc study`): the simulator's studies, in one process, no bus. `solvers`: settings
//! side by side on the same states; `budget`: the real-time regime; `bench`: our world against
//! rapier's full pipeline.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use msgs::shard::format_seeds;
use runtime::shard::RunningShard;
use sim::cli::{SceneArgs, SolveArgs, EVALUATION_SEEDS};
use sim::{ModelKind, ModelSpec, SolverSetting};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use study::shards::{self, BudgetRunData, ShardData, SolverStep, StudyData, WholeTotals};
use study::{bench, budget, compare, friction, threads};

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
    /// What the per-step friction law costs in physics: every seed of --seeds runs under both
    /// laws (--friction is ignored) with the same solver; the pile's height and spread, the
    /// penetrations, the late kinetic energy and body speed of each law compared with the Box2D
    /// law's own variation between seeds (docs/solvers.md).
    Friction(FrictionArgs),
    /// The report of a study run in shards (`--shard I/N`), from the shards' folders in any order
    /// (what `dc report merge` runs for a study): the tables the study makes on one host, or
    /// refused, naming the shard, setting or seeds, with nothing written.
    Merge(MergeArgs),
}

#[derive(clap::Args, Debug)]
struct MergeArgs {
    #[arg(required = true, value_name = "SHARD_DIR")]
    dirs: Vec<PathBuf>,
    /// Where the merged report goes.
    #[arg(long)]
    out: PathBuf,
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

#[derive(clap::Args, Debug)]
struct FrictionArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    solve: SolveArgs,
    /// The late window: the last this many steps of each run, over which the late costs (and
    /// the pile's height and spread) are averaged.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..))]
    late: u32,
    /// The folder for `friction.md` and `friction-runs.csv`.
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
    /// Run only the I-th of N parts of the seeds (I from 0; an array job's task, docs/cluster.md):
    /// --out gets this part's report, `shard.json` and `study.cbor`; `dc report merge` makes the
    /// study's one report from all N.
    #[arg(long, value_name = "I/N", requires = "out")]
    shard: Option<msgs::shard::Shard>,
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
    /// Run only the I-th of N parts of the seeds (I from 0; an array job's task, docs/cluster.md):
    /// --out gets this part's report, `shard.json` and `study.cbor`; `dc report merge` makes the
    /// study's one report from all N.
    #[arg(long, value_name = "I/N", requires = "out")]
    shard: Option<msgs::shard::Shard>,
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
                if a.shard.is_some() {
                    bail!(
                        "--shard with --train-seeds: the learned choice is trained on every shard's behalf and the merge would train it again; run the study with --train-seeds on one host"
                    );
                }
            }
            shard_part(a.shard, &seeds)?;
            check_sampling(&a.scene, a.sample_from, seeds[0], "compared")?;
        }
        Study::Budget(a) => {
            let seeds = a.scene.checked_seeds(a.solve.world_params(None))?;
            shard_part(a.shard, &seeds)?;
            a.spec(seeds[0])?.validate()?;
        }
        Study::Merge(_) => {}
        Study::Threads(a) => {
            let seeds = a.scene.checked_seeds(a.solve.world_params(None))?;
            check_sampling(&a.scene, a.sample_from, seeds[0], "timed")?;
        }
        Study::Friction(a) => {
            let seeds = a.scene.checked_seeds(a.solve.world_params(None))?;
            if seeds.len() < 2 {
                bail!("--seeds: the friction study needs at least 2 seeds (it judges the laws against the Box2D law's variation between seeds)");
            }
            if a.late > a.scene.steps {
                bail!("--late {}: the runs have {} steps", a.late, a.scene.steps);
            }
            sim::Scene::build(&a.scene.scene_config(seeds[0])).context("building the scene")?;
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
    progress_bar(len, what, "seeds")
}

/// A bar over `len` units of work (`seeds`, `runs`).
fn progress_bar(len: usize, what: &str, units: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{{msg}} [{{bar:30}}] {{pos}}/{{len}} {units}, {{elapsed}}, ~{{eta}} left"
        ))
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

/// `dc study solvers`: the same-states table, the chooser, whole runs (of a shard's seeds with
/// --shard, kept for the merge).
fn solvers(args: &SolversArgs) -> Result<()> {
    let seeds = args.scene.seeds()?;
    let Some(shard) = args.shard else {
        let (steps, chooser, whole) = solvers_compute(args, &seeds)?;
        let label = args.scene.seeds_label();
        return solvers_report(args, &command_line(), &label, &steps, chooser.as_ref(), &whole, args.out.as_deref());
    };
    let out = args.out.as_deref().context("--shard needs --out")?;
    let (running, part) = start_shard("dc study solvers", shard, &seeds, out, "Solvers on the same states", None)?;
    let result = (|| {
        let (steps, _, whole) = solvers_compute(args, &part)?;
        solvers_report(args, &command_line(), &format_seeds(&part), &steps, None, &whole, Some(out))?;
        let data = StudyData::Solvers {
            format: shards::FORMAT,
            steps: steps.iter().map(SolverStep::of).collect(),
            whole: whole.iter().map(|(name, t)| (name.clone(), WholeTotals::of(t))).collect(),
        };
        data.write(out)?;
        Ok(())
    })();
    running.finish(result)
}

/// The same-states spec of `dc study solvers` on `seeds`.
fn solvers_spec(args: &SolversArgs, first_seed: u64) -> compare::CompareSpec {
    compare::CompareSpec {
        scene: args.scene.scene_config(first_seed),
        params: args.solve.world_params(None),
        steps: args.scene.steps,
        menu: args.menu.0.clone(),
        sampling: compare::Sampling { from: args.sample_from, every: args.sample_every },
    }
}

type SolversResults = (Vec<compare::ComparedStep>, Option<compare::SolverChooser>, Vec<(String, compare::RunTotals)>);

/// What `dc study solvers` computes on `seeds`: the same states, the chooser (--train-seeds),
/// the whole runs (--whole-runs).
fn solvers_compute(args: &SolversArgs, seeds: &[u64]) -> Result<SolversResults> {
    let menu = &args.menu.0;
    let spec = solvers_spec(args, seeds[0]);
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
    let steps = compare::same_states(&spec, seeds, |_| p.inc(1))?;
    p.finish_and_clear();
    let mut whole = Vec::new();
    if args.whole_runs {
        let choices = menu.iter().map(|&s| (s.to_string(), compare::Choice::Fixed(s)));
        for (name, choice) in
            choices.chain(chooser.as_ref().map(|c| ("learned choice".to_string(), compare::Choice::Learned(c))))
        {
            let p = seed_bar(seeds.len(), &format!("whole runs, {name}"));
            whole.push((name, compare::whole_run(&spec, seeds, choice, |_| p.inc(1))?));
            p.finish_and_clear();
        }
    }
    Ok((steps, chooser, whole))
}

/// `dc study solvers`' report of `steps` (seeds `seeds_label`), printed and written to `out`.
fn solvers_report(
    args: &SolversArgs,
    command: &str,
    seeds_label: &str,
    steps: &[compare::ComparedStep],
    chooser: Option<&compare::SolverChooser>,
    whole: &[(String, compare::RunTotals)],
    out: Option<&Path>,
) -> Result<()> {
    let menu = &args.menu.0;
    let spec = solvers_spec(args, steps.first().map_or(0, |s| s.seed));
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
    // The chooser pays, every step, its features' extraction and its pick (the median pick).
    let pick_us = chooser.map(|c| c.median_pick_us(steps));
    let rows = compare::same_states_table(menu, steps, chooser.zip(pick_us));
    let mut report = format!(
        "# Solvers on the same states\n\n`dc study {command}`\n\nSeeds {seeds_label}, {describe}; builtin's warm start; the trajectory is {}'s.\n\n{}",
        menu[0],
        compare::markdown(&rows)
    );
    if let (Some(c), Some(us)) = (chooser, pick_us) {
        let shares: Vec<String> = menu.iter().zip(c.picks(steps)).map(|(m, k)| format!("{m} {k}")).collect();
        let features_us = charts::median(&steps.iter().map(|s| s.features_us as f64).collect::<Vec<_>>());
        report += &format!(
            "\nThe learned choice's picks (steps): {}; per step {features_us:.2} us for the features and {us:.2} us for the pick (medians).\n",
            shares.join(", ")
        );
    }
    if let Some(factor) = compare::factorisation_markdown(menu, steps) {
        report += &format!("\n## Where a factorising solver's time goes\n\n{factor}");
    }
    if let Some(coarse) = compare::coarse_markdown(menu, steps) {
        report += &format!("\n## What the coarse correction does\n\n{coarse}");
    }
    report += &format!("\nSettling: {}.\n", compare::settling(steps, args.scene.steps));
    if args.whole_runs {
        report += &format!(
            "\n## Whole runs (each solver drives its own trajectory)\n\n{}",
            compare::whole_runs_markdown(whole)
        );
    }
    runtime::print_out(&format!("{report}\n"))?;
    if let Some(dir) = out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_in(dir, "solvers.md", &report)?;
        write_in(dir, "solver-steps.csv", &compare::csv(menu, steps))?;
        compare::plot(&dir.join("solver-sweeps.png"), menu, steps)?;
        eprintln!("wrote {}/solvers.md, solver-steps.csv and solver-sweeps.png", dir.display());
    }
    Ok(())
}

/// `dc study budget`: the real-time regime's tables (of a shard's seeds with --shard, kept for
/// the merge).
fn budget_study(args: &BudgetArgs) -> Result<()> {
    let seeds = args.scene.seeds()?;
    let Some(shard) = args.shard else {
        let runs = budget_compute(args, &seeds)?;
        return budget_report(args, &command_line(), &args.scene.seeds_label(), &runs, args.out.as_deref());
    };
    let out = args.out.as_deref().context("--shard needs --out")?;
    let title = "The real-time regime: accuracy after a fixed sweep budget";
    let (running, part) = start_shard("dc study budget", shard, &seeds, out, title, args.gnn_model.as_deref())?;
    let result = (|| {
        let runs = budget_compute(args, &part)?;
        budget_report(args, &command_line(), &format_seeds(&part), &runs, Some(out))?;
        StudyData::Budget { format: shards::FORMAT, runs: runs.iter().map(BudgetRunData::of).collect() }.write(out)?;
        Ok(())
    })();
    running.finish(result)
}

/// Every run of `dc study budget` on `seeds`.
fn budget_compute(args: &BudgetArgs, seeds: &[u64]) -> Result<Vec<budget::BudgetRun>> {
    let spec = args.spec(seeds[0])?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let bar = seed_bar(seeds.len(), "budget study");
    let runs = budget::study(&spec, seeds, |_| bar.inc(1))?;
    bar.finish_and_clear();
    Ok(runs)
}

/// `dc study budget`'s report of `runs` (seeds `seeds_label`), printed and written to `out`.
fn budget_report(
    args: &BudgetArgs,
    command: &str,
    seeds_label: &str,
    runs: &[budget::BudgetRun],
    out: Option<&Path>,
) -> Result<()> {
    let spec = args.spec(args.scene.seed)?;
    let summaries = budget::summaries(runs);
    let report = format!(
        "# The real-time regime: accuracy after a fixed sweep budget\n\n`dc study {command}`\n\nSeeds {seeds_label}, {} steps, {} bodies, solver {}, early stop when the natural residual <= {}; reference: {} to the natural residual <= {} (cap {}). Every run drives its own trajectory. Accuracy figures are means over the steps with contacts.\n\n{}",
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
    if let Some(dir) = out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_in(dir, "budget.md", &report)?;
        write_in(dir, "budget-steps.csv", &budget::csv(runs))?;
        budget::plot(&dir.join("budget-accuracy.png"), &summaries)?;
        eprintln!("wrote {}/budget.md, budget-steps.csv and budget-accuracy.png", dir.display());
    }
    Ok(())
}

/// `--shard`'s part of `seeds` (all of them without it); an empty part is refused.
fn shard_part(shard: Option<msgs::shard::Shard>, seeds: &[u64]) -> Result<Vec<u64>> {
    match shard {
        None => Ok(seeds.to_vec()),
        Some(shard) => shard.seeds(seeds).map_err(|e| anyhow::anyhow!("--shard {e}")),
    }
}

/// This process's arguments without `--shard` and `--out` (and their values): the study as one
/// host would run it, what the merge parses again.
fn own_arguments() -> Vec<String> {
    let mut own = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--shard" || a == "--out" {
            args.next();
        } else if !(a.starts_with("--shard=") || a.starts_with("--out=")) {
            own.push(a);
        }
    }
    own
}

/// A study's settings by name, as its arguments give them (defaults included), but where it
/// writes: what two shards of one run must agree on.
fn settings_of(arguments: &[String]) -> Result<BTreeMap<String, String>> {
    let argv = std::iter::once("dc-study".to_string()).chain(arguments.iter().cloned());
    let matches = <Cli as clap::CommandFactory>::command().try_get_matches_from(argv)?;
    let Some((name, sub)) = matches.subcommand() else { bail!("no study in the arguments") };
    let command = <Cli as clap::CommandFactory>::command();
    // The study's own arguments (its flattened groups' names are not settings).
    let own: std::collections::BTreeSet<String> = command
        .find_subcommand(name)
        .map(|c| c.get_arguments().map(|a| a.get_id().to_string()).collect())
        .unwrap_or_default();
    let mut settings = BTreeMap::new();
    for id in sub.ids().filter(|id| own.contains(id.as_str())) {
        if let Ok(Some(values)) = sub.try_get_raw(id.as_str()) {
            let joined: Vec<String> = values.map(|v| v.to_string_lossy().into_owned()).collect();
            settings.insert(id.to_string(), joined.join(","));
        }
    }
    Ok(settings)
}

/// A shard of `command` started: its manifest written `running` into `out`; its seeds.
fn start_shard<'a>(
    command: &str,
    shard: msgs::shard::Shard,
    seeds: &[u64],
    out: &'a Path,
    title: &str,
    model: Option<&Path>,
) -> Result<(RunningShard<'a>, Vec<u64>)> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let arguments = own_arguments();
    let mut settings = settings_of(&arguments)?;
    if let Some(model) = model {
        settings.insert("gnn-model sha256".into(), runtime::shard::file_sha256(model).context("--gnn-model")?);
    }
    let exe = std::env::current_exe().context("finding dc-study itself to hash it")?;
    let build = runtime::shard::build_of([exe.as_path()])?;
    let running = RunningShard::start(out, command, shard, seeds, settings, build, title, arguments, shards::FILE)?;
    Ok((running, shard_part(Some(shard), seeds)?))
}

/// `dc study merge`: a sharded study's report from its shards' folders.
fn merge(args: &MergeArgs) -> Result<()> {
    let shards = msgs::shard::gather(&args.dirs)?;
    let canonical = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    if let Some(dir) = args.dirs.iter().find(|d| canonical(d) == canonical(&args.out)) {
        bail!(
            "--out {} is one of the shard folders ({}): the merge would overwrite a shard's report",
            args.out.display(),
            dir.display()
        );
    }
    let first = &shards[0];
    let argv = std::iter::once("dc-study".to_string()).chain(first.manifest.arguments.iter().cloned());
    let cli = Cli::try_parse_from(argv).map_err(|e| {
        anyhow::anyhow!(
            "{}: the study's arguments do not parse: {e}",
            first.dir.join(msgs::shard::Manifest::FILE).display()
        )
    })?;
    let mut data = Vec::new();
    for s in &shards {
        data.push(ShardData { dir: s.dir.clone(), seeds: s.manifest.seeds.clone(), data: StudyData::read(&s.dir)? });
    }
    let command = format!("{} (merged from {} shards)", first.manifest.arguments.join(" "), shards.len());
    match &cli.study {
        Study::Solvers(a) => {
            let (steps, whole) = shards::join_solvers(&data)?;
            solvers_report(a, &command, &a.scene.seeds_label(), &steps, None, &whole, Some(&args.out))?;
        }
        Study::Budget(a) => {
            let runs = shards::join_budget(&data)?;
            budget_report(a, &command, &a.scene.seeds_label(), &runs, Some(&args.out))?;
        }
        _ => bail!("{}: `{}` is not a study that runs in shards", first.dir.display(), first.manifest.command),
    }
    let path = args.out.join("merged.json");
    let text = serde_json::to_string_pretty(&msgs::shard::summary(&shards))?;
    std::fs::write(&path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    eprintln!("merged {} shards: {}", shards.len(), path.display());
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
        Study::Friction(a) => &a.solve,
        Study::Merge(a) => return merge(a),
    };
    solve.start_threads().with_context(|| format!("--threads {}", solve.threads))?;
    match &cli.study {
        Study::Merge(a) => merge(a),
        Study::Solvers(a) => solvers(a),
        Study::Budget(a) => budget_study(a),
        Study::Bench(a) => run_bench(a),
        Study::Threads(a) => threads_study(a),
        Study::Friction(a) => friction_study(a),
    }
}

/// `dc study friction`: both laws on every seed, the costs judged against the Box2D law's own
/// variation between seeds.
fn friction_study(args: &FrictionArgs) -> Result<()> {
    let seeds = args.scene.seeds()?;
    let spec = friction::FrictionSpec {
        scene: args.scene.scene_config(seeds[0]),
        params: args.solve.world_params(None),
        steps: args.scene.steps,
        late: args.late,
    };
    let bar = progress_bar(2 * seeds.len(), "friction study", "runs");
    let mut runs = Vec::with_capacity(2 * seeds.len());
    for &seed in &seeds {
        for law in [sim::solver::FrictionModel::Box, sim::solver::FrictionModel::PerStep] {
            runs.push(friction::run(&spec, seed, law).with_context(|| format!("seed {seed}, friction {law}"))?);
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    let verdicts = friction::verdicts(&runs);
    let outside: Vec<&str> = verdicts.iter().filter(|v| !v.within).map(|v| v.cost).collect();
    let verdict = if outside.is_empty() {
        "every cost of the per-step law is within the Box2D law's own variation between seeds".to_string()
    } else {
        format!("outside the Box2D law's own variation between seeds: {}", outside.join(", "))
    };
    let report = format!(
        "# The per-step friction law against the Box2D law\n\n`dc study {}`\n\nScene {}, {} bodies, seeds {}, {} steps, solver {} ({} <= {}, cap {}); late costs over the last {} steps. A cost is within when the laws' means differ by no more than the Box2D law's largest deviation of one seed from its own mean.\n\n{}\nVerdict: {verdict}.\n",
        command_line(),
        args.scene.scene.name(),
        args.scene.n,
        args.scene.seeds_label(),
        args.scene.steps,
        spec.params.solve.setting(),
        spec.params.solve.stop.name(),
        spec.params.solve.tolerance,
        spec.params.solve.max_sweeps,
        args.late,
        friction::markdown(&runs),
    );
    runtime::print_out(&format!("{report}\n"))?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_in(dir, "friction.md", &report)?;
        write_in(dir, "friction-runs.csv", &friction::csv(&runs))?;
        eprintln!("wrote {}/friction.md and friction-runs.csv", dir.display());
    }
    Ok(())
}
