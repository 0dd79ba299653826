//! dc-unet: the U-Net inference node (subscribes `grid/bodies`, publishes the predicted impulse
//! grid on `grid/unet` for the simulator's next step) and its tools: `train`, `lr-find`, `info`,
//! `bench`.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use msgs::{topics, ControlKind, Grid, GridHeader};
use std::path::PathBuf;
use std::time::{Duration, Instant};
use unet::schedule::Schedule;
use unet::train::{LossKind, OptimizerKind, TrainOptions};
use unet::{GridSpec, ModelFile, Predictor, UNetConfig};

#[derive(Parser, Debug)]
#[command(
    name = "dc-unet",
    about = "U-Net warm-start node; `train`, `lr-find`, `info`, `bench` subcommands",
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    node: NodeArgs,
}

#[derive(Args, Debug)]
struct NodeArgs {
    /// Model file (written by `dc-unet train`).
    #[arg(long, default_value_os_t = runtime::shipped("models/unet-demo.dcu"))]
    model: PathBuf,
    /// Backend: flex (CPU); with the `tch` feature also libtorch, cuda, cuda:N.
    #[arg(long, default_value = "flex", value_parser = unet::device_name)]
    device: String,
    /// Most grids predicted in one batch (grids of several simulators waiting at once; 1 to 1024).
    #[arg(long, default_value_t = 16, value_parser = usize_in(1..=1024))]
    max_batch: usize,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Train a model from recordings.
    Train(TrainArgs),
    /// Learning-rate finder: exponential sweep, loss-vs-rate PNG and CSV, a suggested rate.
    LrFind(LrFindArgs),
    /// What a model file holds.
    Info { model: PathBuf },
    /// Rewrite a model file of an older format (no checksum) as the current one, after checking
    /// that its weights fit its configuration and are finite.
    Upgrade {
        model: PathBuf,
        /// Where to write it (default: over the input).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// The `dc-sph` arguments that make this model's input grids, one per line (`dc eval` uses them).
    SphArgs { model: PathBuf },
    /// Inference and training-step timings per backend.
    Bench(BenchArgs),
}

#[derive(Args, Debug, Clone)]
struct NetArgs {
    /// Downsampling levels (grid sides must be multiples of 2^levels; at most 7).
    #[arg(long, default_value_t = 3, value_parser = usize_in(0..=7))]
    levels: usize,
    /// Channels of the first level (doubling per level; 1 to 256).
    #[arg(long, default_value_t = 8, value_parser = usize_in(1..=unet::model::MAX_BASE_WIDTH as u64))]
    base_width: usize,
    /// Dilations of the bottom's parallel convolutions (each 1 to 64).
    #[arg(long, value_delimiter = ',', default_value = "2,4,8",
          value_parser = usize_in(1..=unet::model::MAX_DILATION as u64))]
    dilations: Vec<usize>,
    /// Bodies only (5 channels) instead of bodies + the step's impulses (7).
    #[arg(long)]
    no_temporal: bool,
    /// Predict impulses directly instead of a correction to the previous step's (temporal only).
    #[arg(long)]
    no_residual: bool,
    /// Grid: kernel.
    #[arg(long, default_value = "poly6")]
    kernel: String,
    /// Grid: kernel support radius, metres (above 0, at most 100).
    #[arg(long, default_value_t = 0.5, value_parser = msgs::flags::f32_above(0.0, 100.0))]
    h: f32,
    /// Grid: node spacing, metres (above 0, at most 100).
    #[arg(long, default_value_t = 0.125, value_parser = msgs::flags::f32_above(0.0, 100.0))]
    res: f32,
    /// Grid: preserving or sph.
    #[arg(long, default_value = "preserving")]
    mode: String,
    /// Grid: sides rounded up to a multiple of this (1 to 4096, the largest grid side).
    #[arg(long, default_value_t = 128, value_parser = usize_in(1..=4096))]
    pad_to: usize,
}

impl NetArgs {
    fn grid(&self) -> GridSpec {
        GridSpec {
            kernel: self.kernel.clone(),
            h: self.h,
            res: self.res,
            mode: self.mode.clone(),
            pad_to: self.pad_to,
            temporal: !self.no_temporal,
        }
    }
    fn net(&self) -> UNetConfig {
        let temporal = !self.no_temporal;
        UNetConfig {
            in_channels: if temporal { 7 } else { 5 },
            out_channels: 2,
            levels: self.levels,
            base_width: self.base_width,
            dilations: self.dilations.clone(),
            residual: (temporal && !self.no_residual).then_some([5, 6]),
        }
    }
}

#[derive(Args, Debug)]
struct TrainArgs {
    /// Recordings (.mcap) or folders of them; several are one data set (`--data a.mcap shards/*/`:
    /// the recordings of several hosts or shards).
    #[arg(long, required = true, num_args = 1..)]
    data: Vec<PathBuf>,
    /// The model file to write.
    #[arg(long, default_value = "models/unet.dcu")]
    out: PathBuf,
    #[command(flatten)]
    net: NetArgs,
    /// Passes over the training data (at most 100000).
    #[arg(long, default_value_t = 4, value_parser = usize_in(0..=100_000))]
    epochs: usize,
    /// Samples per optimiser step (1 to 4096).
    #[arg(long, default_value_t = 8, value_parser = usize_in(1..=4096))]
    batch: usize,
    /// adam or sgd (momentum 0.9).
    #[arg(long, default_value = "adam")]
    optimizer: OptimizerKind,
    /// constant:LR, triangular:MIN:MAX:HALF_CYCLE_STEPS, cosine:MIN:MAX:PERIOD_STEPS[:MULT].
    #[arg(long, default_value = "cosine:1e-5:1e-3:200:2", value_parser = Schedule::parse)]
    schedule: Schedule,
    /// Extra loss weight where the target impulse is non-zero (0 = plain MSE; at most 1e6).
    #[arg(long, default_value_t = 0.0, value_parser = msgs::flags::f32_in(0.0, 1e6))]
    contact_weight: f32,
    /// grid: MSE over every grid node (the thesis's); points: at the next step's contact points
    /// as `unet-delta` reads them (the change on persisting contacts), weighted by the step's
    /// sweeps; reference: as points, against the step's reference solution (recordings with
    /// labelled problems); unrolled: the residual left after --unroll-sweeps PGS sweeps of the
    /// next step's problem from the warm start `unet-delta` reads (recordings with
    /// `--publish-problem`: a warm start for a sweep budget).
    #[arg(long, default_value = "grid")]
    loss: LossKind,
    /// With `--loss unrolled`: the sweep budget trained for (1 to 1000).
    #[arg(long, default_value_t = 8, value_parser = usize_in(1..=1000))]
    unroll_sweeps: usize,
    /// With `--loss unrolled`: weight of a normal row still adding impulse after the sweeps (too
    /// little push: it accumulates as penetration) against 1 for the rest (the gnn-budget recipe's
    /// 4; above 0, at most 1e6).
    #[arg(long, default_value_t = 4.0, value_parser = msgs::flags::f64_above(0.0, 1e6))]
    approach_weight: f64,
    /// Share of simulations held out for validation / test (each from 0 to 0.5).
    #[arg(long, default_value_t = 0.1, value_parser = msgs::flags::f64_in(0.0, 0.5))]
    validation: f64,
    #[arg(long, default_value_t = 0.1, value_parser = msgs::flags::f64_in(0.0, 0.5))]
    test: f64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Samples held for shuffling (1 to 65536).
    #[arg(long, default_value_t = 256, value_parser = usize_in(1..=65_536))]
    shuffle_buffer: usize,
    /// Batches per epoch at most (0 = all).
    #[arg(long, default_value_t = 0)]
    max_batches: usize,
    /// Continue from `<out>.checkpoints/`.
    #[arg(long)]
    resume: bool,
    /// Leave out (and list) recordings of the folder that do not read intact (`--skip-bad
    /// false`: the first one is an error).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    skip_bad: bool,
    /// Backend: flex (CPU); with the `tch` feature also libtorch, cuda, cuda:N.
    #[arg(long, default_value = "flex", value_parser = unet::device_name)]
    device: String,
}

impl TrainArgs {
    fn options(&self) -> TrainOptions {
        TrainOptions {
            data: self.data.clone(),
            out: self.out.clone(),
            net: self.net.net(),
            grid: self.net.grid(),
            epochs: self.epochs,
            batch: self.batch.max(1),
            optimizer: self.optimizer,
            schedule: self.schedule.clone(),
            contact_weight: self.contact_weight,
            loss: self.loss,
            unroll_sweeps: self.unroll_sweeps,
            approach_weight: self.approach_weight,
            validation_fraction: self.validation,
            test_fraction: self.test,
            seed: self.seed,
            skip_bad: self.skip_bad,
            shuffle_buffer: self.shuffle_buffer,
            max_batches: self.max_batches,
            resume: self.resume,
            progress: std::io::IsTerminal::is_terminal(&std::io::stderr()),
            command: std::env::args().collect::<Vec<_>>().join(" "),
        }
    }
}

#[derive(Args, Debug)]
struct LrFindArgs {
    #[command(flatten)]
    train: TrainArgs,
    /// First and last rate of the sweep (above 0, at most 10; start below end).
    #[arg(long, default_value_t = 1e-6, value_parser = msgs::flags::f64_above(0.0, 10.0))]
    start: f64,
    #[arg(long, default_value_t = 1.0, value_parser = msgs::flags::f64_above(0.0, 10.0))]
    end: f64,
    /// Steps of the sweep (2 to 100000).
    #[arg(long, default_value_t = 100, value_parser = usize_in(2..=100_000))]
    steps: usize,
}

#[derive(Args, Debug)]
struct BenchArgs {
    /// Repetitions per measurement (median reported; 1 to 100000).
    #[arg(long, default_value_t = 10, value_parser = usize_in(1..=100_000))]
    reps: usize,
    /// Backends to time (default: every one this build has).
    #[arg(long, value_delimiter = ',', value_parser = unet::device_name)]
    devices: Vec<String>,
    /// Networks: `demo` (this repo's model shape) and/or `thesis` (levels 4, width 16: 2.7M parameters, the size of the thesis network).
    #[arg(long, value_delimiter = ',', default_value = "demo,thesis")]
    nets: Vec<String>,
}

/// The parser of a `usize` flag in `range`.
fn usize_in(range: std::ops::RangeInclusive<u64>) -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::<usize>::new().range(range)
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    // The node's model file is checked with its parameters (the launcher's check on the host
    // that runs it), so a missing or foreign file fails before the graph starts.
    let check = |cli: &Cli| match cli.command {
        None => ModelFile::read_meta(&cli.node.model).map(|_| ()).context("--model"),
        Some(_) => Ok(()),
    };
    let Some(cli) = runtime::parse_args_checked::<Cli, _>(check) else { return Ok(()) };
    runtime::init_logging();
    match cli.command {
        None => run_node(cli.node),
        Some(Command::Train(a)) => {
            let device = unet::device(&a.device)?;
            let meta = unet::train::train(&a.options(), &device)?;
            print_summary(&a.out, &meta);
            Ok(())
        }
        Some(Command::LrFind(a)) => {
            if a.start >= a.end {
                bail!("--start {} must be below --end {}", a.start, a.end);
            }
            let device = unet::device(&a.train.device)?;
            let opts = a.train.options();
            let (curve, suggestion) = unet::train::find_lr(&opts, a.start, a.end, a.steps, &device)?;
            println!(
                "lr finder: {} steps, curve in {} and {}",
                curve.len(),
                opts.out.with_extension("lr.csv").display(),
                opts.out.with_extension("lr.png").display()
            );
            match suggestion {
                Some(lr) => println!("suggested learning rate: {lr:.3e} (steepest descent of the smoothed loss)"),
                None => println!("no suggestion: the loss never fell; try a lower --start"),
            }
            Ok(())
        }
        Some(Command::Info { model }) => {
            let meta = ModelFile::read_meta(&model)?;
            print_summary(&model, &meta);
            Ok(())
        }
        Some(Command::Upgrade { model, out }) => {
            let out = out.unwrap_or_else(|| model.clone());
            let device = unet::device("flex")?;
            let file = ModelFile::upgrade(&model, &out, &device)?;
            println!("{}: written as the current format", out.display());
            print_summary(&out, &file.meta);
            Ok(())
        }
        Some(Command::SphArgs { model }) => {
            for arg in ModelFile::read_meta(&model)?.grid.sph_args() {
                println!("{arg}");
            }
            Ok(())
        }
        Some(Command::Bench(a)) => bench(&a),
    }
}

fn print_summary(path: &std::path::Path, meta: &unet::ModelMeta) {
    let t = &meta.training;
    println!("model {}", path.display());
    println!("  network: {:?}", meta.config);
    println!("  grid: {:?}, shape {:?}, inputs {:?}", meta.grid, meta.grid_shape, meta.input_channels);
    println!("  data: {} ({} training samples, {} validation samples)", t.data, t.train_samples, t.validation_samples);
    println!(
        "  split: {} train / {} validation / {} test simulations",
        t.split.train.len(),
        t.split.validation.len(),
        t.split.test.len()
    );
    println!("  epochs: {}, {:.0} s", t.epochs, t.seconds);
    println!("  train loss per epoch: {:?}", t.train_loss.iter().map(|l| format!("{l:.4}")).collect::<Vec<_>>());
    println!(
        "  validation loss per epoch: {:?}",
        t.validation_loss.iter().map(|l| format!("{l:.4}")).collect::<Vec<_>>()
    );
    if let Some(p) = t.validation_loss_previous {
        println!("  validation loss of the previous step's impulses (`grid`; builtin with --loss unrolled): {p:.4}");
    }
}

/// The node: one prediction per received bodies grid, batched when several wait.
fn run_node(args: NodeArgs) -> Result<()> {
    let node = runtime::Node::from_env("dc-unet")?;
    let mut grids_in = node.subscriber::<GridHeader, f32>(topics::GRID_BODIES)?;
    let mut control = node.subscriber(topics::CONTROL)?;
    let mut grids_out = node.publisher(topics::GRID_UNET)?;
    // A node only described (its ports) reads no model: the file may be on another host.
    let loaded = if runtime::describing() {
        None
    } else {
        let device = unet::device(&args.device)?;
        let loaded = Predictor::load(&args.model, &device);
        Some(loaded.with_context(|| format!("loading the model {}", args.model.display()))?)
    };
    let (true, Some(predictor)) = (node.ready()?, loaded) else { return Ok(()) };
    tracing::info!(model = %args.model.display(), device = args.device, inputs = ?predictor.meta().input_channels, "dc-unet ready");
    let (mut predicted, mut rejected, mut batches) = (0u64, 0u64, 0u64);
    let mut busy = Duration::ZERO;
    let mut pending: Vec<Grid> = Vec::new();
    let mut run_uses_unet: std::collections::HashMap<u64, bool> = Default::default();
    let (mut skipped, mut refused) = (0u64, 0u64);
    while !node.is_shutdown() {
        match grids_in.recv_timeout(Duration::from_millis(50)) {
            Ok(Some(g)) => pending.push(g.into_frame()),
            Ok(None) => {}
            Err(_) if node.is_shutdown() => break,
            Err(e) => return Err(e.into()),
        }
        while pending.len() < args.max_batch.max(1) {
            match grids_in.try_recv()? {
                Some(g) => pending.push(g.into_frame()),
                None => break,
            }
        }
        // Read control after the grids: a run's start is published before its first bodies, so
        // every grid in hand belongs to a run already announced (or to one started without us).
        while let Some(c) = control.try_recv()? {
            node.observe_control(c.header());
            if c.header().kind() == Some(ControlKind::RunStart) {
                match msgs::control::details_of(c.header(), c.items()) {
                    Ok(msgs::ControlDetails::RunStart(p)) => {
                        // `unet`, `unet-delta`: every model that reads our topic.
                        let served = msgs::models::served_on(&p.model);
                        run_uses_unet.insert(c.header().step.run_id, served == Some(topics::GRID_UNET.name));
                    }
                    // Unknown runs are served (see below).
                    other => tracing::warn!("control: a run start whose details do not decode: {other:?}"),
                }
            }
        }
        // Grids of runs with another warm-start model (an evaluation runs several) are drained
        // unread: predicting them would only slow those runs down. Unknown runs are served.
        let before = pending.len();
        pending.retain(|g| run_uses_unet.get(&g.header.step.run_id).copied().unwrap_or(true));
        skipped += (before - pending.len()) as u64;
        if pending.is_empty() {
            continue;
        }
        let t = Instant::now();
        // A grid the model cannot take is answered with an empty grid, so that a simulator in
        // lockstep falls back for that step at once instead of waiting for ever.
        let mut good: Vec<&Grid> = Vec::with_capacity(pending.len());
        for g in &pending {
            match predictor.check(g) {
                Ok(()) => good.push(g),
                Err(e) => {
                    rejected += 1;
                    tracing::error!(topic = topics::GRID_BODIES.name, "{e}");
                    grids_out.publish(&GridHeader { channels: 0, ..g.header }, &[])?;
                }
            }
        }
        for (g, out) in good.iter().zip(predictor.predict_batch(&good)?) {
            match out {
                Ok(out) => {
                    grids_out.publish_frame(&out)?;
                    predicted += 1;
                }
                Err(e) => {
                    // Answered empty, as a grid the model cannot take: the simulator falls back.
                    if refused == 0 {
                        tracing::error!(topic = topics::GRID_UNET.name, "not served: {e}");
                    }
                    refused += 1;
                    grids_out.publish(&GridHeader { channels: 0, ..g.header }, &[])?;
                }
            }
        }
        batches += 1;
        busy += t.elapsed();
        pending.clear();
    }
    tracing::info!(
        predicted,
        rejected,
        refused_non_finite = refused,
        skipped,
        batches,
        mean_batch_ms = busy.as_secs_f64() * 1e3 / batches.max(1) as f64,
        "dc-unet done"
    );
    Ok(())
}

fn bench(args: &BenchArgs) -> Result<()> {
    use burn::module::Module;
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::{Distribution, Tensor};
    let devices: Vec<String> = if args.devices.is_empty() {
        unet::backends().iter().filter(|d| **d != "cuda").map(|d| d.to_string()).collect()
    } else {
        args.devices.clone()
    };
    let reps = args.reps.max(1);
    println!("dc-unet bench: median of {reps} runs after one warm-up; input 128 x 128, 5 channels (thesis input)");
    println!("| net | params | device | infer b=1 ms | infer b=16 ms | train step b=8 ms |");
    println!("|---|---|---|---|---|---|");
    let mut rows: Vec<(String, String, f64)> = Vec::new();
    for net_name in &args.nets {
        let config = match net_name.as_str() {
            "demo" => UNetConfig { in_channels: 5, residual: None, ..UNetConfig::default() },
            "thesis" => UNetConfig {
                in_channels: 5,
                out_channels: 2,
                levels: 4,
                base_width: 16,
                dilations: vec![2, 4, 8],
                residual: None,
            },
            other => bail!("unknown net `{other}` (demo, thesis)"),
        };
        for name in &devices {
            let device = unet::device(name)?;
            device.seed(0);
            let model = config.init(&device).valid();
            let time = |batch: usize| -> Result<f64> {
                let mut times = Vec::new();
                for i in 0..=reps {
                    let x = Tensor::<4>::random([batch, 5, 128, 128], Distribution::Default, &device);
                    device.sync().ok();
                    let t = Instant::now();
                    let y = model.forward(x);
                    let _: Vec<f32> = y.into_data().try_into_vec().map_err(|e| anyhow::anyhow!("{e:?}"))?;
                    if i > 0 {
                        times.push(t.elapsed().as_secs_f64() * 1e3);
                    }
                }
                Ok(charts::median(&times))
            };
            let b1 = time(1)?;
            let b16 = time(16)?;
            let ad = device.clone().autodiff();
            let mut train_model = config.init(&ad);
            let mut optim = AdamConfig::new().init();
            let mut times = Vec::new();
            for i in 0..=reps.min(5) {
                let x = Tensor::<4>::random([8, 5, 128, 128], Distribution::Default, &ad);
                let y = Tensor::<4>::random([8, 2, 128, 128], Distribution::Default, &ad);
                let t = Instant::now();
                let loss = (train_model.forward(x) - y).square().mean();
                let grads = GradientsParams::from_grads(loss.backward(), &train_model);
                train_model = optim.step(1e-4, train_model, grads);
                ad.sync().ok();
                if i > 0 {
                    times.push(t.elapsed().as_secs_f64() * 1e3);
                }
            }
            let step = charts::median(&times);
            println!("| {net_name} | {} | {name} | {b1:.2} | {b16:.1} | {step:.0} |", model.num_params());
            rows.push((net_name.clone(), name.clone(), b1));
        }
    }
    for net in &args.nets {
        let get = |d: &str| rows.iter().find(|r| &r.0 == net && r.1 == d).map(|r| r.2);
        if let (Some(f), Some(t)) = (get("flex"), get("libtorch")) {
            println!("{net}: flex / libtorch CPU at batch 1 = {:.2}x (target <= 2x)", f / t);
        }
    }
    Ok(())
}
