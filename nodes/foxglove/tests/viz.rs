//! `dc-foxglove viz` on recordings: a real one (simulator + SPH recorded by `dc-record`, which needs
//! `dc`, `dc-sim`, `dc-sph` and `dc-record` built beside the bridge: `cargo build --workspace
//! --bins`) and small ones written here with the recorder's writer. The viz files are read back with
//! an independent MCAP reader and the protobuf structs of `client/`.

mod client;

use client::{Grid, RawImage, SceneUpdate};
use deep_contact::{launch, scratch_dir, text};
use msgs::{Body, Contact, ControlDetails, ControlKind, ControlMsg, FrameKind, RunParams, StepHeader};
use prost::Message as _;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::{Command, Output};

const DC_FOXGLOVE: &str = env!("CARGO_BIN_EXE_dc-foxglove");

/// The messages of a viz file per Foxglove topic: (log time, payload), in file order.
type Viz = BTreeMap<String, Vec<(u64, Vec<u8>)>>;

fn read_viz(path: &Path) -> Viz {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut out = Viz::new();
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a readable message");
        out.entry(m.channel.topic.clone()).or_default().push((m.log_time, m.data.into_owned()));
    }
    out
}

fn viz(input: &Path, output: &Path) -> Output {
    let out = Command::new(DC_FOXGLOVE).arg("viz").arg(input).arg(output).output().expect("run dc-foxglove");
    assert!(out.status.success(), "{}", text(&out));
    out
}

/// The log times of a topic, sorted.
fn times(viz: &Viz, topic: &str) -> Vec<u64> {
    let mut t: Vec<u64> = viz.get(topic).map(|v| v.iter().map(|(t, _)| *t).collect()).unwrap_or_default();
    t.sort_unstable();
    t
}

/// The value of an entity's metadata key.
fn meta<'a>(e: &'a client::SceneEntity, key: &str) -> &'a str {
    e.metadata.iter().find(|kv| kv.key == key).map(|kv| kv.value.as_str()).unwrap_or_else(|| panic!("no `{key}`"))
}

/// Per scene (by log time): its step's (simulation, step) and arrow count; checks that every
/// entity carries the log time as its timestamp.
fn scenes(viz: &Viz) -> BTreeMap<u64, ((u32, u32), usize)> {
    let mut out = BTreeMap::new();
    for (t, data) in &viz["/scene"] {
        let update = SceneUpdate::decode(data.as_slice()).expect("a SceneUpdate");
        let contacts = update.entities.iter().find(|e| e.id == "contacts").expect("a contacts entity");
        for e in &update.entities {
            assert_eq!(e.timestamp.expect("a timestamp").ns(), *t, "entity `{}`: stamp = log time", e.id);
        }
        let step = (meta(contacts, "simulation").parse().unwrap(), meta(contacts, "step").parse().unwrap());
        assert!(out.insert(*t, (step, contacts.arrows.len())).is_none(), "two scenes at {t} ns");
    }
    out
}

/// (simulation, step) of the steps of a topic.
type Steps = BTreeSet<(u32, u32)>;

/// What the viz of a recording should hold, read from the recording itself.
#[derive(Debug, Default)]
struct Recorded {
    params: Option<RunParams>,
    /// Arrows per (simulation, step): contacts pushing (normal impulse > 0).
    arrows: BTreeMap<(u32, u32), usize>,
    bodies: Steps,
    /// The steps of each grid topic, and its channel names.
    grids: BTreeMap<String, (Steps, Vec<String>)>,
    stats: usize,
    control: usize,
    /// Log times of the bodies frames, per (simulation, step).
    bodies_log_time: BTreeMap<(u32, u32), u64>,
}

fn recorded(path: &Path) -> Recorded {
    let mut r = Recorded::default();
    let mut reader = recorder::RecordingReader::open(path).unwrap();
    while let Some(m) = reader.next_message() {
        let m = m.unwrap();
        let at = |h: &StepHeader| (h.simulation, h.step);
        match m.channel.kind {
            Some(FrameKind::Bodies) => {
                let f = msgs::decode::<StepHeader, Body>(&m.data).unwrap();
                assert!(r.bodies.insert(at(&f.header)), "one bodies frame per step");
                r.bodies_log_time.insert(at(&f.header), m.log_time);
            }
            Some(FrameKind::Contacts) => {
                let f = msgs::decode::<StepHeader, Contact>(&m.data).unwrap();
                r.arrows.insert(at(&f.header), f.items.iter().filter(|c| c.normal_impulse > 0.0).count());
            }
            Some(FrameKind::Grid) => {
                let f = msgs::decode::<msgs::GridHeader, f32>(&m.data).unwrap();
                let names = (0..f.header.channels as usize).map(|c| f.header.channel_name(c).to_string()).collect();
                let entry = r.grids.entry(m.channel.topic.clone()).or_insert((Steps::new(), names));
                assert!(entry.0.insert(at(&f.header.step)), "one frame per step of {}", m.channel.topic);
            }
            Some(FrameKind::SolveStats) => r.stats += 1,
            Some(FrameKind::Control) => {
                r.control += 1;
                let f = msgs::decode::<msgs::Control, u8>(&m.data).unwrap();
                if let Ok(ControlDetails::RunStart(p)) = f.details() {
                    r.params = Some(p);
                }
            }
            _ => {}
        }
    }
    r
}

/// dt in whole nanoseconds, as the timeline defines it.
fn dt_ns(dt: f32) -> u64 {
    (f64::from(dt) * 1e9).round() as u64
}

#[test]
fn viz_writes_every_recorded_step_at_simulation_time() {
    let dir = scratch_dir("viz-real");
    let recording = dir.join("run.mcap");
    let (seeds, steps) = (2u32, 60u32);
    let (_, out) = launch(
        "viz-real",
        &format!(
            r#"
[graph]
name = "viz-real"

[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}" }}

[[nodes]]
name = "sph"
binary = "dc-sph"
daemon = true
params = {{ bounds = "0,0,12,9", res = 0.5 }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ seeds = "0..{seeds}", steps = {steps}, n = 30, model = "builtin" }}
"#,
            recording.display()
        ),
        &[],
    );
    assert!(out.status.success(), "{}", text(&out));
    let rec = recorded(&recording);
    let total = (seeds * steps) as usize;
    assert_eq!(rec.bodies.len(), total, "the recording holds every step");
    // The SPH node is a daemon, stopped when the simulator ends: the grids of the last steps may
    // not reach the recording. The viz must hold exactly the grids that were recorded.
    let grid_counts: BTreeMap<&str, usize> = rec.grids.iter().map(|(k, (s, _))| (k.as_str(), s.len())).collect();
    assert!(grid_counts.len() >= 2 && grid_counts.values().all(|n| *n > 0), "{grid_counts:?}\n{}", text(&out));
    for (topic, (grid_steps, _)) in &rec.grids {
        let missing: Vec<_> = rec.bodies.difference(grid_steps).collect();
        if !missing.is_empty() {
            eprintln!("the recording has no {topic} frame of (simulation, step) {missing:?}");
        }
    }
    let params = rec.params.clone().expect("the recording has its run start");
    let dt = dt_ns(params.dt);
    assert!(dt > 0);

    let file = dir.join("viz.mcap");
    let out = viz(&recording, &file);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains(" 0 at their recorded log time"), "{}", text(&out));
    let v = read_viz(&file);

    // Every step's scene, at (simulation index x steps + step) x dt: consecutive scenes dt apart,
    // across the simulation boundary too.
    let scenes = scenes(&v);
    assert_eq!(scenes.len(), total, "one scene per recorded step");
    let expected: Vec<u64> = (0..total as u64).map(|i| i * dt).collect();
    assert_eq!(scenes.keys().copied().collect::<Vec<_>>(), expected);
    let time_of = |step: &(u32, u32)| {
        let index = params.seeds.iter().position(|&s| s == u64::from(step.0)).expect("a seed") as u64;
        (index * u64::from(steps) + u64::from(step.1)) * dt
    };
    for (t, (step, arrows)) in &scenes {
        assert_eq!(*t, time_of(step), "step {step:?}");
        assert_eq!(*arrows, rec.arrows[step], "step {step:?}: the scene carries its own step's contacts");
    }
    assert!(scenes.values().any(|(_, a)| *a > 0), "some steps push");

    // Every recorded grid's set: the grid and one heat map per channel, at its step's time.
    for (topic, (grid_steps, channels)) in &rec.grids {
        let mut expected: Vec<u64> = grid_steps.iter().map(time_of).collect();
        expected.sort_unstable();
        let grid = format!("/{topic}");
        assert_eq!(times(&v, &grid), expected, "{grid}");
        for (t, data) in &v[&grid] {
            assert_eq!(Grid::decode(data.as_slice()).unwrap().timestamp.unwrap().ns(), *t, "{grid}");
        }
        for c in channels {
            let heat = format!("/{topic}/heat/{c}");
            assert_eq!(times(&v, &heat), expected, "{heat}");
            let (t, data) = &v[&heat][0];
            assert_eq!(RawImage::decode(data.as_slice()).unwrap().timestamp.unwrap().ns(), *t, "{heat}");
        }
    }

    // Every statistics frame, its step at its time; the control messages; the transform.
    assert_eq!(rec.stats, total);
    assert_eq!(times(&v, "/stats/solve"), expected);
    for (t, data) in &v["/stats/solve"] {
        let s: serde_json::Value = serde_json::from_slice(data).unwrap();
        let step = (s["simulation"].as_u64().unwrap() as u32, s["step"].as_u64().unwrap() as u32);
        assert_eq!(scenes[t].0, step, "stats at {t} ns");
    }
    assert_eq!(v["/control"].len(), rec.control, "2 + 2 per simulation");
    let control = times(&v, "/control");
    assert_eq!((control[0], *control.last().unwrap()), (0, total as u64 * dt), "run start at 0, run end at its end");
    assert!(!v["/tf"].is_empty());
    let messages: usize = v.values().map(Vec::len).sum();
    eprintln!(
        "{} recorded steps -> {messages} viz messages on {} topics (dt {dt} ns): {:?}",
        total,
        v.len(),
        v.iter().map(|(k, m)| (k.as_str(), m.len())).collect::<Vec<_>>()
    );
}

/// A ball resting on a wall, and the contact between them pushing with `impulse`.
fn frames(h: StepHeader, impulse: f32) -> (msgs::Frame<StepHeader, Body>, msgs::Frame<StepHeader, Contact>) {
    let wall = Body { id: 0, shape: msgs::Shape::Wall as u32, size: [5.0, 0.5], x: 5.0, y: -0.5, ..Default::default() };
    let ball = Body { id: 1, shape: msgs::Shape::Ball as u32, size: [0.5, 0.5], x: 5.0, y: 0.5, ..Default::default() };
    let contact = Contact { x: 5.0, y: 0.0, nx: 0.0, ny: 1.0, normal_impulse: impulse, ..Default::default() };
    (msgs::Frame::new(h, vec![wall, ball]), msgs::Frame::new(h, vec![contact]))
}

fn run_params(dt: f32, seeds: Vec<u64>, steps: u32) -> RunParams {
    RunParams { seeds, steps, dt, model: "builtin".into(), ..Default::default() }
}

#[test]
fn viz_stamps_steps_in_whole_nanoseconds_whatever_the_recorded_order() {
    // dt = 1/60 s, as the f32 the run start carries: 16,666,667.54 ns, rounded once to
    // 16,666,668; step k at k x 16,666,668 ns.
    let dir = scratch_dir("viz-order");
    let recording = dir.join("run.mcap");
    let run = StepHeader { run_id: 1796139974837132098, simulation: 0, step: 0 };
    let steps = 12u32;
    let mut w = recorder::RecordingWriter::create(&recording).unwrap();
    let put = |w: &mut recorder::RecordingWriter, topic: &str, kind: FrameKind, t: u64, data: Vec<u8>| {
        w.write(topic, kind, t, t, &data).unwrap();
    };
    let at = |step: u32| StepHeader { simulation: 7, step, ..run };
    // As the recorder interleaves topics: a batch of bodies, then the contacts, the run start late.
    for batch in [0..5, 5..steps] {
        for step in batch.clone() {
            let (b, _) = frames(at(step), 0.1 * (step + 1) as f32);
            put(&mut w, "bodies", FrameKind::Bodies, 1000 + u64::from(step), msgs::encode(&b).unwrap());
        }
        if batch.start == 0 {
            let start = ControlMsg::run_start(run, &run_params(1.0 / 60.0, vec![7], steps));
            put(&mut w, "control", FrameKind::Control, 2000, msgs::encode(&start).unwrap());
        }
        // Step 3 has no contacts frame (its scene goes out with the bodies alone, at the end);
        // step 4's contact pushes nothing. Neither scene has an arrow.
        for step in batch.filter(|&s| s != 3) {
            let (_, c) = frames(at(step), if step == 4 { 0.0 } else { 0.1 });
            put(&mut w, "contacts", FrameKind::Contacts, 3000 + u64::from(step), msgs::encode(&c).unwrap());
        }
    }
    w.finish().unwrap();

    let file = dir.join("viz.mcap");
    let out = viz(&recording, &file);
    assert!(String::from_utf8_lossy(&out.stdout).contains("1 step(s) without contacts"), "{}", text(&out));
    let v = read_viz(&file);
    let scenes = scenes(&v);
    let expected: BTreeMap<u64, ((u32, u32), usize)> =
        (0..steps).map(|s| (u64::from(s) * 16_666_668, ((7, s), usize::from(s != 3 && s != 4)))).collect();
    assert_eq!(scenes, expected);
    assert_eq!(times(&v, "/control"), [0]);
}

#[test]
fn viz_without_run_parameters_keeps_the_recorded_log_times_and_says_so_once() {
    let dir = scratch_dir("viz-legacy");
    let recording = dir.join("old.mcap");
    let mut w = recorder::RecordingWriter::create(&recording).unwrap();
    // A run start from before run starts carried dt (legacy JSON details without it).
    let run = StepHeader { run_id: 5, simulation: 0, step: 0 };
    let legacy = r#"{"scene":"ball-box","n":1,"seeds":[0],"steps":4,"model":"builtin","fallback":"builtin","tolerance":0.0001,"max_sweeps":100,"sampler":"native"}"#;
    let start = msgs::Frame::new(
        msgs::Control { step: run, kind: ControlKind::RunStart as u32, count: 1 },
        legacy.as_bytes().to_vec(),
    );
    w.write("control", FrameKind::Control, 500, 500, &msgs::encode(&start).unwrap()).unwrap();
    let log_time = |step: u32| 1_000_000 + u64::from(step) * 7_000_003;
    for step in 0..4 {
        let (b, c) = frames(StepHeader { step, ..run }, 0.2);
        w.write("bodies", FrameKind::Bodies, log_time(step), log_time(step), &msgs::encode(&b).unwrap()).unwrap();
        let t = log_time(step) + 10;
        w.write("contacts", FrameKind::Contacts, t, t, &msgs::encode(&c).unwrap()).unwrap();
    }
    w.finish().unwrap();
    let rec = recorded(&recording);
    assert!(rec.params.is_none(), "the legacy run start has no dt");

    let file = dir.join("viz.mcap");
    let out = viz(&recording, &file);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let warnings = stderr.matches("recorded log time, not simulation time").count();
    assert_eq!(warnings, 1, "said once: {}", text(&out));
    let v = read_viz(&file);
    let scenes = scenes(&v);
    // A scene goes out at its bodies' time.
    let expected: Vec<u64> = rec.bodies_log_time.values().copied().collect();
    assert_eq!(scenes.keys().copied().collect::<Vec<_>>(), expected);
    assert!(scenes.values().all(|(_, arrows)| *arrows == 1));
    assert_eq!(times(&v, "/control"), [500]);
}
