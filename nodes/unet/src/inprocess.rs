//! The closed loop with every stage in one process and no bus: simulator, SPH transfer, U-Net,
//! per-step statistics and an MCAP recording, called in turn. The floor the bus graphs are
//! measured against (`dc bench loop`); in lockstep it solves exactly what the graph solves.

use crate::{Predictor, Result, UnetError};
use msgs::{Grid, StepHeader};
use sim::{ModelKind, SceneConfig, WarmStarter, World, WorldParams};
use std::cell::RefCell;
use std::path::Path;
use std::rc::Rc;
use std::time::Instant;

/// What a loop run did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LoopRun {
    pub steps: u64,
    /// Wall time of the step loops (all stages), seconds.
    pub loop_secs: f64,
    pub total_sweeps: u64,
    pub fallbacks: u64,
}

/// Runs `seeds` of `scene` for `steps` steps each with the `unet` warm start of `predictor`,
/// recording bodies, contacts and statistics to `record` (CBOR, as `dc-record` writes them).
pub fn run_loop(
    predictor: &Predictor,
    scene: &SceneConfig,
    params: WorldParams,
    seeds: &[u64],
    steps: u32,
    record: &Path,
) -> Result<LoopRun> {
    let err = |what: String| UnetError::Config(what);
    let spec = predictor.meta().grid.clone();
    let config = spec.transfer_config()?;
    // The grid made of step k - 1, which the warm start of step k samples.
    let next: Rc<RefCell<Option<Grid>>> = Rc::default();
    let source = {
        let next = next.clone();
        move |_run: u64, simulation: u32, step: u32| {
            next.borrow_mut().take().filter(|g: &Grid| (g.header.step.simulation, g.header.step.step) == (simulation, step))
        }
    };
    let model = ModelKind::Unet.build_with_source(0, Some(Box::new(source))).map_err(|e| err(e.to_string()))?;
    let mut warm = WarmStarter::new(model, ModelKind::Builtin.build(0).map_err(|e| err(e.to_string()))?);
    let mut writer = recorder::write::RecordingWriter::create(record).map_err(|e| err(e.to_string()))?;
    for (topic, kind) in [
        (msgs::topics::BODIES.name, recorder::FrameKind::Bodies),
        (msgs::topics::CONTACTS.name, recorder::FrameKind::Contacts),
        (msgs::topics::SOLVE_STATS.name, recorder::FrameKind::SolveStats),
    ] {
        writer.add_channel(topic, kind).map_err(|e| err(e.to_string()))?;
    }
    let mut out = LoopRun { steps: 0, loop_secs: 0.0, total_sweeps: 0, fallbacks: 0 };
    let (mut bodies, mut contacts) = (Vec::new(), Vec::new());
    let run_id = 1;
    for &seed in seeds {
        let simulation = seed as u32;
        let mut world = World::new(&SceneConfig { seed, ..scene.clone() }, params).map_err(|e| err(e.to_string()))?;
        world.set_ids(run_id, simulation);
        warm.begin_simulation(simulation, seed);
        world.body_msgs(&mut bodies);
        let mut transfer = sph::Transfer::new(config, spec.geometry(&bodies)?).map_err(|e| err(e.to_string()))?;
        let started = Instant::now();
        for step in 0..steps {
            let stats = world.step(&mut warm).clone();
            let header = StepHeader { run_id, simulation, step };
            out.total_sweeps += stats.solve.sweeps as u64;
            out.fallbacks += stats.fallback as u64;
            world.body_msgs(&mut bodies);
            world.contact_msgs(&mut contacts);
            let residuals: Vec<f32> = world.residuals().iter().take(msgs::MAX_RESIDUALS).copied().collect();
            let used = if stats.fallback { warm.fallback.name().to_string() } else { warm.model.name().to_string() };
            let stats_msg = msgs::Frame::new(stats.to_msg(header, warm.model.name(), &used), residuals);
            // SPH + U-Net: the warm start of the next step.
            let (input, _) = transfer
                .bodies_grid(header, &bodies, spec.temporal.then_some(contacts.as_slice()))
                .map_err(|e| err(e.to_string()))?;
            *next.borrow_mut() = predictor.predict_batch(&[&input])?.pop();
            // Recorder.
            let t = started.elapsed().as_nanos() as u64;
            let encode = |r: std::result::Result<Vec<u8>, msgs::CodecError>| r.map_err(|e| err(e.to_string()));
            for (topic, kind, bytes) in [
                (msgs::topics::BODIES.name, recorder::FrameKind::Bodies, encode(msgs::encode(&msgs::Frame::new(header, bodies.clone())))?),
                (msgs::topics::CONTACTS.name, recorder::FrameKind::Contacts, encode(msgs::encode(&msgs::Frame::new(header, contacts.clone())))?),
                (msgs::topics::SOLVE_STATS.name, recorder::FrameKind::SolveStats, encode(msgs::encode(&stats_msg))?),
            ] {
                writer.write(topic, kind, t, t, &bytes).map_err(|e| err(e.to_string()))?;
            }
            out.steps += 1;
        }
        out.loop_secs += started.elapsed().as_secs_f64();
    }
    writer.finish().map_err(|e| err(e.to_string()))?;
    Ok(out)
}
