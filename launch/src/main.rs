//! `dc`: the Deep Contact command — launch node graphs, run single nodes, inspect graphs, bench.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use launch::graph::{find_binary, Graph, NodeSpec, DEFAULT_HOST};
use launch::supervisor::{self, Output, RunError};
use launch::unique_namespace;
use msgs::RunSummary;
use runtime::Transport;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

mod bench_bus;
mod bench_observe;
mod topic;

#[derive(Parser)]
#[command(name = "dc", version, about = "Deep Contact: learning warm starts for rigid-body contact solvers")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Start this host's nodes of a launch file and supervise them.
    Launch {
        file: PathBuf,
        /// Which host of the file this machine is (default: the only host, or `local`).
        #[arg(long)]
        host: Option<String>,
        /// Bus namespace (default: the file's); separates graphs running side by side.
        #[arg(long)]
        namespace: Option<String>,
        /// Show what would start where and over which transport, then exit.
        #[arg(long)]
        dry_run: bool,
        /// Run programs the file names that are not dc's own node binaries (`dc-*` beside dc),
        /// or with an environment that chooses what code runs: checking the graph runs them.
        #[arg(long)]
        trust: bool,
        /// With several hosts: how long to wait for the other hosts' nodes before giving up
        /// (`120s`, `500ms`; a unit is required: a bare `120` is ambiguous here).
        #[arg(long, default_value = "120s", value_parser = duration_with_unit)]
        wait_hosts: std::time::Duration,
        /// How long this host's nodes may take to be ready (ports made: a model loaded, a
        /// server's packages imported); meanwhile dc says whom it waits for.
        #[arg(long, default_value = "120s", value_parser = duration_with_unit)]
        ready_timeout: std::time::Duration,
        /// Run the I-th of N parts of the graph's seeds (an array job's task: docs/cluster.md):
        /// every node's `seeds` becomes its part, each recorder writes `NAME.shard-I-of-N.mcap`
        /// (or under `DIR/shard-I-of-N/`), the namespace gains `-shard-I`. Every host of a
        /// several-host graph runs the file with the same --shard.
        #[arg(long, value_name = "I/N")]
        shard: Option<msgs::shard::Shard>,
    },
    /// Start one node by hand: `dc run sim --steps 10` runs `dc-sim --steps 10`.
    Run {
        node: String,
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Print the graph of a launch file (asking dc's own node binaries for their topics; other
    /// programs the file names are refused unless --trust).
    List {
        file: PathBuf,
        /// Run programs the file names that are not dc's own node binaries, to ask their topics.
        #[arg(long)]
        trust: bool,
    },
    /// Record a running graph (`dc record -a`, `dc record TOPIC...`, `-o FILE`), inspect and
    /// repair recordings (`dc record info FILE`, `dc record recover IN OUT`); runs dc-record.
    Record {
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Publish a recording onto the bus (runs dc-replay): `dc play FILE [--rate R] [--loop]
    /// [--topics a,b] [--remap A=B] [--namespace NS]`, so a recorded run can be watched in
    /// Foxglove or fed to a node.
    Play {
        /// The recording (.mcap), or a folder of recordings played in name order.
        file: PathBuf,
        /// dc-replay's options (`dc play FILE --help` lists them).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Train a warm-start model from recordings: `--model unet` (default; runs `dc-unet train`)
    /// or `--model gnn` (runs `dc-gnn-train`); the other arguments go to it (`--help` lists them).
    Train {
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// The thesis protocol: every warm-start model on the same seeds, one report comparing them.
    Eval(Box<EvalArgs>),
    /// Reports: `dc report merge SHARD_DIR... --out DIR` makes one report from the shards of
    /// `dc eval --shard I/N` (runs `dc-metrics --merge`) or `dc study solvers|budget --shard I/N`
    /// (runs `dc-study merge`).
    Report {
        #[command(subcommand)]
        what: ReportWhat,
    },
    /// The simulator's studies, in one process (runs dc-study): `dc study solvers SETTINGS`
    /// (solvers side by side on the same states), `dc study budget BUDGETS` (the real-time
    /// regime), `dc study bench` (our world against rapier's pipeline), `dc study threads SETTINGS` (what the colour order's threads buy); `--help` lists each one's flags.
    #[command(disable_help_flag = true)]
    Study {
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: BenchWhat,
    },
    /// Shell completions for dc: `dc completions bash > ~/.local/share/bash-completion/completions/dc`
    /// (zsh: into a folder of `$fpath` as `_dc`; also fish, elvish, powershell).
    Completions { shell: clap_complete::Shell },
    /// The nodes of the graphs running on this machine: `dc node list`.
    Node {
        #[command(subcommand)]
        what: NodeWhat,
    },
    /// A running graph's topics: `dc topic list | info TOPIC | echo TOPIC | hz TOPIC | bw TOPIC`.
    Topic {
        #[command(subcommand)]
        what: TopicWhat,
    },
}

#[derive(Subcommand, Debug)]
enum ReportWhat {
    /// One report from every shard's folder of a run (`dc eval|study ... --shard I/N --out DIR`):
    /// each shard once, finished, of the same settings and build; else refused, naming the shard,
    /// setting or seeds, and nothing written.
    Merge {
        /// The shards' folders, any order (`reports/run/shard-*`).
        #[arg(required = true, value_name = "SHARD_DIR")]
        dirs: Vec<PathBuf>,
        /// Where the merged report goes.
        #[arg(long)]
        out: PathBuf,
        /// dc-metrics's report options (`--phases 100,150`, `--settle-speed 0.1`).
        #[arg(last = true)]
        metrics_args: Vec<String>,
    },
}

#[derive(Subcommand, Debug)]
enum NodeWhat {
    /// Every node of the graphs running on this machine, as their launchers list them:
    /// namespace, host, graph, node, pid, state, program (every namespace, or one).
    List {
        /// Only this graph's bus namespace.
        #[arg(long)]
        namespace: Option<String>,
    },
}

#[derive(Subcommand, Debug)]
enum TopicWhat {
    /// Topics alive on this host's iceoryx2 bus (or over zenoh with --zenoh), with their frame
    /// kind, writers, readers and delivery (every namespace, or one).
    List {
        #[command(flatten)]
        place: topic::Where,
    },
    /// What a topic carries (header and item types, their fields, who publishes it) and where
    /// it is alive: writers, readers, delivery.
    Info(topic::InfoArgs),
    /// Print a topic's frames as they pass, decoded (header fields by name, items summarised).
    Echo(topic::EchoArgs),
    /// Publish a control message into a running graph: `dc topic pub control shutdown` ends it
    /// cleanly (every node finishes, files closed), as Ctrl-C of its launcher does.
    Pub(topic::PubArgs),
    /// Relay topics of a graph on this host to zenoh (`dc/<namespace>/<topic>`), so a zenoh
    /// client (Python's `subscribe.py`, another machine) taps them without editing the launch file.
    Bridge(topic::BridgeArgs),
    /// A topic's rate: mean, min, max and std dev of the period over the latest frames.
    Hz(topic::RateArgs),
    /// A topic's bandwidth: bytes per second and frame sizes over the latest frames.
    Bw(topic::RateArgs),
}

#[derive(clap::Args, Debug)]
struct EvalArgs {
    /// Warm-start models to compare, `name` or `name:param`.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "none,builtin,copy,copy2,bad,random,grid,copy-grid,unet",
        long_help = msgs::models::option_help("Warm-start models to compare, `name` or `name:param` (`blend:0.75`).")
    )]
    models: Vec<String>,
    /// Model file of the `unet` model (`dc train` writes one; the repository ships a demo model).
    #[arg(long, default_value_os_t = runtime::shipped("models/unet-demo.dcu"))]
    unet_model: PathBuf,
    /// The command serving each `external:NAME` model of --models, in their order (`python3
    /// python/serve_example.py`, split into words as a shell would, but run without one): started
    /// as node NAME of the graph, it answers each step's problem over zenoh (docs/external.md);
    /// a late answer falls back to builtin, counted; a server that fails stops the evaluation,
    /// named.
    #[arg(long, value_name = "COMMAND")]
    serve: Vec<String>,
    /// Model file of the `gnn` model (`dc-gnn`), run inside the simulators.
    #[arg(long)]
    gnn_model: Option<PathBuf>,
    /// Evaluation seeds (simulation ids), the same for every model.
    #[arg(long, default_value = "0..30")]
    seeds: String,
    #[arg(long, default_value = "ball-box")]
    scene: String,
    #[arg(long, default_value_t = 250)]
    steps: u32,
    /// Solver tolerance: of the simulator's stopping rule (by default the natural residual, in
    /// impulse units; `-- --solver pgs --stop change` is the thesis's solver and rule).
    #[arg(long, default_value_t = 1e-4)]
    tolerance: f64,
    /// Dynamic bodies.
    #[arg(long, default_value_t = 100)]
    n: u32,
    /// Simulator processes running at once (models are split among them; grid-based ones share
    /// one SPH node and one dc-unet); 1 keeps timings clean.
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Sweep threads of each simulator (`dc-sim --threads`: the colour order's rows on that many
    /// threads; the answer is the same on any number). Default: the simulator's own, the
    /// machine's cores. The simulators' check of the graph refuses what they cannot run.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    threads: Option<u32>,
    /// Report folder (default reports/eval-<unix seconds>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Run only the I-th of N parts of --seeds (I from 0: `$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT`,
    /// Kubernetes' `$JOB_COMPLETION_INDEX`): contiguous blocks, the same on every host. OUT gets
    /// this part's report, `shard.json` (the run's settings and build, its seeds, whether it
    /// finished) and `records.cbor`; `dc report merge` makes the run's one report from all N
    /// (docs/cluster.md).
    #[arg(long, value_name = "I/N")]
    shard: Option<msgs::shard::Shard>,
    /// Seeds reserved for training; evaluating on them is refused unless --force.
    #[arg(long, default_value = "1000..1110")]
    training_seeds: String,
    /// Evaluate even on training seeds.
    #[arg(long)]
    force: bool,
    /// Print the graph instead of running it.
    #[arg(long)]
    dry_run: bool,
    /// Also solve each step of the other models from builtin's warm start (`dc-sim
    /// --shadow-builtin`): the report's "same states vs builtin", a warm start's own saving apart
    /// from its run's trajectory. One more solve per step; `--same-states false` skips it.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    same_states: bool,
    /// Solvers to run every model with (`pgs,nncg:1.2/down`, as `dc-sim --solver` spells
    /// them): one evaluation per solver in OUT/<solver>/, then OUT/solvers.md, a solver x model
    /// table (sweeps and solve time against the first solver's builtin, capped steps, same states
    /// vs builtin within each solver).
    #[arg(long, value_delimiter = ',')]
    solvers: Vec<String>,
    /// Sweep budgets to run every model at (`4,8,16`; `dc-sim --budget K`: exactly K sweeps a
    /// step, fewer only when the natural residual is already below --tolerance): one evaluation
    /// per budget in OUT/budget-K/ (OUT/<solver>/budget-K/ with --solvers), then OUT/budgets.md,
    /// each model's accuracy after its budget placed on builtin's curve over these budgets.
    /// Same states are not measured (every model makes K sweeps).
    #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u32).range(1..=msgs::curve::MAX_BUDGET as i64))]
    budget: Vec<u32>,
    /// Also split every step's warm-start error against the step's exact solution, beside
    /// builtin's on the same step (`dc-sim --error-split`, three more solves a step outside its
    /// time): the report's "which part of builtin's error each model removes", for every model,
    /// served ones too; with --budget also in OUT/budgets.md.
    #[arg(long)]
    error_split: bool,
    /// Print every node's log (otherwise: a progress bar on a terminal, one line per finished
    /// model, and the nodes' warnings and errors; `RUST_LOG` set means the same as -v).
    #[arg(short, long)]
    verbose: bool,
    /// More simulator parameters, passed through (after `--`).
    #[arg(last = true)]
    sim_args: Vec<String>,
}

#[derive(Subcommand)]
enum BenchWhat {
    /// Steps/s of the closed loop (sim + sph + unet + metrics + recorder, lockstep) on one host
    /// over iceoryx2, the same graph with every topic over zenoh, and every stage in one process.
    Loop {
        #[arg(long, default_value = "0..2")]
        seeds: String,
        #[arg(long, default_value_t = 100)]
        steps: u32,
        /// Dynamic bodies (ball-box).
        #[arg(long, default_value_t = 40)]
        n: u32,
        #[arg(long, default_value_os_t = runtime::shipped("models/unet-demo.dcu"))]
        unet_model: PathBuf,
        /// Repetitions of each variant (the median is reported).
        #[arg(long, default_value_t = 3)]
        repeat: usize,
    },
    /// What watching a running graph costs its simulator: throughput alone and with
    /// `dc topic echo | hz | bw` and `dc record -a` attached.
    Observe(bench_observe::ObserveBenchArgs),
    /// One-way latency and throughput of an in-process channel, iceoryx2 and zenoh used
    /// directly (raw), and our bus over each, with the ratios of ours to raw.
    Bus(bench_bus::BusBenchArgs),
}

fn main() {
    runtime::init_logging();
    let cli = Cli::parse();
    let code = match real_main(cli) {
        Ok(()) => 0,
        // The reader of our output went away (`dc topic echo ... | head`): done, as coreutils.
        Err(e) if e.chain().any(|c| c.is::<runtime::StdoutClosed>()) => 0,
        // Ctrl-C is how a user ends a graph: said as what happened, not as an error; the
        // status stays 130, as a shell's for an interrupted command.
        Err(e) if e.downcast_ref::<RunError>().is_some_and(|r| matches!(r, RunError::Interrupted)) => {
            eprintln!("dc: stopped (Ctrl-C); every node of the graph was stopped");
            130
        }
        Err(e) => {
            eprintln!("dc: error: {}", runtime::error_text(&e));
            1
        }
    };
    std::process::exit(code);
}

fn interrupt_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    let _ = ctrlc::set_handler(move || f.store(true, Ordering::SeqCst));
    flag
}

/// A duration that names its unit (a plain number would be milliseconds, a trap for a timeout
/// given in seconds everywhere else in the README).
fn duration_with_unit(s: &str) -> Result<std::time::Duration, String> {
    if s.trim().parse::<f64>().is_ok() {
        return Err(format!("`{s}`: give a unit, e.g. {s}s or {s}ms"));
    }
    runtime::parse_duration(s)
}

fn real_main(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Launch { file, host, namespace, dry_run, trust, wait_hosts, ready_timeout, shard } => {
            let mut graph = Graph::load(&file)?;
            graph.trust = trust;
            if let Some(ns) = namespace {
                runtime::check_namespace(&ns).map_err(|why| anyhow::anyhow!("--namespace `{ns}`: {why}"))?;
                graph.namespace = ns;
            }
            if let Some(shard) = shard {
                for change in launch::shard::shard_graph(&mut graph, shard)? {
                    runtime::print_line(&format!("shard {shard}: {change}"))?;
                }
            }
            let host = pick_host(&graph, host)?;
            graph.check_params_on(Some(&host))?;
            if dry_run {
                return print_graph(&graph, Some(&host));
            }
            let flag = interrupt_flag();
            let options = supervisor::RunOptions { hosts_timeout: wait_hosts, ready_timeout };
            supervisor::run_with(&graph, &host, Output::Forward, &flag, &options)?;
            Ok(())
        }
        Command::Run { node, args } => exec_node(&node, &args),
        Command::Record { args } => exec_node("record", &args),
        Command::Study { args } => exec_node("study", &args),
        Command::Play { file, args } => {
            let mut all = vec!["--input".to_string(), file.display().to_string()];
            all.extend(args);
            exec_node("replay", &all)
        }
        Command::Train { args } => {
            let (node, args) = train_command(args)?;
            exec_node(node, &args)
        }
        Command::List { file, trust } => {
            let mut graph = Graph::load(&file)?;
            graph.trust = trust;
            print_graph(&graph, None)
        }
        Command::Node { what: NodeWhat::List { namespace } } => node_list(namespace.as_deref()),
        Command::Completions { shell } => {
            clap_complete::generate(shell, &mut <Cli as clap::CommandFactory>::command(), "dc", &mut std::io::stdout());
            Ok(())
        }
        Command::Topic { what } => match what {
            TopicWhat::List { place } => topic::list(&place),
            TopicWhat::Info(args) => topic::info(&args),
            TopicWhat::Echo(args) => topic::echo(&args),
            TopicWhat::Bridge(args) => topic::bridge(&args),
            TopicWhat::Pub(args) => topic::publish(&args),
            TopicWhat::Hz(args) => topic::rate(&args, topic::Figure::Hz),
            TopicWhat::Bw(args) => topic::rate(&args, topic::Figure::Bw),
        },
        Command::Eval(args) => eval(*args),
        Command::Report { what: ReportWhat::Merge { dirs, out, metrics_args } } => {
            // A study's shards are merged by dc-study, an evaluation's by dc-metrics (which also
            // names what is wrong with a folder that has no readable manifest).
            let study = msgs::shard::Manifest::read(&dirs[0]).is_ok_and(|m| m.command.starts_with("dc study"));
            if study && !metrics_args.is_empty() {
                bail!("options after `--` are an evaluation report's (dc-metrics); a study's merge takes none");
            }
            let (node, first) = if study { ("study", "merge") } else { ("metrics", "--merge") };
            let mut args = vec![first.to_string()];
            args.extend(dirs.iter().map(|d| d.display().to_string()));
            args.push(format!("--out={}", out.display()));
            args.extend(metrics_args);
            exec_node(node, &args)
        }
        Command::Bench { what: BenchWhat::Bus(args) } => bench_bus::run(&args, &interrupt_flag()),
        Command::Bench { what: BenchWhat::Observe(args) } => bench_observe::run(&args),
        Command::Bench { what: BenchWhat::Loop { seeds, steps, n, unet_model, repeat } } => {
            bench_loop(&seeds, steps, n, &unet_model, repeat.max(1))
        }
    }
}

fn pick_host(graph: &Graph, host: Option<String>) -> Result<String> {
    match host {
        Some(h) if graph.hosts.contains_key(&h) => Ok(h),
        Some(h) => bail!(
            "{}: unknown host `{h}` (hosts: {})",
            graph.file,
            graph.hosts.keys().cloned().collect::<Vec<_>>().join(", ")
        ),
        None if graph.hosts.len() == 1 => Ok(graph.hosts.keys().next().cloned().unwrap_or_default()),
        None => bail!("{}: the graph has several hosts; say which this is with --host", graph.file),
    }
}

/// `dc node list`: one line per node of the graphs running here; none running is an error
/// (exit 1), so a script can tell.
fn node_list(namespace: Option<&str>) -> Result<()> {
    let graphs = runtime::lock::NamespaceLock::running_graphs(namespace);
    if graphs.is_empty() {
        match namespace {
            Some(ns) => {
                bail!("no graph runs in namespace `{ns}` on this machine (`dc node list` shows every namespace)")
            }
            None => bail!("no graph runs on this machine"),
        }
    }
    let rows: Vec<[String; 7]> = graphs
        .iter()
        .flat_map(|g| {
            g.nodes.iter().map(|n| {
                let state =
                    if n.restarts > 0 { format!("{} ({} restarts)", n.state, n.restarts) } else { n.state.clone() };
                [
                    g.namespace.clone(),
                    g.host.clone(),
                    g.graph.clone(),
                    n.name.clone(),
                    n.pid.to_string(),
                    state,
                    n.program.clone(),
                ]
            })
        })
        .collect();
    let titles = ["namespace", "host", "graph", "node", "pid", "state", "program"];
    let widths: Vec<usize> =
        (0..7).map(|i| rows.iter().map(|r| r[i].len()).chain([titles[i].len()]).max().unwrap_or(0)).collect();
    let line = |cells: [&str; 7]| {
        let padded: Vec<String> = cells.iter().zip(&widths).map(|(c, w)| format!("{c:w$}")).collect();
        padded.join("  ").trim_end().to_string()
    };
    runtime::print_line(&line(titles))?;
    for r in &rows {
        runtime::print_line(&line([&r[0], &r[1], &r[2], &r[3], &r[4], &r[5], &r[6]]))?;
    }
    Ok(())
}

/// What would start where, and how each topic travels (asks the node binaries for their ports).
fn print_graph(graph: &Graph, only: Option<&str>) -> Result<()> {
    let ports = launch::plan::describe_ports(graph)?;
    let plan = launch::plan::Plan::new(graph, &ports);
    plan.check_port_limits(graph)?;
    println!("graph `{}` ({}), bus namespace `{}`", graph.name, graph.file, graph.namespace);
    if let Some(root) = &graph.root {
        println!("nodes run in {} (relative paths are taken from there)", root.display());
    }
    if let Some((endpoint, host)) = &plan.router {
        println!("zenoh router: {endpoint} (run by the launcher on `{host}`)");
    }
    for (name, host) in &graph.hosts {
        if only.is_some_and(|h| h != name) {
            continue;
        }
        println!("host `{name}` (address {})", host.address);
        for n in graph.nodes_on(name) {
            let mut flags = Vec::new();
            if n.daemon {
                flags.push("daemon".to_string());
            }
            if let launch::graph::OnFailure::Restart { max } = n.on_failure {
                flags.push(format!("restart <= {max}"));
            }
            let flags = if flags.is_empty() { String::new() } else { format!(" [{}]", flags.join(", ")) };
            println!("  {}{flags}: {} {}", n.name, n.program.display(), n.args.join(" "));
            let p = &ports[&n.name];
            let list = |set: &std::collections::BTreeSet<String>| {
                if set.is_empty() {
                    "-".to_string()
                } else {
                    set.iter().cloned().collect::<Vec<_>>().join(", ")
                }
            };
            println!("      publishes {}; subscribes {}", list(&p.publishes), list(&p.subscribes));
            if let Some(e) = plan.endpoints.get(&n.name) {
                println!("      zenoh {e}");
            }
        }
        let launcher = launch::plan::launcher_name(name);
        if let Some(e) = plan.endpoints.get(&launcher) {
            println!("  (launcher: zenoh {e})");
        }
    }
    println!("topics:");
    for r in plan.routes() {
        let show = |v: &[(String, String)]| {
            if v.is_empty() {
                "nobody".to_string()
            } else {
                v.iter()
                    .map(|(n, h)| if plan.multi_host { format!("{n}@{h}") } else { n.clone() })
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        };
        let links = if r.links.is_empty() { "no link".to_string() } else { r.links.join("; ") };
        let qos = if plan.best_effort.contains(&r.topic) { "best-effort" } else { "reliable" };
        println!("  {:<14} {} -> {}  [{links}] {qos}", r.topic, show(&r.writers), show(&r.readers));
    }
    Ok(())
}

fn bench_loop(seeds: &str, steps: u32, n: u32, model: &std::path::Path, repeat: usize) -> Result<()> {
    let find = |b: &str| find_binary(b).with_context(|| format!("{b} not built (cargo build --workspace --bins)"));
    let (unet, in_process) = (find("dc-unet")?, find("dc-loop-bench")?);
    let sph_args = unet_sph_args(&unet, model)?;
    let scratch = std::env::temp_dir().join(unique_namespace("bench-loop"));
    std::fs::create_dir_all(&scratch)?;
    let flag = interrupt_flag();
    runtime::print_line(&format!(
        "closed loop: ball-box, {n} bodies, seeds {seeds}, {steps} steps, unet model {} (lockstep), {repeat} runs each",
        model.display()
    ))?;
    runtime::print_line(&format!(
        "{:<34} {:>10} {:>10} {:>12} {:>9}",
        "variant", "steps/s", "loop s", "total sweeps", "fallbacks"
    ))?;
    let mut medians = Vec::new();
    for variant in ["one process (no bus)", "graph, iceoryx2 (one host)", "graph, every topic over zenoh"] {
        let mut runs = Vec::new();
        for r in 0..repeat {
            let run = if variant.starts_with("one process") {
                let out = std::process::Command::new(&in_process)
                    .args(["--seeds", seeds, "--steps", &steps.to_string(), "--n", &n.to_string()])
                    .arg("--model")
                    .arg(model)
                    .arg("--record")
                    .arg(scratch.join(format!("inprocess-{r}.mcap")))
                    .output()?;
                if !out.status.success() {
                    bail!("dc-loop-bench failed: {}", String::from_utf8_lossy(&out.stderr));
                }
                let stdout = String::from_utf8_lossy(&out.stdout);
                one_summary("dc-loop-bench", stdout.lines())?
            } else {
                let zenoh = variant.contains("zenoh");
                let dir = scratch.join(format!("{}-{r}", if zenoh { "zenoh" } else { "iceoryx2" }));
                let graph = loop_graph(seeds, steps, n, model, &sph_args, &dir, zenoh)?;
                let report = supervisor::run(&graph, DEFAULT_HOST, Output::Capture, &flag)?;
                let lines = report.stdout.get("sim").map(Vec::as_slice).unwrap_or_default();
                one_summary("the simulator", lines.iter().map(String::as_str))?
            };
            runs.push(run);
        }
        runs.sort_by(|a, b| (a.steps as f64 / a.loop_secs).total_cmp(&(b.steps as f64 / b.loop_secs)));
        let m = runs[runs.len() / 2].clone();
        let rate = m.steps as f64 / m.loop_secs;
        runtime::print_line(&format!(
            "{variant:<34} {rate:>10.1} {:>10.2} {:>12} {:>9}",
            m.loop_secs, m.total_sweeps, m.fallbacks
        ))?;
        medians.push((rate, m));
    }
    let (inproc, iox, zenoh) = (medians[0].0, medians[1].0, medians[2].0);
    runtime::print_line(&format!("ratios (steps/s): iceoryx2 / one process = {:.2} (target >= 0.9); zenoh / one process = {:.2}; zenoh / iceoryx2 = {:.2}", iox / inproc, zenoh / inproc, zenoh / iox))?;
    let same = medians.iter().all(|(_, m)| m.total_sweeps == medians[0].1.total_sweeps);
    runtime::print_line(&format!("same total sweeps in every variant (lockstep solves the same problems): {same}"))?;
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(())
}

/// The one run summary (`msgs::RunSummary`) among `who`'s stdout lines.
fn one_summary<'a>(who: &str, lines: impl IntoIterator<Item = &'a str>) -> Result<RunSummary> {
    let mut found = RunSummary::find_in(lines).with_context(|| format!("{who} printed a bad run summary"))?;
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => bail!("{who} printed no run summary"),
        k => bail!("{who} printed {k} run summaries, expected one"),
    }
}

/// The `dc-sph` arguments that make the input grids `model` was trained on.
fn unet_sph_args(unet: &std::path::Path, model: &std::path::Path) -> Result<Vec<String>> {
    let out =
        std::process::Command::new(unet).arg("sph-args").arg(model).output().context("running dc-unet sph-args")?;
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        // The node's `error: ...` line (runtime::exit), else all it said.
        let message = stderr.lines().rev().find_map(|l| l.strip_prefix("error: ")).unwrap_or(stderr.trim());
        bail!("{message}");
    }
    Ok(String::from_utf8_lossy(&out.stdout).lines().map(str::to_string).collect())
}

/// The closed loop as a graph: sim (lockstep unet) + sph + unet + metrics + recorder.
fn loop_graph(
    seeds: &str,
    steps: u32,
    n: u32,
    model: &std::path::Path,
    sph_args: &[String],
    dir: &std::path::Path,
    zenoh: bool,
) -> Result<Graph> {
    let node = |name: &str, binary: &str, daemon: bool, args: Vec<String>| {
        NodeSpec::new(name, binary, daemon, args).with_env("RUST_LOG", "warn")
    };
    let sim_args = vec![
        "--models=unet".into(),
        format!("--seeds={seeds}"),
        format!("--steps={steps}"),
        format!("--n={n}"),
        "--deadline=none".into(),
    ];
    let nodes = vec![
        node("sph", "dc-sph", true, sph_args.to_vec()),
        node("unet", "dc-unet", true, vec![format!("--model={}", model.display())]),
        node("recorder", "dc-record", true, vec![format!("--dir={}", dir.join("recordings").display())]),
        node(
            "metrics",
            "dc-metrics",
            false,
            vec!["--runs=1".into(), format!("--out={}", dir.join("report").display())],
        ),
        node("sim", "dc-sim", false, sim_args),
    ];
    let mut graph = Graph::single_host("bench-loop", &unique_namespace("loop"), nodes)?;
    graph.check_params()?;
    if zenoh {
        for t in msgs::topics::names() {
            graph.topics.insert(t.to_string(), Transport::Zenoh);
        }
    }
    Ok(graph)
}

/// Builds the evaluation graph: one metrics node and `jobs` simulators sharing the models.
fn eval_graph(args: &EvalArgs, out: &std::path::Path, solver: Option<&str>, budget: Option<u32>) -> Result<Graph> {
    let seeds = msgs::parse_seeds(&args.seeds).map_err(|e| anyhow::anyhow!("--seeds {e}"))?;
    let training = msgs::parse_seeds(&args.training_seeds).map_err(|e| anyhow::anyhow!("--training-seeds {e}"))?;
    let overlap: Vec<u64> = seeds.iter().copied().filter(|s| training.binary_search(s).is_ok()).collect();
    if !overlap.is_empty() && !args.force {
        bail!(
            "{} evaluation seeds are training seeds (e.g. {}): results would flatter learned models; use other seeds or --force",
            overlap.len(),
            overlap[0]
        );
    }
    if args.models.is_empty() {
        bail!("--models is empty");
    }
    // Each model once, by the name its statistics carry: two runs of one name would be merged
    // into one row of the report (`builtin,builtin`; `blend,blend:0.5`).
    let mut named = std::collections::BTreeSet::new();
    for m in &args.models {
        let name = msgs::models::canonical_name(m).map_err(|e| anyhow::anyhow!("--models: {e}"))?;
        if !named.insert(name.clone()) {
            bail!("--models: `{m}` is `{name}`, already asked for: its runs would be merged into one report row");
        }
    }
    let jobs = args.jobs.clamp(1, args.models.len());
    let mut title = eval_title(args);
    let mut metrics_args = vec![format!("--runs={}", args.models.len()), format!("--out={}", out.display())];
    if let Some(shard) = args.shard {
        let part = shard.seeds(&seeds).map_err(|e| anyhow::anyhow!("--shard {e}"))?;
        title += &format!(" - shard {shard}, seeds {}", msgs::shard::format_seeds(&part));
        metrics_args.push("--records".into());
    }
    metrics_args.push(format!("--title={title}"));
    let mut nodes = vec![NodeSpec::new("metrics", "dc-metrics", false, metrics_args)];
    // Grid-based models need the SPH node (it turns each step's contacts into the next step's
    // warm-start grid); it serves every simulator of the graph. With `unet` it makes the model's
    // input grids (e.g. temporal, padded to 128); padding leaves the `grid` model's samples
    // unchanged (the extra nodes lie outside the box).
    let reads = |topic: &str| args.models.iter().any(|m| msgs::models::served_on(m) == Some(topic));
    let uses_unet = reads(msgs::topics::GRID_UNET.name);
    let grid_based = uses_unet || reads(msgs::topics::GRID_CONTACTS.name);
    let mut sph_args = vec!["--mode=preserving".to_string()];
    if uses_unet {
        if !args.unet_model.is_file() {
            bail!(
                "the unet model needs a model file: {} does not exist (train one with `dc train`, see the README, or pass --unet-model)",
                args.unet_model.display()
            );
        }
        // The SPH node must make exactly the grids the model was trained on: the model file says how.
        let unet = find_binary("dc-unet").context("dc-unet not built (cargo build --workspace --bins)")?;
        sph_args = unet_sph_args(&unet, &args.unet_model).context("--unet-model")?;
    }
    if grid_based {
        nodes.push(NodeSpec::new("sph", "dc-sph", true, sph_args));
    }
    if uses_unet {
        nodes.push(NodeSpec::new("unet", "dc-unet", true, vec![format!("--model={}", args.unet_model.display())]));
    }
    // `gnn-node` reads the network from a `dc-gnn` node, the same model file as `gnn`.
    if reads(msgs::topics::WARM_GNN.name) {
        let model =
            args.gnn_model.as_ref().context("the gnn-node model needs --gnn-model FILE (e.g. models/gnn.dcg)")?;
        nodes.push(NodeSpec::new("gnn", "dc-gnn", true, vec![format!("--model={}", model.display())]));
    }
    let externals = external_servers(args)?;
    nodes.extend(externals.iter().cloned());
    let run_seeds = run_seeds(args)?;
    for j in 0..jobs {
        let models: Vec<&str> = args.models.iter().skip(j).step_by(jobs).map(String::as_str).collect();
        let sim_args = simulator_args(args, &run_seeds, &models, solver, budget);
        nodes.push(NodeSpec::new(format!("sim-{j}"), "dc-sim", false, sim_args));
    }
    let mut graph = Graph::single_host("eval", &unique_namespace("eval"), nodes)?;
    if !externals.is_empty() {
        // A server is any process: it reaches the graph over zenoh, the one transport every
        // language has (iceoryx2 stays for the Rust nodes' other topics).
        use msgs::topics::{CONTROL, PROBLEM_BODIES, PROBLEM_CONTACTS, WARM_EXTERNAL};
        for topic in [CONTROL.name, PROBLEM_BODIES.name, PROBLEM_CONTACTS.name, WARM_EXTERNAL.name] {
            graph.topics.insert(topic.to_string(), Transport::Zenoh);
        }
    }
    Ok(graph)
}

/// The report's title of the whole run (a shard's report adds its part).
fn eval_title(args: &EvalArgs) -> String {
    format!(
        "Warm-start evaluation: {} scene, {} bodies, seeds {}, {} steps, tolerance {}",
        args.scene, args.n, args.seeds, args.steps, args.tolerance
    )
}

/// The seeds the simulators run: --seeds, or the shard's part of them, as `dc-sim --seeds` reads.
fn run_seeds(args: &EvalArgs) -> Result<String> {
    let Some(shard) = args.shard else { return Ok(args.seeds.clone()) };
    let seeds = msgs::parse_seeds(&args.seeds).map_err(|e| anyhow::anyhow!("--seeds {e}"))?;
    let part = shard.seeds(&seeds).map_err(|e| anyhow::anyhow!("--shard {e}"))?;
    Ok(msgs::shard::format_seeds(&part))
}

/// What a shard's manifest records of the run, by name: every flag that changes its results or
/// timings (not where it writes or how it prints), and a hash of each model file it reads.
fn eval_settings(args: &EvalArgs, graph: &Graph) -> Result<std::collections::BTreeMap<String, String>> {
    let mut settings = std::collections::BTreeMap::new();
    let mut set = |name: &str, value: String| settings.insert(name.to_string(), value);
    set("models", args.models.join(","));
    set("seeds", args.seeds.clone());
    set("scene", args.scene.clone());
    set("steps", args.steps.to_string());
    set("tolerance", args.tolerance.to_string());
    set("n", args.n.to_string());
    set("jobs", args.jobs.to_string());
    set("threads", args.threads.map_or("the machine's cores".into(), |t| t.to_string()));
    set("same-states", args.same_states.to_string());
    set("error-split", args.error_split.to_string());
    set("serve", args.serve.join(" ; "));
    set("simulator arguments", shlex::try_join(args.sim_args.iter().map(String::as_str)).unwrap_or_default());
    if graph.nodes.iter().any(|n| n.binary == "dc-unet") {
        set("unet-model sha256", runtime::shard::file_sha256(&args.unet_model).context("--unet-model")?);
    }
    if let Some(gnn) = &args.gnn_model {
        set("gnn-model sha256", runtime::shard::file_sha256(gnn).context("--gnn-model")?);
    }
    Ok(settings)
}

/// The server nodes of the `external:NAME` models: the i-th --serve command serves the i-th
/// external model, as node NAME, told its model's name (`DC_EXTERNAL_MODEL`).
fn external_servers(args: &EvalArgs) -> Result<Vec<NodeSpec>> {
    let names: Vec<&str> = args.models.iter().filter_map(|m| msgs::models::external_name(m)).collect();
    if names.len() != args.serve.len() {
        bail!(
            "{} external models ({}) and {} --serve commands: give one command per `external:NAME` model, in order              (`--models builtin,external:py --serve \"python3 python/serve_example.py\"`)",
            names.len(),
            names.join(", "),
            args.serve.len()
        );
    }
    names
        .iter()
        .zip(&args.serve)
        .map(|(name, command)| {
            let words = shlex::split(command).filter(|w| !w.is_empty());
            let words =
                words.with_context(|| format!("--serve `{command}`: not a command line (unbalanced quotes?)"))?;
            Ok(NodeSpec::new(*name, &words[0], true, words[1..].to_vec())
                .with_env("DC_EXTERNAL_MODEL", *name)
                // A Python server's lines reach the launcher as they are written.
                .with_env("PYTHONUNBUFFERED", "1"))
        })
        .collect()
}

/// The arguments of an evaluation's simulator running `models` (with a solver and a budget).
fn simulator_args(
    args: &EvalArgs,
    seeds: &str,
    models: &[&str],
    solver: Option<&str>,
    budget: Option<u32>,
) -> Vec<String> {
    let mut sim_args = vec![
        format!("--models={}", models.join(",")),
        format!("--seeds={seeds}"),
        format!("--scene={}", args.scene),
        format!("--steps={}", args.steps),
        format!("--tolerance={}", args.tolerance),
        format!("--n={}", args.n),
    ];
    if let Some(gnn) = &args.gnn_model {
        sim_args.push(format!("--gnn-model={}", gnn.display()));
    }
    // At a budget every model makes the same sweeps: builtin on the same states says nothing.
    if args.same_states && budget.is_none() {
        sim_args.push("--shadow-builtin".into());
    }
    if args.error_split {
        sim_args.push("--error-split".into());
    }
    if let Some(threads) = args.threads {
        sim_args.push(format!("--threads={threads}"));
    }
    sim_args.extend(args.sim_args.iter().cloned());
    if let Some(solver) = solver {
        sim_args.push(format!("--solver={solver}"));
    }
    if let Some(k) = budget {
        sim_args.push(format!("--budget={k}"));
    }
    sim_args
}

fn eval(args: EvalArgs) -> Result<()> {
    let out = args.out.clone().unwrap_or_else(|| {
        let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
        PathBuf::from(format!("reports/eval-{secs}"))
    });
    if !args.solvers.is_empty() || !args.budget.is_empty() {
        if args.shard.is_some() {
            bail!(
                "--shard with --solvers or --budget: shard each solver's or budget's evaluation as a run of its own \
                 (`dc eval --shard I/N ... -- --solver S` or `-- --budget K`), one merge each"
            );
        }
        return eval_variants(&args, &out);
    }
    let graph = eval_graph(&args, &out, None, None)?;
    graph.check_params()?;
    if args.dry_run {
        return print_graph(&graph, None);
    }
    // The report is written after every simulation ran: a folder that cannot take it must
    // stop the evaluation before it starts, not lose it at the end.
    writable_dir(&out).context("--out")?;
    let shard = match args.shard {
        Some(shard) => {
            let seeds = msgs::parse_seeds(&args.seeds).map_err(|e| anyhow::anyhow!("--seeds {e}"))?;
            let build = runtime::shard::build_of(
                graph.nodes.iter().filter(|n| n.binary.starts_with("dc-")).map(|n| n.program.as_path()),
            )?;
            let settings = eval_settings(&args, &graph)?;
            Some(runtime::shard::RunningShard::start(
                &out,
                "dc eval",
                shard,
                &seeds,
                settings,
                build,
                &eval_title(&args),
                Vec::new(),
                // What the metrics node writes last (`--records`), and the merge reads.
                "records.cbor",
            )?)
        }
        None => None,
    };
    let flag = interrupt_flag();
    let progress = EvalProgress::new(&args, 1)?;
    let ran = supervisor::run(&graph, DEFAULT_HOST, progress.output(), &flag).map_err(anyhow::Error::from);
    let ran = match shard {
        Some(shard) => shard.finish(ran),
        None => ran,
    };
    ran?;
    progress.finish();
    runtime::print_line(&format!("evaluation report: {}", out.join("report.html").display()))?;
    Ok(())
}

/// What `dc eval` shows while it runs: every node's log with -v; otherwise a progress bar of the
/// simulations (on a terminal only), a line per model as its run ends, and what nodes warn of.
struct EvalProgress {
    bar: Option<indicatif::ProgressBar>,
}

impl EvalProgress {
    fn new(args: &EvalArgs, evaluations: usize) -> Result<EvalProgress> {
        if args.verbose || std::env::var_os("RUST_LOG").is_some() {
            return Ok(EvalProgress { bar: None });
        }
        let seeds = msgs::parse_seeds(&run_seeds(args)?).map_err(|e| anyhow::anyhow!("--seeds {e}"))?;
        let total = (seeds.len() * args.models.len() * evaluations) as u64;
        let bar = indicatif::ProgressBar::with_draw_target(Some(total), indicatif::ProgressDrawTarget::stderr());
        bar.set_style(
            indicatif::ProgressStyle::with_template("eval [{bar:30}] {pos}/{len} simulations, {elapsed}, ~{eta} left")
                .expect("the template is valid")
                .progress_chars("=> "),
        );
        Ok(EvalProgress { bar: Some(bar) })
    }

    fn output(&self) -> Output {
        let Some(bar) = self.bar.clone() else { return Output::Forward };
        let say = {
            let bar = bar.clone();
            // A hidden bar (no terminal) prints nothing of its own, `println` included.
            move |text: String| {
                if bar.is_hidden() {
                    let _ = runtime::try_print_line(&text);
                } else {
                    bar.println(text)
                }
            }
        };
        // The metrics node's first table (one row per model) is the evaluation's result.
        let in_table = std::sync::atomic::AtomicBool::new(false);
        Output::Watch(Arc::new(move |node: &str, stderr: bool, line: &str| {
            if node == "metrics" && !stderr {
                if line.starts_with("| model | sims |") {
                    in_table.store(true, Ordering::Relaxed);
                } else if line.trim().is_empty() {
                    in_table.store(false, Ordering::Relaxed);
                }
                if in_table.load(Ordering::Relaxed) {
                    say(line.to_string());
                }
            } else if stderr && line.contains(" simulation done ") {
                bar.inc(1);
            } else if let (false, Some((_, json))) = (stderr, line.split_once(RunSummary::PREFIX)) {
                if let Ok(s) = serde_json::from_str::<RunSummary>(json) {
                    let text = format!(
                        "[{node}] model {}: {} steps, {:.1} sweeps a step, {} fallbacks, {:.2} s",
                        s.model,
                        s.steps,
                        s.total_sweeps as f64 / s.steps.max(1) as f64,
                        s.fallbacks,
                        s.loop_secs
                    );
                    say(text);
                }
            }
        }))
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// The first item of `list` that an earlier one repeats.
fn repeated<T: PartialEq>(list: &[T]) -> Option<&T> {
    list.iter().enumerate().find(|(i, x)| list[..*i].contains(x)).map(|(_, x)| x)
}

/// One evaluation of `dc eval --solvers/--budget`: its solver and budget, folder and graph.
struct Variant {
    solver: Option<String>,
    budget: Option<u32>,
    dir: PathBuf,
    graph: Graph,
}

/// `dc eval --solvers` and/or `--budget`: every graph checked first, then one evaluation per
/// solver and budget, then the solver x model table (without budgets) or the budget table (per
/// solver).
fn eval_variants(args: &EvalArgs, out: &std::path::Path) -> Result<()> {
    let solvers: Vec<Option<&String>> =
        if args.solvers.is_empty() { vec![None] } else { args.solvers.iter().map(Some).collect() };
    let budgets: Vec<Option<u32>> =
        if args.budget.is_empty() { vec![None] } else { args.budget.iter().copied().map(Some).collect() };
    if let Some(s) = repeated(&args.solvers) {
        bail!("--solvers: `{s}` is asked for twice");
    }
    if let Some(k) = repeated(&args.budget) {
        bail!("--budget: {k} is asked for twice");
    }
    let mut runs = Vec::new();
    for solver in &solvers {
        for &budget in &budgets {
            let mut dir = out.to_path_buf();
            if let Some(s) = solver {
                dir.push(s.replace(['/', ':'], "-"));
            }
            if let Some(k) = budget {
                dir.push(format!("budget-{k}"));
            }
            let graph = eval_graph(args, &dir, solver.map(String::as_str), budget)?;
            let what = [solver.map(|s| format!("--solvers {s}")), budget.map(|k| format!("--budget {k}"))];
            graph.check_params().with_context(|| what.iter().flatten().cloned().collect::<Vec<_>>().join(", "))?;
            runs.push(Variant { solver: solver.cloned(), budget, dir, graph });
        }
    }
    if args.dry_run {
        return runs.iter().try_for_each(|v| print_graph(&v.graph, None));
    }
    writable_dir(out).context("--out")?;
    for v in &runs {
        writable_dir(&v.dir).context("--out")?;
    }
    let flag = interrupt_flag();
    let mut summaries = Vec::new();
    let progress = EvalProgress::new(args, runs.len())?;
    for v in &runs {
        supervisor::run(&v.graph, DEFAULT_HOST, progress.output(), &flag)?;
        let path = v.dir.join("summary.csv");
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        summaries.push(launch::solver_table::read_summary(&text).with_context(|| path.display().to_string())?);
    }
    progress.finish();
    if args.budget.is_empty() {
        let named: Vec<(&str, Vec<_>)> =
            runs.iter().zip(summaries).map(|(v, s)| (v.solver.as_deref().unwrap_or_default(), s)).collect();
        let table = launch::solver_table::markdown(&named);
        let path = out.join("solvers.md");
        std::fs::write(&path, format!("# Solvers x models\n\n{table}"))
            .with_context(|| format!("writing {}", path.display()))?;
        runtime::print_line(&format!("{table}\nsolver x model table: {}", path.display()))?;
        return Ok(());
    }
    let mut text = String::from("# Models at fixed sweep budgets\n\n");
    let mut rows = runs.iter().zip(summaries).peekable();
    while let Some((v, s)) = rows.next() {
        let mut per_budget = vec![(v.budget.unwrap_or(0), s)];
        while let Some((w, s)) = rows.next_if(|(w, _)| w.solver == v.solver) {
            per_budget.push((w.budget.unwrap_or(0), s));
        }
        if let Some(solver) = &v.solver {
            text += &format!("## Solver {solver}\n\n");
        }
        text += &launch::solver_table::budget_markdown(&per_budget);
        text.push('\n');
    }
    let path = out.join("budgets.md");
    std::fs::write(&path, &text).with_context(|| format!("writing {}", path.display()))?;
    runtime::print_line(&format!("{text}budget table: {}", path.display()))?;
    Ok(())
}

/// Creates `dir` (and its parents) if needed and proves it writable by writing and removing a
/// probe file; the error names the path.
fn writable_dir(dir: &std::path::Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the folder {}", dir.display()))?;
    let probe = dir.join(format!(".dc-write-probe-{}", std::process::id()));
    std::fs::write(&probe, b"probe").with_context(|| format!("cannot write in the folder {}", dir.display()))?;
    std::fs::remove_file(&probe).with_context(|| format!("cannot remove {} again", probe.display()))?;
    Ok(())
}

/// Replaces this process with node binary `dc-<node>` (or `<node>`) run with `args`.
/// The trainer `dc train ARGS` runs and its arguments: `--model gnn` (or `--model=gnn`, anywhere)
/// picks `dc-gnn-train`, `--model unet` or none `dc-unet train`.
fn train_command(args: Vec<String>) -> Result<(&'static str, Vec<String>)> {
    let mut model = None;
    let mut rest = Vec::with_capacity(args.len());
    let mut it = args.into_iter();
    while let Some(a) = it.next() {
        match a.strip_prefix("--model") {
            Some("") => model = Some(it.next().context("`--model` needs a value: unet or gnn")?),
            Some(v) if v.starts_with('=') => model = Some(v[1..].to_string()),
            _ => rest.push(a),
        }
    }
    match model.as_deref() {
        None | Some("unet") => Ok(("unet", std::iter::once("train".to_string()).chain(rest).collect())),
        Some("gnn") => Ok(("gnn-train", rest)),
        Some(other) => bail!("dc train: unknown model `{other}` (unet or gnn)"),
    }
}

fn exec_node(node: &str, args: &[String]) -> Result<()> {
    let program = [format!("dc-{node}"), node.to_string()]
        .iter()
        .find_map(|n| find_binary(n))
        .with_context(|| format!("no node binary `dc-{node}` or `{node}` beside dc or on PATH"))?;
    use std::os::unix::process::CommandExt;
    let err = std::process::Command::new(&program).args(args).exec();
    bail!("cannot run {}: {err}", program.display())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(s: &str) -> Vec<String> {
        s.split_whitespace().map(str::to_string).collect()
    }

    #[test]
    fn an_output_folder_is_created_and_probed_and_an_unwritable_one_is_named() {
        let base = std::env::temp_dir().join(format!("dc-writable-dir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let dir = base.join("a/b");
        writable_dir(&dir).unwrap();
        assert!(dir.is_dir());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "the probe is removed");
        // A file where a folder should be (root may write anywhere, so no permission test).
        let file = base.join("file");
        std::fs::write(&file, b"x").unwrap();
        for bad in [file.clone(), file.join("sub")] {
            let e = format!("{:#}", writable_dir(&bad).unwrap_err());
            assert!(e.contains(&bad.display().to_string()), "{e}");
        }
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn eval_at_a_budget_passes_it_to_every_simulator_without_the_shadow_solve() {
        let cli = Cli::try_parse_from(["dc", "eval", "--seeds", "0..2", "--budget", "4,8"]).unwrap();
        let Command::Eval(eval) = cli.command else { unreachable!("an eval command") };
        let sims = |budget| vec![simulator_args(&eval, "0..2", &["builtin", "none"], Some("pgs"), budget)];
        let at8 = sims(Some(8));
        for args in &at8 {
            assert!(args.contains(&"--budget=8".to_string()) && args.contains(&"--solver=pgs".to_string()), "{args:?}");
            assert!(!args.contains(&"--shadow-builtin".to_string()), "{args:?}");
            assert!(!args.contains(&"--error-split".to_string()), "only when asked: {args:?}");
        }
        assert!(sims(None)
            .iter()
            .all(|a| a.contains(&"--shadow-builtin".to_string()) && !a.iter().any(|x| x.starts_with("--budget"))));
        assert!(Cli::try_parse_from(["dc", "eval", "--budget", "0"]).is_err());
        let cli = Cli::try_parse_from(["dc", "eval", "--budget", "8", "--error-split"]).unwrap();
        let Command::Eval(eval) = cli.command else { panic!("not eval") };
        assert!(simulator_args(&eval, "0..2", &["unet-delta"], None, Some(8)).contains(&"--error-split".to_string()));
    }

    #[test]
    fn eval_refuses_a_model_asked_for_twice_under_one_name() {
        let graph = |models: &str| {
            let cli = Cli::try_parse_from(["dc", "eval", "--seeds", "0..2", "--models", models]).unwrap();
            let Command::Eval(eval) = cli.command else { unreachable!("an eval command") };
            eval_graph(&eval, std::path::Path::new("reports/unused"), None, None).map(|_| ())
        };
        for twice in ["builtin,builtin", "blend,blend:0.5", "none,extrapolate:1,extrapolate"] {
            let e = format!("{:#}", graph(twice).unwrap_err());
            assert!(e.contains("already asked for"), "{twice}: {e}");
        }
        if let Err(e) = graph("builtin,blend:0.5,blend:0.75") {
            assert!(!format!("{e:#}").contains("already asked for"), "{e:#}");
        }
    }

    #[test]
    fn dc_train_picks_its_trainer_by_model() {
        let (node, rest) = train_command(args("--data d --out m.dcu")).unwrap();
        assert_eq!((node, rest), ("unet", args("train --data d --out m.dcu")));
        let (node, rest) = train_command(args("--data d --model gnn --out m.dcg")).unwrap();
        assert_eq!((node, rest), ("gnn-train", args("--data d --out m.dcg")));
        let (node, rest) = train_command(args("--model=unet --epochs 2")).unwrap();
        assert_eq!((node, rest), ("unet", args("train --epochs 2")));
        assert!(train_command(args("--model transformer")).unwrap_err().to_string().contains("unknown model"));
        assert!(train_command(args("--model")).is_err());
    }
}
