//! `dc-loop-bench`: the closed loop with every stage in one process and no bus: the simulator's
//! own step loop (`sim::run`), the SPH transfer, the U-Net and an MCAP recording of bodies,
//! contacts and statistics, called in turn. The floor the bus graphs are measured against
//! (`dc bench loop`); in lockstep it solves exactly what the graph solves. Prints the run's
//! summary line (`msgs::RunSummary`), as `dc-sim` does.

use anyhow::{Context, Result};
use msgs::{ControlMsg, FrameKind, Grid};
use sim::run::{RunSink, RunSpec, StepOutput};
use sim::{ModelKind, SceneConfig, SimError, WarmStarter, WorldParams};
use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;
use std::time::Instant;

#[derive(clap::Parser, Debug)]
#[command(name = "dc-loop-bench", about = "The closed loop (sim, SPH, U-Net, statistics, recording) in one process")]
struct Args {
    /// U-Net model file.
    #[arg(long, default_value_os_t = runtime::shipped("models/unet-demo.dcu"))]
    model: PathBuf,
    #[arg(long, default_value = "0..2")]
    seeds: String,
    #[arg(long, default_value_t = 100)]
    steps: u32,
    /// Dynamic bodies (ball-box scene).
    #[arg(long, default_value_t = 40)]
    n: usize,
    /// Where the recording goes.
    #[arg(long)]
    record: PathBuf,
    /// burn device of the U-Net (flex; libtorch with the `tch` feature).
    #[arg(long, default_value = "flex", value_parser = unet::device_name)]
    device: String,
}

/// Each step: record it, then make the next step's warm start (SPH transfer + U-Net).
struct InProcess<'a> {
    predictor: &'a unet::Predictor,
    spec: unet::GridSpec,
    transfer: Option<(u32, sph::Transfer)>,
    next: Rc<RefCell<Option<Grid>>>,
    writer: recorder::RecordingWriter,
    started: Instant,
    encoded: Vec<u8>,
}

impl InProcess<'_> {
    fn write<H: msgs::FrameHeader, T: msgs::FrameItem>(
        &mut self,
        topic: &str,
        kind: FrameKind,
        header: &H,
        items: &[T],
    ) -> Result<(), SimError> {
        let out = |e: String| SimError::Output(format!("{topic}: {e}"));
        msgs::encode_into(header, items, &mut self.encoded).map_err(|e| out(e.to_string()))?;
        let t = self.started.elapsed().as_nanos() as u64;
        self.writer.write(topic, kind, t, t, &self.encoded).map_err(|e| out(e.to_string()))
    }

    fn predict(&mut self, out: &StepOutput<'_>) -> Result<(), String> {
        let simulation = out.header.simulation;
        // A transfer per simulation: its geometry follows the scene's bodies.
        if self.transfer.as_ref().is_none_or(|(s, _)| *s != simulation) {
            let config = self.spec.transfer_config().map_err(|e| e.to_string())?;
            let geometry = self.spec.geometry(out.bodies).map_err(|e| e.to_string())?;
            self.transfer = Some((simulation, sph::Transfer::new(config, geometry).map_err(|e| e.to_string())?));
        }
        let (_, transfer) = self.transfer.as_mut().expect("set above");
        let contacts = self.spec.temporal.then_some(out.contacts);
        let (input, _) = transfer.bodies_grid(out.header, out.bodies, contacts).map_err(|e| e.to_string())?;
        *self.next.borrow_mut() = self.predictor.predict(&input).map_err(|e| e.to_string()).map(Some)?;
        Ok(())
    }
}

impl RunSink for InProcess<'_> {
    fn control(&mut self, _msg: &ControlMsg) -> Result<(), SimError> {
        Ok(())
    }
    fn step(&mut self, out: &StepOutput<'_>) -> Result<(), SimError> {
        self.predict(out).map_err(|e| SimError::Output(format!("U-Net warm start: {e}")))?;
        self.write(msgs::topics::BODIES.name, FrameKind::Bodies, &out.header, out.bodies)?;
        self.write(msgs::topics::CONTACTS.name, FrameKind::Contacts, &out.header, out.contacts)?;
        self.write(msgs::topics::SOLVE_STATS.name, FrameKind::SolveStats, &out.stats.to_header(), out.residuals)
    }
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(args) = runtime::parse_args::<Args>() else { return Ok(()) };
    runtime::init_logging();
    let device = unet::device(&args.device)?;
    let predictor = unet::Predictor::load(&args.model, &device)?;
    let seeds = msgs::parse_seeds(&args.seeds).map_err(|e| anyhow::anyhow!("--seeds {e}"))?;
    // The grid made of step k - 1, which the warm start of step k samples.
    let next: Rc<RefCell<Option<Grid>>> = Rc::default();
    let source = {
        let next = next.clone();
        move |_run: u64, simulation: u32, step: u32| {
            next.borrow_mut()
                .take()
                .filter(|g: &Grid| (g.header.step.simulation, g.header.step.step) == (simulation, step))
        }
    };
    let model = ModelKind::Unet.build_with_source(0, Some(Box::new(source)))?;
    let mut warm = WarmStarter::new(model, ModelKind::Builtin.build(0)?);
    let mut writer = recorder::RecordingWriter::create(&args.record)
        .with_context(|| format!("creating {}", args.record.display()))?;
    for topic in [msgs::topics::BODIES.name, msgs::topics::CONTACTS.name, msgs::topics::SOLVE_STATS.name] {
        writer.add_channel(topic, FrameKind::of_topic(topic).expect("a table topic"))?;
    }
    let mut sink = InProcess {
        predictor: &predictor,
        spec: predictor.meta().grid.clone(),
        transfer: None,
        next,
        writer,
        started: Instant::now(),
        encoded: Vec::new(),
    };
    let spec = RunSpec {
        scene: SceneConfig { n: args.n, ..SceneConfig::default() },
        // What dc-sim solves with by default, so that both solve the same steps.
        params: WorldParams::recommended(),
        seeds,
        steps: args.steps,
        run_id: 1,
        problems: false,
        label: None,
        shadow_builtin: false,
        error_split: false,
    };
    let summary = sim::run::run(&spec, &mut warm, &mut sink)?;
    sink.writer.finish()?;
    println!("{}", summary.line());
    Ok(())
}
