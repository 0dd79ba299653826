//! `dc-sim`: the simulator node. Runs simulations in sequence and publishes bodies, contacts (with
//! their final impulses), solver statistics and control messages every step; grid-based warm-start
//! models read their grid from the bus. `dc-sim --bench` runs the benchmark instead (no bus).

use anyhow::{bail, Context, Result};
use msgs::{ControlKind, ControlMsg, StepHeader};
use sim::warm::GridSource;
use sim::{bench, ModelKind, SamplerKind, SceneConfig, SceneKind, SolveParams, WarmStarter, World, WorldParams};
use std::time::{Duration, Instant};

fn positive_f32(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("must be a finite number > 0, got {v}")),
        Err(e) => Err(e.to_string()),
    }
}

fn required_duration(s: &str) -> Result<Duration, String> {
    sim::parse_deadline(s).map_err(|e| e.to_string())?.ok_or_else(|| "a duration is required, not `none`".to_string())
}

/// A grid deadline; `None` is lockstep. A newtype because clap reads `Option<T>` as "flag may be absent".
#[derive(Debug, Clone, Copy)]
struct Deadline(Option<Duration>);

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
    /// Warm-start model: none, builtin, copy, copy0, copy2, bad, random, extrapolate, grid, unet.
    #[arg(long, default_value = "builtin", value_parser = |s: &str| s.parse::<ModelKind>())]
    model: ModelKind,
    /// Several models, each run in turn as its own run (`none,builtin,copy`); overrides --model.
    #[arg(long, value_delimiter = ',', value_parser = |s: &str| s.parse::<ModelKind>())]
    models: Vec<ModelKind>,
    /// Model standing in when a grid is late (a local model).
    #[arg(long, default_value = "builtin", value_parser = |s: &str| s.parse::<ModelKind>())]
    fallback: ModelKind,
    /// Convergence tolerance: largest impulse change of a sweep.
    #[arg(long, default_value_t = 1e-4, value_parser = positive_f32)]
    tolerance: f32,
    /// Sweep cap.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..))]
    max_sweeps: u32,
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
            None => {
                if self.simulations == 0 {
                    bail!("--simulations must be >= 1");
                }
                Ok((self.seed..self.seed + self.simulations).collect())
            }
        }
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
        let mut p = WorldParams {
            solve: SolveParams { tolerance: self.tolerance, max_sweeps: self.max_sweeps },
            ..WorldParams::default()
        };
        p.position.slop = self.slop;
        p
    }
}

/// Whether the node producing our grids is there, as the launcher's notices tell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Producer {
    /// Running: wait up to the deadline (lockstep: up to `lockstep_timeout`).
    Up,
    /// Its node died: no wait, every step falls back.
    Down,
    /// Back (or lost without a notice): wait at most `resume_patience` until a grid arrives. Its
    /// restart may miss the grid of the step in flight, so an unbounded wait could hang forever.
    Resuming,
}

/// The grid of a step from the bus, waiting up to the deadline; later grids are kept for their step.
/// Also watches the control topic for the launcher's notices about the grid's producer. Shared by
/// the warm-start model (which asks for grids) and the step loop, which drains both subscribers
/// every step: grids of other simulators sharing the producer, grids of steps that needed none
/// (no contacts) and our own control messages must never fill a queue, or the producer stalls
/// on it while another simulator waits for its reply.
struct BusGridSource {
    sub: runtime::Subscriber<msgs::GridHeader, f32>,
    control: runtime::Subscriber<msgs::Control, u8>,
    producer: Producer,
    deadline: Option<Duration>,
    lockstep_timeout: Duration,
    resume_patience: Duration,
    /// Simulation ids of this simulator: several simulators may share one grid producer.
    simulations: std::collections::BTreeSet<u32>,
    pending: Option<msgs::Grid>,
    shutdown: runtime::ShutdownSignal,
}

type SharedSource = std::rc::Rc<std::cell::RefCell<BusGridSource>>;

/// The warm-start model's handle on the shared source.
struct SourceHandle(SharedSource);

impl GridSource for SourceHandle {
    fn grid(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Grid> {
        self.0.borrow_mut().grid(run_id, simulation, step)
    }
}

impl BusGridSource {
    /// Applies the launcher's notices about the node that publishes our grid topic.
    fn read_control(&mut self) {
        loop {
            let c = match self.control.try_recv() {
                Ok(Some(c)) => c,
                Ok(None) => return,
                Err(e) => {
                    tracing::warn!("control subscriber: {e}");
                    return;
                }
            };
            let kind = c.header().kind();
            if !matches!(kind, Some(ControlKind::NodeDown | ControlKind::NodeUp)) {
                continue;
            }
            let details: serde_json::Value = serde_json::from_slice(c.items()).unwrap_or_default();
            let topic = self.sub.topic();
            let ours = details["publishes"]
                .as_array()
                .is_some_and(|topics| topics.iter().any(|t| t.as_str() == Some(topic)));
            if !ours {
                continue;
            }
            let node = details["node"].as_str().unwrap_or("?");
            if kind == Some(ControlKind::NodeDown) {
                tracing::warn!(node, topic, "grid producer down: falling back until it returns");
                self.producer = Producer::Down;
            } else {
                tracing::info!(node, topic, "grid producer back: resuming");
                self.producer = Producer::Resuming;
            }
        }
    }

    /// Before step `step` of `simulation`: reads the notices, and takes every grid waiting,
    /// keeping only the newest of ours that this step or a later one can use.
    fn between_steps(&mut self, run_id: u64, simulation: u32, step: u32) {
        self.read_control();
        loop {
            let got = match self.sub.try_recv() {
                Ok(Some(r)) => r,
                Ok(None) => return,
                Err(e) => {
                    tracing::warn!("grid subscriber: {e}");
                    return;
                }
            };
            let h = *got.header();
            // Step k is warm-started from the grid made of step k - 1.
            if !self.is_ours(run_id, &h) || (h.step.simulation, h.step.step) < (simulation, step.saturating_sub(1)) {
                continue;
            }
            self.producer = Producer::Up;
            self.pending = Some(got.into_frame());
        }
    }

    fn is_ours(&self, run_id: u64, h: &msgs::GridHeader) -> bool {
        (run_id == 0 || h.step.run_id == run_id) && self.simulations.contains(&h.step.simulation)
    }

    fn wait_limit(&self) -> Option<Duration> {
        match (self.producer, self.deadline) {
            (Producer::Down, _) => Some(Duration::ZERO),
            (Producer::Resuming, d) => Some(d.map_or(self.resume_patience, |d| d.min(self.resume_patience))),
            (Producer::Up, Some(d)) => Some(d),
            (Producer::Up, None) => None,
        }
    }

    fn grid(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Grid> {
        // Simulations run in increasing id order, so (simulation, step) orders the stream.
        let want = (simulation, step);
        let key = |h: &msgs::GridHeader| (h.step.simulation, h.step.step);
        if let Some(p) = self.pending.take() {
            match key(&p.header).cmp(&want) {
                std::cmp::Ordering::Equal => return Some(p),
                std::cmp::Ordering::Greater => {
                    self.pending = Some(p);
                    return None;
                }
                std::cmp::Ordering::Less => {}
            }
        }
        let start = Instant::now();
        loop {
            self.read_control();
            let waited = start.elapsed();
            let slice = match self.wait_limit() {
                Some(limit) => match limit.checked_sub(waited) {
                    Some(left) if !left.is_zero() => left.min(Duration::from_millis(20)),
                    _ => return None,
                },
                None => {
                    if self.shutdown.is_set() {
                        return None;
                    }
                    if waited >= self.lockstep_timeout {
                        tracing::warn!(
                            simulation, step, waited = ?waited,
                            "no grid within --lockstep-timeout: its producer counts as lost; falling back"
                        );
                        self.producer = Producer::Resuming;
                        return None;
                    }
                    Duration::from_millis(20)
                }
            };
            let got = match self.sub.recv_timeout(slice) {
                Ok(Some(r)) => r,
                Ok(None) => continue,
                Err(e) => {
                    tracing::warn!("grid subscriber: {e}");
                    return None;
                }
            };
            let h = *got.header();
            if !self.is_ours(run_id, &h) {
                continue; // another run's leftovers, or another simulator's grid
            }
            // Grids flow again: back to waiting for each one.
            self.producer = Producer::Up;
            match key(&h).cmp(&want) {
                std::cmp::Ordering::Less => continue, // stale: its step was already solved
                std::cmp::Ordering::Equal => return Some(got.into_frame()),
                std::cmp::Ordering::Greater => {
                    self.pending = Some(got.into_frame());
                    return None;
                }
            }
        }
    }
}

fn run_bench(args: &Args) -> Result<()> {
    let mut cases = Vec::new();
    for part in args.bench_cases.split(',') {
        let (n, steps) = part.split_once(':').context("--bench-cases: expected n:steps,...")?;
        cases.push((n.trim().parse()?, steps.trim().parse()?));
    }
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

fn main() -> Result<()> {
    let args: Args = runtime::parse_args();
    runtime::init_logging();
    if args.bench {
        return run_bench(&args);
    }
    let seeds = args.seeds()?;
    let params = args.world_params();
    params.validate()?;
    if args.fallback.is_grid_based() {
        bail!("--fallback must be a local model, not `{}`", args.fallback.name());
    }
    // Fail before touching the bus when the scene cannot be built.
    sim::Scene::build(&args.scene_config(seeds[0])).context("building the scene")?;

    let node = runtime::Node::from_env("dc-sim")?;
    let models = if args.models.is_empty() { vec![args.model] } else { args.models.clone() };
    let mut pubs = Publishers {
        bodies: node.publisher(msgs::topics::BODIES)?,
        contacts: node.publisher(msgs::topics::CONTACTS)?,
        stats: node.publisher(msgs::topics::SOLVE_STATS)?,
        control: node.publisher(msgs::topics::CONTROL)?,
    };
    // Grid-based runs open their grid and control subscribers for the run only (see `run`).
    for model in &models {
        if let Some(topic) = grid_topic(*model) {
            node.will_subscribe(topic.name);
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
        run(&args, &node, &mut pubs, model, first_run_id + i as u64, &seeds, params)?;
    }
    Ok(())
}

/// The topic a grid-based model reads its warm starts from.
fn grid_topic(model: ModelKind) -> Option<msgs::topics::Topic<msgs::GridHeader, f32>> {
    match model {
        ModelKind::Grid => Some(msgs::topics::GRID_CONTACTS),
        ModelKind::Unet => Some(msgs::topics::GRID_UNET),
        _ => None,
    }
}

/// Prefix of the JSON line with a run's totals on stdout.
const RUN_SUMMARY_PREFIX: &str = "dc-sim run ";

/// The simulator's publishers.
struct Publishers {
    bodies: runtime::Publisher<StepHeader, msgs::Body>,
    contacts: runtime::Publisher<StepHeader, msgs::Contact>,
    stats: runtime::Publisher<msgs::SolveStatsHeader, f32>,
    control: runtime::Publisher<msgs::Control, u8>,
}

/// One run: every seed with one warm-start model.
#[allow(clippy::too_many_arguments)]
fn run(
    args: &Args,
    node: &runtime::Node,
    pubs: &mut Publishers,
    model_kind: ModelKind,
    run_id: u64,
    seeds: &[u64],
    params: WorldParams,
) -> Result<()> {
    let Publishers { bodies: bodies_pub, contacts: contacts_pub, stats: stats_pub, control: control_pub } = pubs;
    // The grid subscriber exists only during a grid-based run: a grid producer publishes with
    // back-pressure, and a subscriber nobody reads (another model's run) would fill up and stall
    // the producer, which stalls the simulator in turn (a deadlock seen in `dc eval`). In lockstep
    // at most one grid is outstanding, so the loop cannot fill it.
    let topic = grid_topic(model_kind);
    let shared: Option<SharedSource> = match topic {
        Some(topic) => Some(std::rc::Rc::new(std::cell::RefCell::new(BusGridSource {
            sub: node.subscriber(topic)?,
            // Our own control messages arrive here too; the step loop drains it every step.
            control: node.subscriber(msgs::topics::CONTROL)?,
            producer: Producer::Up,
            deadline: args.deadline.0,
            lockstep_timeout: args.lockstep_timeout,
            resume_patience: args.resume_patience,
            simulations: seeds.iter().map(|&s| s as u32).collect(),
            pending: None,
            shutdown: node.shutdown_signal(),
        }))),
        None => None,
    };
    let source = shared.clone().map(|s| Box::new(SourceHandle(s)) as Box<dyn GridSource>);
    let model = model_kind.build_with_source(args.seed, source)?;
    let mut warm = WarmStarter::new(model, args.fallback.build(args.seed)?);
    let run_header = StepHeader { run_id, simulation: 0, step: 0 };
    let details = serde_json::json!({
        "scene": args.scene.name(), "n": args.n, "seeds": seeds, "steps": args.steps,
        "model": model_kind.name(), "fallback": args.fallback.name(), "tolerance": args.tolerance,
        "max_sweeps": args.max_sweeps, "sampler": format!("{:?}", args.sampler).to_lowercase(),
        "dt": params.dt,
    });
    control_pub.publish_frame(&ControlMsg::control(run_header, ControlKind::RunStart, seeds.len() as u32, &details.to_string()))?;
    tracing::info!(run_id, simulations = seeds.len(), model = model_kind.name(), "run start");

    let (mut bodies, mut contacts, mut residuals) = (Vec::new(), Vec::new(), Vec::new());
    // The run's totals, printed on stdout at its end (benchmarks read them).
    let (mut run_steps, mut run_secs, mut run_sweeps, mut run_fallbacks) = (0u64, 0f64, 0u64, 0u64);
    'run: for &seed in seeds {
        let simulation = u32::try_from(seed).context("seeds must fit in u32 (they are simulation ids)")?;
        let mut world = World::new(&args.scene_config(seed), params)?;
        world.set_ids(run_id, simulation);
        warm.begin_simulation(simulation, seed);
        let sim_header = StepHeader { run_id, simulation, step: 0 };
        let scene_details = serde_json::json!({
            "seed": seed, "side": world.scene().side, "bodies": world.bodies().len(),
            "dynamic": world.scene().dynamic_count(), "omega": world.scene().omega,
        });
        control_pub.publish_frame(&ControlMsg::control(sim_header, ControlKind::SimulationStart, args.steps, &scene_details.to_string()))?;
        let (mut total_sweeps, mut unconverged) = (0u64, 0u32);
        let started = Instant::now();
        for step in 0..args.steps {
            if node.is_shutdown() {
                break 'run;
            }
            if let Some(source) = &shared {
                source.borrow_mut().between_steps(run_id, simulation, step);
            }
            let stats = world.step(&mut warm).clone();
            let header = StepHeader { run_id, simulation, step };
            total_sweeps += stats.solve.sweeps as u64;
            unconverged += (!stats.solve.converged) as u32;
            world.body_msgs(&mut bodies);
            world.contact_msgs(&mut contacts);
            residuals.clear();
            residuals.extend(world.residuals().iter().take(msgs::MAX_RESIDUALS));
            let used = if stats.fallback { warm.fallback.name() } else { warm.model.name() };
            let stats_header = stats.to_msg(header, warm.model.name(), used);
            bodies_pub.publish(&header, &bodies)?;
            contacts_pub.publish(&header, &contacts)?;
            stats_pub.publish(&stats_header, &residuals)?;
        }
        control_pub.publish_frame(&ControlMsg::control(
            StepHeader { step: world.steps_taken(), ..sim_header },
            ControlKind::SimulationEnd,
            world.steps_taken(),
            "",
        ))?;
        tracing::info!(
            seed,
            steps = world.steps_taken(),
            total_sweeps,
            unconverged,
            fallbacks = warm.fallbacks_total(),
            secs = started.elapsed().as_secs_f32(),
            "simulation done"
        );
        run_steps += world.steps_taken() as u64;
        run_secs += started.elapsed().as_secs_f64();
        run_sweeps += total_sweeps;
        run_fallbacks += warm.fallbacks_total() as u64;
    }
    control_pub.publish_frame(&ControlMsg::control(run_header, ControlKind::RunEnd, seeds.len() as u32, ""))?;
    tracing::info!(run_id, "run end");
    let summary = serde_json::json!({
        "run_id": run_id, "model": model_kind.name(), "steps": run_steps, "loop_secs": run_secs,
        "total_sweeps": run_sweeps, "fallbacks": run_fallbacks,
    });
    println!("{RUN_SUMMARY_PREFIX}{summary}");
    Ok(())
}
