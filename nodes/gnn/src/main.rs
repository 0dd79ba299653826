//! `dc-gnn`: the contact-graph network's node and tools. `dc-gnn --model FILE` is the node: each
//! step's problem in (`problem/bodies` + `problem/contacts`, which a simulator running `gnn-node`
//! publishes before it solves), its per-contact warm start out (`warm/gnn`). `bench` times a
//! prediction for a pile of a given size on one core (target: <= 0.3 ms for 200 contacts);
//! `info FILE` prints a model file; `init --out FILE` writes an untrained network (its warm start
//! is builtin's, exactly).

use anyhow::Result;
use clap::{Parser, Subcommand};
use gnn::net::{Net, NetConfig};
use gnn::{ModelFile, Predictor};
use msgs::{ProblemBody, ProblemContact};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(
    name = "dc-gnn",
    about = "Contact-graph network warm start: the node (default: serves warm starts on the bus); bench, model files",
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    serve: ServeArgs,
}

/// The node's parameters.
#[derive(clap::Args, Debug)]
struct ServeArgs {
    /// The network (`dc train --model gnn` writes one).
    #[arg(long, default_value_os_t = runtime::shipped("models/gnn.dcg"))]
    model: PathBuf,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Median time of one warm start (features + network) for a synthetic pile.
    Bench {
        #[arg(long, default_value_t = 200)]
        contacts: usize,
        /// Bodies of the pile (contacts join random neighbours, a few touch the floor).
        #[arg(long, default_value_t = 100)]
        bodies: usize,
        #[command(flatten)]
        net: NetConfig,
        #[arg(long, default_value_t = 2000)]
        reps: usize,
    },
    /// Prints a model file.
    Info { file: PathBuf },
    /// Rewrites a format-1 model file (whose checksum covers the weights only) as format 2,
    /// whose checksum covers everything; in place unless `--out` is given.
    Upgrade {
        file: PathBuf,
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Writes an untrained network (decoder at zero: builtin's warm start).
    Init {
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        net: NetConfig,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// A pile-like problem: body 0 is the floor, contacts between neighbouring bodies.
fn synthetic_pile(bodies: usize, contacts: usize) -> (Vec<ProblemBody>, Vec<ProblemContact>) {
    let mut b = vec![ProblemBody::default()];
    b.extend((1..bodies.max(2)).map(|i| ProblemBody {
        v: [0.01 * (i % 7) as f32, -0.098],
        w: 0.0,
        inv_mass: 1.0 / (0.5 + (i % 5) as f32 * 0.1),
        inv_inertia: 8.0,
    }));
    let n = b.len() as u32;
    let c = (0..contacts as u32)
        .map(|i| {
            let a = if i % 10 == 0 { 0 } else { 1 + i % (n - 1) };
            let bb = 1 + (i * 7 + 3) % (n - 1);
            let (a, bb) = if a == bb { (0, bb) } else { (a.min(bb), a.max(bb)) };
            let angle = i as f32 * 0.37;
            ProblemContact {
                body_a: a,
                body_b: bb,
                feature: i,
                age: i % 40,
                ra: [0.25 * angle.cos(), 0.25 * angle.sin()],
                rb: [-0.25 * angle.cos(), -0.25 * angle.sin()],
                normal: [angle.cos(), angle.sin()],
                friction: 0.5,
                penetration: 0.001,
                previous: [0.3 + 0.01 * (i % 13) as f32, 0.01],
                before_previous: [0.3, 0.0],
                reference: [f32::NAN; 2],
                height: 0.0,
            }
        })
        .collect();
    (b, c)
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    // A model file that cannot be read fails the launcher's parameter check, not the run.
    let Some(cli) = runtime::parse_args_checked::<Cli, _>(|c| match &c.command {
        None => ModelFile::load(&c.serve.model).map(|_| ()),
        Some(_) => Ok(()),
    }) else {
        return Ok(());
    };
    runtime::init_logging();
    let Some(command) = cli.command else { return serve(&cli.serve.model) };
    match command {
        Command::Bench { contacts, bodies, net: config, reps } => {
            let NetConfig { hidden, rounds } = config;
            let (b, c) = synthetic_pile(bodies, contacts);
            let mut net = Net::new(config, 1);
            // A trained network's decoder is not zero; its cost is the same either way.
            net.decode = gnn::net::Linear::glorot(net.readout_width(), 2, &mut sph::SplitMix64::new(2));
            let mut p = Predictor::new(net);
            let mut out = vec![[0.0f32; 2]; c.len()];
            for _ in 0..reps.min(100) {
                p.warm_start(&b, &c, &mut out)?;
            }
            let mut times: Vec<f64> = (0..reps.max(1))
                .map(|_| {
                    let t = Instant::now();
                    let _ = p.warm_start(&b, &c, &mut out);
                    t.elapsed().as_secs_f64() * 1e6
                })
                .collect();
            times.sort_by(f64::total_cmp);
            let (median, p99) = (times[times.len() / 2], times[(times.len() * 99) / 100]);
            println!(
                "dc-gnn bench: {} contacts, {} bodies, hidden {hidden}, {rounds} rounds, one core: median {median:.1} us, p99 {p99:.1} us (target <= 300 us for 200 contacts)",
                c.len(),
                b.len()
            );
        }
        Command::Info { file } => {
            let m = ModelFile::load(&file)?;
            println!("{}: format {}, {:?}, checksum {:016x}", file.display(), m.format, m.net.config, m.checksum);
            println!("  made by: {}", m.provenance);
        }
        Command::Upgrade { file, out } => {
            let out = out.unwrap_or_else(|| file.clone());
            let m = ModelFile::upgrade(&file, &out)?;
            println!("wrote {} (format {}, checksum {:016x})", out.display(), m.format, m.checksum);
        }
        Command::Init { out, net, seed } => {
            let m = ModelFile::new(Net::new(net, seed), "dc-gnn init (untrained: builtin)");
            m.save(&out)?;
            println!("wrote {}", out.display());
        }
    }
    Ok(())
}

/// The node loop: pairs each step's problem bodies and contacts, predicts, publishes.
fn serve(model: &std::path::Path) -> Result<()> {
    use msgs::{topics, Contact, ProblemHeader};
    let node = runtime::Node::from_env("dc-gnn")?;
    let mut bodies = node.subscriber(topics::PROBLEM_BODIES)?;
    let mut contacts = node.subscriber(topics::PROBLEM_CONTACTS)?;
    let mut control = node.subscriber(topics::CONTROL)?;
    let mut warm = node.publisher(topics::WARM_GNN)?;
    // A node only described (its ports) reads no model: the file may be on another host.
    let loaded = if runtime::describing() { None } else { Some(ModelFile::load(model)?) };
    let (true, Some(file)) = (node.ready()?, loaded) else { return Ok(()) };
    let mut predictor = Predictor::new(file.net);
    tracing::info!(model = %model.display(), made_by = file.provenance, "dc-gnn serving");
    let mut pairer: sph::StepPairer<Vec<ProblemBody>, (ProblemHeader, Vec<ProblemContact>)> = sph::StepPairer::new();
    let (mut out, mut reply) = (Vec::new(), Vec::<Contact>::new());
    let (mut served, mut refused, mut busy) = (0u64, 0u64, std::time::Duration::ZERO);
    while !node.is_shutdown() {
        while let Some(c) = control.try_recv()? {
            node.observe_control(c.header());
        }
        // The simulator publishes a step's bodies, then its contacts, then waits for the answer.
        match contacts.recv_timeout(std::time::Duration::from_millis(50)) {
            Err(_) if node.is_shutdown() => break,
            other => {
                if let Some(r) = other? {
                    pairer.push_b(r.header().step, (*r.header(), r.into_frame().items));
                }
            }
        }
        while let Some(r) = bodies.try_recv()? {
            pairer.push_a(*r.header(), r.into_frame().items);
        }
        while let Some(r) = contacts.try_recv()? {
            pairer.push_b(r.header().step, (*r.header(), r.into_frame().items));
        }
        while let Some((step, b, (_, c))) = pairer.pop() {
            let t = Instant::now();
            out.clear();
            out.resize(c.len(), [0.0; 2]);
            if let Err(e) = predictor.warm_start(&b, &c, &mut out) {
                // No reply: the simulator falls back for this step (counted there), as for a
                // late one; logged once in full, then counted.
                if refused == 0 {
                    tracing::error!(topic = topics::WARM_GNN.name, step = ?step, "not served: {e}");
                }
                refused += 1;
                continue;
            }
            reply.clear();
            reply.extend(c.iter().zip(&out).map(|(c, o)| Contact {
                body_a: c.body_a,
                body_b: c.body_b,
                feature: c.feature,
                nx: c.normal[0],
                ny: c.normal[1],
                penetration: c.penetration,
                friction: c.friction,
                normal_impulse: o[0],
                tangent_impulse: o[1],
                ..Default::default()
            }));
            busy += t.elapsed();
            warm.publish(&step, &reply)?;
            served += 1;
        }
    }
    let mean_us = if served > 0 { busy.as_secs_f64() * 1e6 / served as f64 } else { 0.0 };
    tracing::info!(
        served,
        refused_non_finite = refused,
        mean_us = format!("{mean_us:.1}"),
        unpaired = pairer.dropped() + pairer.pending() as u64,
        "dc-gnn done"
    );
    Ok(())
}
