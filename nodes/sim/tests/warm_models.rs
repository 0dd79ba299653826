//! Warm-start models: grid sampling through a grid source, fallbacks, temporal models.

use msgs::{Grid, StepHeader};
use sim::warm::{GridModel, GridSource, ModelKind, ModelSpec, WarmStarter};
use sim::{SceneConfig, World, WorldParams};
use std::cell::Cell;
use std::rc::Rc;

fn constant_grid(step: StepHeader, normal: f32, tangent: f32) -> Grid {
    let mut g = Grid::zeros(step, [0.0, 0.0], 0.5, 31, 31, &["normal", "tangent"]);
    g.channel_data_mut(0).fill(normal);
    g.channel_data_mut(1).fill(tangent);
    g
}

#[test]
fn grid_model_samples_the_previous_steps_grid_at_the_contacts() {
    let asked = Rc::new(Cell::new(Vec::<u32>::new()));
    let log = asked.clone();
    let source = move |run: u64, sim: u32, step: u32| {
        let mut v = log.take();
        v.push(step);
        log.set(v);
        Some(constant_grid(StepHeader { run_id: run, simulation: sim, step }, 0.25, -0.1))
    };
    let model = ModelKind::Grid.build_with_source(0, Some(Box::new(source) as Box<dyn GridSource>)).unwrap();
    let mut warm = WarmStarter::new(model, ModelKind::Builtin.build(0).unwrap());
    let mut world = World::new(&SceneConfig::default(), WorldParams::default()).unwrap();
    let mut saw_contacts = false;
    for _ in 0..120 {
        let s = world.step(&mut warm).clone();
        assert!(!s.fallback);
        if s.contacts > 0 {
            saw_contacts = true;
            assert!(world.warm_start_used().iter().all(|l| l.normal == 0.25 && (l.tangent + 0.1).abs() < 1e-7));
        }
    }
    assert!(saw_contacts);
    // Step k asks for the grid of step k - 1 (none at step 0), every step, contacts or not.
    assert_eq!(asked.take(), (0..119).collect::<Vec<u32>>());
}

#[test]
fn late_grid_falls_back_to_the_named_model_and_is_counted() {
    // Grids arrive only for even steps.
    let source = |run: u64, sim: u32, step: u32| {
        step.is_multiple_of(2).then(|| constant_grid(StepHeader { run_id: run, simulation: sim, step }, 1.0, 0.0))
    };
    let model = GridModel::new("grid", Box::new(source));
    let mut warm = WarmStarter::new(Box::new(model), ModelKind::None.build(0).unwrap());
    warm.begin_simulation(0, 0);
    let mut world = World::new(&SceneConfig::default(), WorldParams::default()).unwrap();
    let mut fallbacks = 0;
    for k in 0..100u32 {
        let s = world.step(&mut warm).clone();
        // Step k needs the grid of k - 1: missing when k - 1 is odd.
        let expect = k > 0 && (k - 1) % 2 == 1;
        assert_eq!(s.fallback, expect, "step {k}");
        fallbacks += expect as u32;
        assert_eq!(s.fallbacks_total, fallbacks);
        // The statistics name the model asked for and the one that stood in.
        assert_eq!((s.model.as_str(), s.used_model.as_str()), ("grid", if expect { "none" } else { "grid" }));
        assert_eq!(s.to_header().fallback, expect as u32);
    }
    assert_eq!(warm.fallbacks_total(), 50 - 1);
}

#[test]
fn builtin_reuses_persisting_impulses_and_counts_them() {
    let mut world = World::new(&SceneConfig { seed: 6, ..Default::default() }, WorldParams::default()).unwrap();
    let mut warm = ModelKind::Builtin.starter(0).unwrap();
    let mut previous: Vec<(sim::ContactKey, sim::Impulse)> = Vec::new();
    let mut persisting_seen = 0;
    for _ in 0..200 {
        let s = world.step(&mut warm).clone();
        let mut persisting = 0;
        for (c, w) in world.contacts().iter().zip(world.warm_start_used()) {
            match previous.iter().find(|(k, _)| *k == c.key) {
                Some((_, l)) => {
                    persisting += 1;
                    assert_eq!(w, l);
                }
                None => assert_eq!(*w, sim::Impulse::default()),
            }
        }
        assert_eq!(s.persisting_contacts, persisting);
        persisting_seen += persisting;
        previous = world.contacts().iter().map(|c| c.key).zip(world.impulses().iter().copied()).collect();
    }
    // Once the pile forms, most contacts persist from step to step.
    assert!(persisting_seen > 5_000, "{persisting_seen}");
}

#[test]
fn grid_models_without_a_source_are_a_clear_error() {
    let e = ModelKind::Unet.build(0).err().unwrap();
    assert!(e.to_string().contains("needs a grid source"), "{e}");
}

/// Total sweeps of one ball-box simulation (seed 0, 150 steps) with `model`.
fn total_sweeps(model: ModelKind) -> u64 {
    let mut warm = WarmStarter::new(model.build(0).unwrap(), ModelKind::None.build(0).unwrap());
    warm.begin_simulation(0, 0);
    let mut world = World::new(&SceneConfig::default(), WorldParams::default()).unwrap();
    (0..150).map(|_| world.step(&mut warm).sweeps as u64).sum()
}

#[test]
fn the_exact_solution_survives_the_preserving_grid_but_not_the_thesis_transfer() {
    // The gate of grid warm starts: the solution itself, sent through the grid and back.
    let (copy, preserving, thesis, none) = (
        total_sweeps(ModelKind::Copy),
        total_sweeps(ModelKind::CopyGrid),
        total_sweeps(ModelKind::CopyGridSph),
        total_sweeps(ModelKind::None),
    );
    eprintln!("total sweeps: copy {copy}, copy-grid {preserving}, copy-grid-sph {thesis}, none {none}");
    // The transfer costs something (copy is exact), but keeps most of the solution's worth.
    assert!(copy <= preserving, "copy {copy} vs copy-grid {preserving}");
    assert!(preserving * 3 < none, "copy-grid {preserving} vs none {none}");
    // The thesis's transfer shrinks impulses to ~8%: barely better than starting from zero.
    assert!(thesis * 10 > none * 8, "copy-grid-sph {thesis} vs none {none}");
}

/// Per-step sweeps of one ball-box simulation (seed 0, 150 steps) with the model `spec` names.
fn sweeps_per_step(spec: &str) -> Vec<u32> {
    let spec: ModelSpec = spec.parse().unwrap();
    let mut warm = WarmStarter::new(spec.build(0).unwrap(), ModelKind::None.build(0).unwrap());
    warm.begin_simulation(0, 0);
    let mut world = World::new(&SceneConfig::default(), WorldParams::default()).unwrap();
    (0..150).map(|_| world.step(&mut warm).sweeps).collect()
}

#[test]
fn the_oracle_ablations_span_builtin_to_exact() {
    let total = |s: &str| sweeps_per_step(s).iter().map(|&s| s as u64).sum::<u64>();
    let builtin = sweeps_per_step("builtin");
    let copy = sweeps_per_step("copy");
    // The oracle solves from builtin to 2e-6, far below the run's 1e-4: a sweep or two confirm it
    // (re-applying the impulses rounds differently from the oracle's accumulated updates, which
    // a jammed pile amplifies for a few sweeps).
    assert!(copy.iter().all(|&s| s <= 5), "copy needs at most 5 sweeps a step: {copy:?}");
    assert!(copy.iter().sum::<u32>() <= 2 * copy.len() as u32, "{copy:?}");
    // blend:0 is builtin bit for bit (the world evolves identically), noise:0 is the oracle.
    assert_eq!(sweeps_per_step("blend:0"), builtin);
    assert_eq!(sweeps_per_step("noise:0"), copy);
    // Removing more of builtin's error costs fewer sweeps.
    let (b, half, most, exact) = (total("builtin"), total("blend:0.5"), total("blend:0.9"), total("copy"));
    eprintln!("total sweeps: builtin {b}, blend:0.5 {half}, blend:0.9 {most}, copy {exact}");
    assert!(exact < most && most < half && half < b, "{exact} < {most} < {half} < {b}");
    // The gain is in the persisting contacts: exact there does most of what exact everywhere does.
    let (persisting, new) = (total("copy-persisting"), total("copy-new"));
    eprintln!("copy-persisting {persisting}, copy-new {new}");
    assert!(persisting < new, "copy-persisting {persisting} vs copy-new {new}");
    assert!(new <= b * 11 / 10, "exact on new contacts alone is about builtin: {new} vs {b}");
}

#[test]
fn baselines_fill_reappearing_contacts_and_damp_extrapolation() {
    // extrapolate:0 is builtin (l1 + 0 (l1 - l2), clamped into the cone it already is in).
    assert_eq!(sweeps_per_step("extrapolate:0"), sweeps_per_step("builtin"));
    // continue:0 is builtin too (no step along the last sweep's change).
    assert_eq!(sweeps_per_step("continue:0"), sweeps_per_step("builtin"));
    let spec: ModelSpec = "extrapolate:0.5".parse().unwrap();
    assert_eq!(spec.build(0).unwrap().name(), "extrapolate:0.5");
}

#[test]
fn an_untrained_contact_graph_network_is_builtin_exactly() {
    let dir = std::env::temp_dir().join(format!("dc-sim-gnn-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("untrained.dcg");
    gnn::ModelFile::new(gnn::net::Net::new(gnn::net::NetConfig::default(), 4), "test").save(&path).unwrap();
    let spec: ModelSpec = "gnn".parse().unwrap();
    let err = spec.build(0).err().unwrap().to_string();
    assert!(err.contains("--gnn-model"), "{err}");
    let files = sim::ModelFiles { gnn: Some(path) };
    let run = |spec: &ModelSpec| -> Vec<u32> {
        let mut warm = WarmStarter::new(
            spec.build_with(0, sim::warm::Served::default(), &files).unwrap(),
            ModelKind::None.build(0).unwrap(),
        );
        warm.begin_simulation(0, 0);
        let mut world = World::new(&SceneConfig::default(), WorldParams::default()).unwrap();
        (0..150)
            .map(|_| {
                let s = world.step(&mut warm);
                assert!(!s.fallback, "step {}: {} fell back", s.step, s.model);
                s.sweeps
            })
            .collect()
    };
    // The decoder starts at zero: the correction is 0 and the warm start is builtin's, bit for bit.
    assert_eq!(run(&spec), sweeps_per_step("builtin"));
    // As a direction only (gnn-subspace:0), a zero correction is no direction: builtin again.
    let direction: ModelSpec = "gnn-subspace:0".parse().unwrap();
    assert!(direction.build(0).err().unwrap().to_string().contains("--gnn-model"));
    assert_eq!(run(&direction), sweeps_per_step("builtin"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Per step: the step's own sweeps, and builtin's on the same problem when measured.
type PairedSweeps = Vec<(u32, Option<u32>)>;

/// One ball-box simulation (seed 0, 150 steps) with `spec`, builtin measured alongside when
/// `shadow`: per step sweeps, and the final body positions.
/// `spec` (builtin its fallback) begun on seed 0's ball-box world with `params`.
fn seed_zero(spec: &str, params: WorldParams) -> (WarmStarter, World) {
    let spec: ModelSpec = spec.parse().unwrap();
    let mut warm = WarmStarter::new(spec.build(0).unwrap(), ModelKind::Builtin.build(0).unwrap());
    warm.begin_simulation(0, 0);
    (warm, World::new(&SceneConfig::default(), params).unwrap())
}

fn with_shadow(spec: &str, shadow: bool) -> (PairedSweeps, Vec<[f32; 2]>) {
    let (mut warm, mut world) = seed_zero(spec, WorldParams::default());
    world.shadow_builtin(shadow);
    let per_step = (0..150)
        .map(|_| {
            let s = world.step(&mut warm);
            assert_eq!(s.builtin_measured, shadow);
            (s.sweeps, s.builtin_measured.then_some(s.builtin_sweeps))
        })
        .collect();
    (per_step, world.bodies().iter().map(|b| [b.x.x, b.x.y]).collect())
}

#[test]
fn builtin_alongside_measures_the_same_problems_without_touching_the_run() {
    // Measuring builtin beside a model leaves the model's run bit for bit as it was.
    let (plain, plain_bodies) = with_shadow("none", false);
    let (shadowed, shadowed_bodies) = with_shadow("none", true);
    assert_eq!(plain.iter().map(|s| s.0).collect::<Vec<_>>(), shadowed.iter().map(|s| s.0).collect::<Vec<_>>());
    assert_eq!(plain_bodies, shadowed_bodies);
    // From zero, the jammed late steps cost more than builtin's warm start on the same problems.
    let late = |v: &[(u32, Option<u32>)]| {
        v[100..].iter().fold((0u64, 0u64), |(a, b), s| (a + s.0 as u64, b + s.1.unwrap() as u64))
    };
    let (own, builtin) = late(&shadowed);
    assert!(own > builtin && builtin > 0, "none {own} vs builtin on its states {builtin}");
    // On a builtin run, builtin on the same problems is the run itself.
    let (builtin_run, _) = with_shadow("builtin", true);
    assert!(builtin_run.iter().all(|&(own, shadow)| shadow == Some(own)), "{builtin_run:?}");
}

/// One ball-box simulation (seed 0, 150 steps) with `spec` at a budget of 8 PGS sweeps, the
/// warm-start error split when `split`: every step's statistics and the final body positions.
fn with_split(spec: &str, split: bool) -> (Vec<msgs::StepStats>, Vec<[f32; 2]>) {
    let mut params = WorldParams::default();
    params.solve = sim::solver::SolveParams { max_sweeps: 8, ..params.solve }.with_setting("pgs".parse().unwrap());
    let (mut warm, mut world) = seed_zero(spec, params);
    world.error_split(split);
    let steps = (0..150)
        .map(|_| {
            let s = world.step(&mut warm).clone();
            // The statistics carry the world's f64 sums as f32.
            let carried = world.last_split().map(|w| (w.n as u32, w.model_smooth as f32, w.builtin_left as f32));
            assert_eq!(carried, s.split().map(|_| (s.split_contacts, s.split_model_smooth, s.split_builtin_left)));
            s
        })
        .collect();
    (steps, world.bodies().iter().map(|b| [b.x.x, b.x.y]).collect())
}

#[test]
fn the_error_split_measures_every_step_with_contacts_without_touching_the_run() {
    let (plain, plain_bodies) = with_split("none", false);
    let (split, split_bodies) = with_split("none", true);
    assert_eq!(plain_bodies, split_bodies, "measuring changed the run");
    for (p, s) in plain.iter().zip(&split) {
        assert_eq!((p.sweeps, p.natural_rms.to_bits()), (s.sweeps, s.natural_rms.to_bits()));
        assert_eq!(p.split(), None);
        // Every step with contacts is split, over all its contacts, at the run's budget.
        assert_eq!(s.split_contacts, s.contacts);
        assert_eq!(s.split_budget, if s.contacts > 0 { 8 } else { 0 });
    }
    let none = msgs::ErrorSplit::over(&split).unwrap();
    assert_eq!(none.n, split.iter().map(|s| s.contacts as u64).sum::<u64>());
    // A zero start is further from the solution than builtin's, in both parts, and 8 sweeps
    // leave more of it; each start's error is larger than what 8 sweeps leave of it.
    let ((ms, mr), (bs, br), (ml, bl)) = (none.model_rms(), none.builtin_rms(), none.left_rms());
    assert!(ms > bs && mr > br && ml > bl, "{none:?}");
    assert!(ml < ms.hypot(mr) && bl < bs.hypot(br), "{none:?}");
    // On a builtin run the model's start is builtin's: the same parts, nothing removed.
    let (builtin, _) = with_split("builtin", true);
    let b = msgs::ErrorSplit::over(&builtin).unwrap();
    assert_eq!((b.model_rms(), b.model_left), (b.builtin_rms(), b.builtin_left));
    assert_eq!(b.left_natural().0, b.left_natural().1);
    // The natural residual the sweeps leave is the run's own on a builtin run: the same solve.
    let run_mean =
        builtin.iter().filter(|s| s.contacts > 0).map(|s| s.natural_rms as f64).sum::<f64>() / b.steps as f64;
    assert!((b.left_natural().1 - run_mean).abs() < 1e-6 * run_mean, "{b:?} vs {run_mean}");
    assert_eq!(b.removed(), (0.0, 0.0));
}

#[test]
fn the_subspace_correction_runs_in_the_world_and_stays_near_builtin() {
    // subspace:K corrects builtin inside the span of the previous solve's last sweeps: on a real
    // pile it changes the warm start (so the run differs) and converges like builtin does.
    let builtin = sweeps_per_step("builtin");
    let subspace = sweeps_per_step("subspace:2");
    assert_ne!(subspace, builtin, "the correction never moved the warm start");
    let (b, s) = (builtin.iter().sum::<u32>() as f64, subspace.iter().sum::<u32>() as f64);
    assert!(s < 1.25 * b && s > 0.75 * b, "subspace:2 {s} vs builtin {b}");
    assert_eq!(ModelSpec::of(ModelKind::Subspace).name(), "subspace:2");
}

/// The world's problem capture and the pipelined model's carry: the step carried one step on is
/// the next step's problem (a test of the world driving a model, so it lives outside both).
mod carried {
    use sim::problem::Problem;
    use sim::warm::{Needs, SolvedStep, Unavailable, WarmStartInput, WarmStartModel};
    use sim::{Impulse, SceneConfig, World, WorldParams};

    /// Keeps, at each step, the problem the world captured and the problem carried one step on.
    #[derive(Default)]
    struct Watch {
        actual: Vec<Problem>,
        ahead: Vec<Problem>,
    }

    /// The shared watch as a model (a newtype: the trait and `Rc` are both foreign here).
    struct Watcher(std::rc::Rc<std::cell::RefCell<Watch>>);

    impl WarmStartModel for Watcher {
        fn name(&self) -> &str {
            "builtin"
        }
        fn needs(&self) -> Needs {
            Needs::PROBLEM
        }
        fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
            self.0.borrow_mut().actual.push(sim::warm::model::step_problem(input)?.clone());
            input.history.fill_previous(input.contacts, out);
            Ok(())
        }
        fn after_step(&mut self, done: &SolvedStep<'_>) {
            let mut ahead = Problem { header: Default::default(), bodies: Vec::new(), contacts: Vec::new() };
            sim::warm::product::carry_one_step(done, done.problem.expect("asked for"), &mut ahead);
            self.0.borrow_mut().ahead.push(ahead);
        }
    }

    /// The problem carried one step on is the next step's problem on every contact that
    /// persists: the same previous impulses and ages exactly, the same velocities, and the
    /// geometry re-measured at the corrected poses within a small fraction of a body's size.
    #[test]
    fn a_step_carried_on_is_the_next_steps_problem_on_persisting_contacts() {
        let watch = std::rc::Rc::new(std::cell::RefCell::new(Watch::default()));
        let mut warm = sim::warm::WarmStarter::new(Box::new(Watcher(watch.clone())), Box::new(sim::warm::Builtin));
        let recommended = WorldParams::recommended();
        // A budget of 8 sweeps: the regime the pipelined model is for.
        let params = WorldParams { solve: sim::SolveParams { max_sweeps: 8, ..recommended.solve }, ..recommended };
        let mut world = World::new(&SceneConfig { n: 60, seed: 5, ..Default::default() }, params).unwrap();
        for _ in 0..120 {
            world.step(&mut warm);
        }
        let watch = watch.borrow();
        let (mut compared, mut worst) = (0, [0.0f32; 5]);
        for (ahead, next) in watch.ahead.iter().zip(&watch.actual[1..]) {
            assert_eq!(ahead.header.step, next.header.step);
            for (a, n) in ahead.bodies.iter().zip(&next.bodies) {
                worst[0] = worst[0].max((a.v[0] - n.v[0]).abs().max((a.v[1] - n.v[1]).abs()).max((a.w - n.w).abs()));
            }
            for n in &next.contacts {
                let Some(a) =
                    ahead.contacts.iter().find(|a| (a.body_a, a.body_b, a.feature) == (n.body_a, n.body_b, n.feature))
                else {
                    continue;
                };
                compared += 1;
                assert_eq!((a.age, a.previous, a.before_previous), (n.age, n.previous, n.before_previous));
                let d = |x: [f32; 2], y: [f32; 2]| (x[0] - y[0]).hypot(x[1] - y[1]);
                worst[1] = worst[1].max(d(a.normal, n.normal));
                worst[2] = worst[2].max(d(a.ra, n.ra).max(d(a.rb, n.rb)));
                worst[3] = worst[3].max((a.penetration - n.penetration).abs());
                worst[4] = worst[4].max((a.height - n.height).abs());
            }
        }
        eprintln!(
            "{compared} contacts compared; worst: velocity {}, normal {}, arm {}, depth {}, height {}",
            worst[0], worst[1], worst[2], worst[3], worst[4]
        );
        assert!(compared > 1000, "{compared}");
        assert!(worst[0] < 1e-5, "velocities differ by {}", worst[0]);
        assert!(worst[1] < 0.05 && worst[2] < 0.05 && worst[3] < 0.01 && worst[4] < 0.05, "{worst:?}");
    }
}

/// A `--gnn-model` that is a device, a FIFO or a folder is refused by its kind before anything is
/// read (`/dev/zero` used to grow `dc-sim` to gigabytes), in the library and in the parameter
/// check a launch file goes through (`DC_VALIDATE=1`: exit status 2), naming the file.
#[test]
fn a_gnn_model_that_is_not_a_regular_file_is_refused_before_reading() {
    let dir = std::env::temp_dir().join(format!("dc-sim-gnn-kinds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("pipe.dcg");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let spec: ModelSpec = "gnn".parse().unwrap();
    let started = std::time::Instant::now();
    for (path, why) in [
        (std::path::PathBuf::from("/dev/zero"), "is a character device, not a model file"),
        (fifo.clone(), "is a FIFO (named pipe), not a model file"),
        (dir.clone(), "is a directory, not a model file"),
    ] {
        let files = sim::ModelFiles { gnn: Some(path.clone()) };
        let e = spec.build_with(0, sim::warm::Served::default(), &files).err().expect("refused").to_string();
        assert!(e.contains(&format!("{}: {why}", path.display())), "{e}");
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_dc-sim"))
            .args(["--model", "gnn", "--gnn-model"])
            .arg(&path)
            .env("DC_VALIDATE", "1")
            .env_remove("DC_BUS")
            .env_remove("DC_LAUNCHED")
            .output()
            .expect("run dc-sim");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(err.contains(&format!("{}: {why}", path.display())), "{err}");
    }
    assert!(started.elapsed() < std::time::Duration::from_secs(20), "{:?}", started.elapsed());
    let _ = std::fs::remove_dir_all(&dir);
}

/// The shipped small budget network, for tests of how a trained network is deployed.
fn shipped_network() -> sim::ModelFiles {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/gnn-budget8-small.dcg");
    sim::ModelFiles { gnn: Some(path) }
}

/// Every step of seed 0 (ball-box, 8 PGS sweeps a step) with `spec`: the step's contact keys,
/// the warm start it used and its final impulses.
type StepRecord = (Vec<sim::ContactKey>, Vec<sim::Impulse>, Vec<sim::Impulse>);

fn network_run(spec: &str, files: &sim::ModelFiles, steps: u32) -> Vec<StepRecord> {
    let spec: ModelSpec = spec.parse().unwrap();
    let mut warm = WarmStarter::new(
        spec.build_with(0, sim::warm::Served::default(), files).unwrap(),
        ModelKind::Builtin.build(0).unwrap(),
    );
    warm.begin_simulation(0, 0);
    let mut params = WorldParams::default();
    params.solve.max_sweeps = 8;
    let mut world = World::new(&SceneConfig::default(), params).unwrap();
    (0..steps)
        .map(|_| {
            assert!(!world.step(&mut warm).fallback);
            let keys = world.contacts().iter().map(|c| c.key).collect();
            (keys, world.warm_start_used().to_vec(), world.impulses().to_vec())
        })
        .collect()
}

#[test]
fn the_network_every_n_steps_carries_its_correction_on_persisting_contacts() {
    let files = shipped_network();
    let (gnn, every_1) = (network_run("gnn", &files, 80), network_run("gnn-every:1", &files, 80));
    assert!(gnn == every_1, "gnn-every:1 is gnn, bit for bit");
    let every_3 = network_run("gnn-every:3", &files, 120);
    let builtin_start = |s: usize, key: &sim::ContactKey| -> Option<sim::Impulse> {
        let (keys, _, impulses) = &every_3[s.checked_sub(1)?];
        keys.binary_search(key).ok().map(|i| impulses[i])
    };
    let mut correction = std::collections::BTreeMap::new();
    let (mut corrected, mut moved) = (0, 0);
    for (s, (keys, used, _)) in every_3.iter().enumerate() {
        if s % 3 == 0 {
            // The network ran: keep its correction to builtin's start.
            correction.clear();
            for (k, u) in keys.iter().zip(used) {
                let b = builtin_start(s, k).unwrap_or_default();
                correction.insert(*k, sim::Impulse { normal: u.normal - b.normal, tangent: u.tangent - b.tangent });
            }
            continue;
        }
        for (k, u) in keys.iter().zip(used) {
            let expected = match (builtin_start(s, k), correction.get(k)) {
                (Some(b), Some(d)) => {
                    corrected += 1;
                    moved += usize::from(d.normal != 0.0 || d.tangent != 0.0);
                    sim::Impulse { normal: b.normal + d.normal, tangent: b.tangent + d.tangent }
                }
                (b, _) => b.unwrap_or_default(),
            };
            assert_eq!(*u, expected, "step {s}, contact {k:?}");
        }
    }
    // The test sees carried corrections, most of them non-zero (a trained network).
    assert!(corrected > 1000 && moved * 2 > corrected, "{moved} of {corrected} carried corrections non-zero");
}
