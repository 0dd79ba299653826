//! dc-sph: the SPH-grid node. Subscribes to bodies and contacts, pairs them by step, publishes the
//! bodies grid (`grid/bodies`, the U-Net's input) and the impulse grid (`grid/contacts`, the `grid`
//! warm-start model) of every step. `dc-sph bench` times the scatter (the transfer-error study
//! is an experiment: `dc-sph-study` in the `experiments` crate).

mod commands;

use anyhow::Result;
use clap::Parser;
use msgs::{topics, Body, Contact, ControlKind, Frame, StepHeader};
use sph::{Bounds, GridGeometry, StepPairer, Transfer};
use std::time::{Duration, Instant};

#[derive(Parser, Debug)]
#[command(
    name = "dc-sph",
    about = "SPH grid transfer node; `bench` subcommand",
    args_conflicts_with_subcommands = true
)]
struct Args {
    #[command(subcommand)]
    command: Option<commands::Command>,
    #[command(flatten)]
    node: NodeArgs,
}

/// Parameters of the node.
#[derive(clap::Args, Debug)]
struct NodeArgs {
    #[command(flatten)]
    grid: commands::GridArgs,
    /// Append the step's contact impulses to the bodies grid (`prev_normal`, `prev_tangent`: the
    /// 7-channel temporal U-Net input).
    #[arg(long)]
    temporal: bool,
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(args) = runtime::parse_args_checked::<Args, _>(|a| match &a.command {
        None => a.node.grid.validate(),
        Some(_) => Ok(()),
    }) else {
        return Ok(());
    };
    runtime::init_logging();
    match args.command {
        Some(command) => commands::run(command),
        None => run_node(args.node),
    }
}

type BodiesFrame = Frame<StepHeader, Body>;
type ContactsFrame = Frame<StepHeader, Contact>;

/// How long the node keeps draining after `RunEnd` when nothing arrives (the last frames may travel
/// behind the control message on other topics).
const DRAIN_AFTER_RUN_END: Duration = Duration::from_millis(300);

fn run_node(args: NodeArgs) -> Result<()> {
    let config = args.grid.transfer_config();
    let node = runtime::Node::from_env("dc-sph")?;
    let mut bodies_sub = node.subscriber(topics::BODIES)?;
    let mut contacts_sub = node.subscriber(topics::CONTACTS)?;
    let mut control = node.subscriber(topics::CONTROL)?;
    let mut grid_bodies = node.publisher(topics::GRID_BODIES)?;
    let mut grid_contacts = node.publisher(topics::GRID_CONTACTS)?;
    if !node.ready()? {
        return Ok(());
    }
    tracing::info!(?config, bounds = ?args.grid.bounds, pad_to = args.grid.pad_to, temporal = args.temporal, "dc-sph ready");

    let mut pairer: StepPairer<BodiesFrame, ContactsFrame> = StepPairer::new();
    let mut transfer: Option<Transfer> = None;
    let mut simulation: Option<(u64, u32)> = None;
    let (mut steps, mut outside_total, mut failed) = (0u64, 0u64, 0u64);
    // The node ends once every run it saw start has ended (and the last frames are drained):
    // several simulators may share it (`dc eval --jobs N`), each with several runs, so one run's
    // end is not the end of the work.
    let mut run_ended: Option<Instant> = None;
    let mut open_runs = std::collections::BTreeSet::new();
    loop {
        // Asked to stop (the launcher stops a graph's producers before their readers): one last
        // pass turns what has already arrived into grids, so a recording keeps its last steps.
        let stopping = node.is_shutdown();
        while let Some(c) = control.try_recv()? {
            node.observe_control(c.header());
            match c.header().kind() {
                Some(ControlKind::RunStart) => {
                    open_runs.insert(c.header().step.run_id);
                    run_ended = None;
                }
                Some(ControlKind::RunEnd) => {
                    open_runs.remove(&c.header().step.run_id);
                    if open_runs.is_empty() {
                        run_ended = Some(Instant::now());
                    }
                }
                _ => {}
            }
        }
        // Wait on the stream that is behind, so a step goes out as soon as its second half lands.
        let waited = if stopping {
            Ok(None)
        } else if pairer.pending_a() > 0 {
            contacts_sub
                .recv_timeout(Duration::from_millis(50))
                .map(|r| r.map(|r| pairer.push_b(*r.header(), r.into_frame())))
        } else {
            bodies_sub
                .recv_timeout(Duration::from_millis(50))
                .map(|r| r.map(|r| pairer.push_a(*r.header(), r.into_frame())))
        };
        let (waited, interrupted) = match waited {
            // Ctrl-C / SIGTERM interrupts the wait: that is a shutdown, not a failure.
            Err(_) if node.is_shutdown() => (None, true),
            other => (other?, false),
        };
        let mut got = waited.is_some();
        while let Some(r) = bodies_sub.try_recv()? {
            pairer.push_a(*r.header(), r.into_frame());
            got = true;
        }
        while let Some(r) = contacts_sub.try_recv()? {
            pairer.push_b(*r.header(), r.into_frame());
            got = true;
        }
        while let Some((step, bodies, contacts)) = pairer.pop() {
            // The geometry is fixed per simulation (from its walls, or the given bounds).
            if simulation != Some((step.run_id, step.simulation)) || transfer.is_none() {
                simulation = Some((step.run_id, step.simulation));
                let geometry = args.grid.geometry_for(&bodies.items)?;
                if transfer.as_ref().map(|t| *t.geometry()) != Some(geometry) {
                    tracing::info!(?geometry, simulation = step.simulation, "grid geometry");
                    transfer = Some(Transfer::new(config, geometry)?);
                }
            }
            let t = transfer.as_mut().expect("set above");
            let temporal = args.temporal.then_some(contacts.items.as_slice());
            let grids = t
                .bodies_grid(step, &bodies.items, temporal)
                .and_then(|b| Ok((b, t.contacts_grid(step, &contacts.items)?)));
            match grids {
                Ok(((bg, br), (cg, cr))) => {
                    grid_bodies.publish_frame(&bg)?;
                    grid_contacts.publish_frame(&cg)?;
                    steps += 1;
                    let outside = (br.outside + cr.outside) as u64;
                    if outside > 0 && outside_total == 0 {
                        tracing::warn!(
                            step = step.step,
                            outside,
                            "particles outside the grid are skipped (counted from now on)"
                        );
                    }
                    outside_total += outside;
                }
                Err(e) => {
                    // One bad step must not take the graph down; the simulator's deadline falls
                    // back for it and counts the fallback.
                    failed += 1;
                    tracing::error!(simulation = step.simulation, step = step.step, "no grids for this step: {e}");
                }
            }
        }
        if stopping || interrupted {
            break;
        }
        if let Some(at) = run_ended {
            if got {
                run_ended = Some(Instant::now());
            } else if at.elapsed() > DRAIN_AFTER_RUN_END {
                break;
            }
        }
    }
    tracing::info!(steps, outside_total, failed, unpaired = pairer.dropped() + pairer.pending() as u64, "dc-sph done");
    Ok(())
}

impl commands::GridArgs {
    /// The grid for a simulation whose first bodies frame is `bodies`.
    fn geometry_for(&self, bodies: &[Body]) -> Result<GridGeometry> {
        let bounds = match self.bounds {
            commands::BoundsArg::Fixed(b) => b,
            commands::BoundsArg::Auto => Bounds::from_walls(bodies).unwrap_or_else(|| {
                tracing::warn!("no walls in the scene; using the thesis box 0,0,15,15");
                Bounds::THESIS_BOX
            }),
        };
        Ok(GridGeometry::from_bounds(bounds, self.res, self.pad_to)?)
    }
}
