//! The U-Net crate: network shapes, learning, model files, normalisation, the dataset from real
//! recorded simulations, and bad input.

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Distribution, Tensor};
use msgs::FrameKind;
use msgs::{ControlKind, ControlMsg, StepHeader};
use recorder::RecordingWriter;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use unet::data::{list_simulations, Normalization, Part, SampleStream, Split};
use unet::schedule::Schedule;
use unet::train::{LossKind, OptimizerKind, TrainOptions};
use unet::{GridSpec, ModelFile, Predictor, UNetConfig, UnetError};

fn device() -> Device {
    Device::flex()
}

fn scratch(test: &str) -> PathBuf {
    deep_contact::scratch_dir(&format!("unet-{test}"))
}

fn values(t: Tensor<4>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().unwrap()
}

/// What was recorded of one step: its bodies and contacts (impulses solved).
type Recorded = BTreeMap<(u32, u32), (Vec<msgs::Body>, Vec<msgs::Contact>)>;

/// A recording of real simulations (the sim library, ball-box with 20 balls in the thesis box),
/// laid out as `dc-record` writes it.
fn record_simulations(path: &Path, run_id: u64, seeds: &[u64], steps: u32) {
    record_settled_simulations(path, run_id, seeds, 0, steps);
}

/// [`record_simulations`] of steps `settle..settle + steps` (the first `settle` are simulated, not
/// recorded). Returns what it recorded per (simulation, step), kept here rather than read back, so
/// that tests compare samples with the simulation itself.
fn record_settled_simulations(path: &Path, run_id: u64, seeds: &[u64], settle: u32, steps: u32) -> Recorded {
    record_steps(path, run_id, seeds, settle, steps, Recording::default())
}

/// [`record_settled_simulations`] with each recorded step's velocity problem labelled with its
/// reference solution (as `dc-sim --publish-problem --label-tolerance 1e-6` records it).
fn record_labelled_simulations(path: &Path, run_id: u64, seeds: &[u64], settle: u32, steps: u32) -> Recorded {
    record_steps(path, run_id, seeds, settle, steps, Recording { labelled: true, ..Recording::default() })
}

/// How [`record_steps`] records.
#[derive(Clone, Copy, Default)]
struct Recording {
    /// Each step's velocity problem, labelled with its reference solution.
    labelled: bool,
    /// The simulations' steps interleaved (A's step k, B's step k, A's step k + 1, ...), as two
    /// simulators running at once are recorded; otherwise one simulation after the other.
    interleaved: bool,
}

fn record_steps(path: &Path, run_id: u64, seeds: &[u64], settle: u32, steps: u32, how: Recording) -> Recorded {
    use sim::{ModelKind, SceneConfig, WarmStarter, World, WorldParams};
    let mut w = RecordingWriter::create(path).unwrap();
    let mut t = 1_000_000_000u64;
    let mut put = |w: &mut RecordingWriter, topic: &str, data: Vec<u8>| {
        t += 1_000;
        w.write(topic, FrameKind::of_topic(topic).unwrap(), t, t, &data).unwrap();
    };
    let run = StepHeader { run_id, simulation: 0, step: 0 };
    put(&mut w, "control", msgs::encode(&ControlMsg::simple(run, ControlKind::RunStart, seeds.len() as u32)).unwrap());
    let (mut bodies, mut contacts) = (Vec::new(), Vec::new());
    let mut recorded = Recorded::new();
    let mut worlds: Vec<(u64, World, WarmStarter)> = seeds
        .iter()
        .map(|&seed| {
            let config = SceneConfig { n: 20, seed, side: Some(15.0), ..SceneConfig::default() };
            let mut world = World::new(&config, WorldParams::default()).unwrap();
            world.set_ids(run_id, seed as u32);
            let mut warm =
                WarmStarter::new(ModelKind::Builtin.build(seed).unwrap(), ModelKind::None.build(seed).unwrap());
            warm.begin_simulation(seed as u32, seed);
            for _ in 0..settle {
                world.step(&mut warm);
            }
            if how.labelled {
                world.capture_problems(Some(sim::SolveParams { tolerance: 1e-6, ..world.params().oracle }));
            }
            (seed, world, warm)
        })
        .collect();
    let order: Vec<(usize, u32)> = if how.interleaved {
        (settle..settle + steps).flat_map(|step| (0..seeds.len()).map(move |i| (i, step))).collect()
    } else {
        (0..seeds.len()).flat_map(|i| (settle..settle + steps).map(move |step| (i, step))).collect()
    };
    for (i, step) in order {
        let (seed, world, warm) = &mut worlds[i];
        world.step(warm);
        world.body_msgs(&mut bodies);
        world.contact_msgs(&mut contacts);
        let h = StepHeader { run_id, simulation: *seed as u32, step };
        if let Some(p) = world.problem() {
            assert_eq!(p.header.step, h, "the problem is the recorded step's");
            put(&mut w, "problem/bodies", msgs::encode(&msgs::Frame::new(h, p.bodies.clone())).unwrap());
            put(&mut w, "problem/contacts", msgs::encode(&msgs::Frame::new(p.header, p.contacts.clone())).unwrap());
        }
        put(&mut w, "bodies", msgs::encode(&msgs::Frame::new(h, bodies.clone())).unwrap());
        put(&mut w, "contacts", msgs::encode(&msgs::Frame::new(h, contacts.clone())).unwrap());
        recorded.insert((*seed as u32, step), (bodies.clone(), contacts.clone()));
    }
    w.finish().unwrap();
    recorded
}

/// Every trainable float parameter of a model, in the module's order (not the batch-norm running
/// statistics: buffers every training forward pass moves, which an optimiser step does not bound).
fn weights(model: &unet::UNet) -> Vec<f32> {
    #[derive(Default)]
    struct Collect {
        path: Vec<String>,
        values: Vec<f32>,
    }
    impl burn::module::ModuleVisitor for Collect {
        fn enter_module(&mut self, name: &str, _: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _: &str, _: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
            if !self.path.last().is_some_and(|p| p.starts_with("running_")) {
                self.values.extend(param.val().into_data().try_into_vec::<f32>().unwrap());
            }
        }
    }
    let mut c = Collect::default();
    model.visit(&mut c);
    c.values
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// Equal up to float rounding (1e-6 of the largest value).
fn assert_close(got: &[f32], expected: &[f32], what: &str) {
    let scale = expected.iter().map(|v| v.abs()).fold(1e-6f32, f32::max);
    let worst = max_abs_diff(got, expected);
    assert!(worst <= 1e-6 * scale, "{what}: differs by {worst} (values up to {scale})");
}

fn small_spec() -> GridSpec {
    // 15 / 0.25 + 1 = 61 nodes, padded to 64: a quarter of the thesis grid's cost.
    GridSpec { res: 0.25, pad_to: 64, ..GridSpec::default() }
}

fn small_net() -> UNetConfig {
    UNetConfig { levels: 2, base_width: 4, ..UNetConfig::default() }
}

#[test]
fn shapes_hold_for_several_sizes_levels_and_batches() {
    let d = device();
    for (levels, [h, w], batch, c_in) in
        [(1, [8, 8], 1, 5), (2, [32, 64], 3, 7), (3, [64, 32], 2, 7), (4, [128, 128], 1, 5)]
    {
        let config = UNetConfig {
            in_channels: c_in,
            levels,
            base_width: 4,
            residual: (c_in == 7).then_some([5, 6]),
            ..UNetConfig::default()
        };
        let model = config.init(&d);
        let y = model.forward(Tensor::<4>::random([batch, c_in, h, w], Distribution::Default, &d));
        assert_eq!(y.dims(), [batch, 2, h, w], "levels {levels}, {h} x {w}");
    }
}

#[test]
fn an_untrained_residual_model_answers_the_previous_impulses_exactly() {
    let d = device();
    let model = UNetConfig { levels: 2, base_width: 4, ..UNetConfig::default() }.init(&d);
    let x = Tensor::<4>::random([2, 7, 16, 16], Distribution::Default, &d);
    let prev = values(x.clone().slice([0..2, 5..7, 0..16, 0..16]));
    assert_eq!(values(model.valid().forward(x)), prev);
}

#[test]
fn a_residual_model_leaves_the_previous_impulses_after_one_training_step() {
    // The zero-initialised head must be a trainable parameter, not a constant.
    let d = device().autodiff();
    d.seed(2);
    let mut model = UNetConfig { levels: 1, base_width: 4, ..UNetConfig::default() }.init(&d);
    let x = Tensor::<4>::random([1, 7, 8, 8], Distribution::Default, &d);
    let prev = values(x.clone().slice([0..1, 5..7, 0..8, 0..8]));
    let target = Tensor::<4>::ones([1, 2, 8, 8], &d);
    let loss = (model.forward(x.clone()) - target).square().mean();
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    model = AdamConfig::new().init().step(1e-2, model, grads);
    assert_ne!(values(model.valid().forward(x.inner())), prev);
}

#[test]
fn overfitting_a_tiny_batch_cuts_the_loss_a_hundredfold() {
    let d = device().autodiff();
    d.seed(1);
    let config = UNetConfig { in_channels: 5, levels: 2, base_width: 8, residual: None, ..UNetConfig::default() };
    let mut model = config.init(&d);
    // A target the input determines: a smooth function of two input channels.
    let x = Tensor::<4>::random([2, 5, 16, 16], Distribution::Default, &d);
    let y = Tensor::cat(
        vec![x.clone().slice([0..2, 0..1, 0..16, 0..16]) * 0.5, x.clone().slice([0..2, 1..2, 0..16, 0..16]).tanh()],
        1,
    );
    let mut optim = AdamConfig::new().init();
    let mut first = None;
    let mut last = f32::NAN;
    for _ in 0..300 {
        let loss = (model.forward(x.clone()) - y.clone()).square().mean();
        last = loss.clone().into_scalar();
        first.get_or_insert(last);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(3e-3, model, grads);
    }
    let first = first.unwrap();
    assert!(last < first / 100.0, "loss {first} -> {last}");
}

fn meta_for(config: &UNetConfig, shape: [usize; 2]) -> unet::ModelMeta {
    let c = config.in_channels;
    unet::ModelMeta {
        config: config.clone(),
        grid: small_spec(),
        normalization: Normalization {
            input_mean: vec![0.1; c],
            input_std: vec![2.0; c],
            target_mean: vec![0.2, -0.1],
            target_std: vec![3.0, 0.5],
        },
        input_channels: small_spec().input_channels(),
        output_channels: vec!["normal".into(), "tangent".into()],
        grid_shape: shape,
        training: Default::default(),
    }
}

#[test]
fn a_saved_model_loads_with_identical_outputs() {
    let d = device();
    let config = UNetConfig { residual: None, ..small_net() };
    let model = config.init(&d);
    // Move the batch-norm running statistics away from their defaults, so they must be saved too.
    let ad = d.clone().autodiff();
    let trained = {
        let mut m = config.init(&ad);
        let mut optim = AdamConfig::new().init();
        for _ in 0..3 {
            let x = Tensor::<4>::random([2, 7, 16, 16], Distribution::Default, &ad) * 3.0 + 1.0;
            let loss = m.forward(x).square().mean();
            let grads = GradientsParams::from_grads(loss.backward(), &m);
            m = optim.step(1e-2, m, grads);
        }
        m.valid()
    };
    drop(model);
    let dir = scratch("save-load");
    let path = dir.join("m.dcu");
    let meta = meta_for(&config, [16, 16]);
    ModelFile::save(&meta, &trained, &path).unwrap();
    let loaded = ModelFile::load(&path, &d).unwrap();
    assert_eq!(loaded.meta, meta);
    let x = Tensor::<4>::random([1, 7, 16, 16], Distribution::Default, &d);
    assert_eq!(values(trained.forward(x.clone())), values(loaded.model.valid().forward(x)));
}

#[test]
fn corrupt_and_mismatched_model_files_are_clear_errors() {
    let d = device();
    let dir = scratch("bad-model");
    let config = small_net();
    let path = dir.join("m.dcu");
    ModelFile::save(&meta_for(&config, [16, 16]), &config.init(&d), &path).unwrap();
    let bytes = std::fs::read(&path).unwrap();

    let not_model = dir.join("notes.dcu");
    std::fs::write(&not_model, b"hello, not a model").unwrap();
    let e = ModelFile::load(&not_model, &d).unwrap_err().to_string();
    assert!(e.contains("notes.dcu") && e.contains("not a Deep Contact U-Net model"), "{e}");

    let truncated = dir.join("truncated.dcu");
    std::fs::write(&truncated, &bytes[..bytes.len() - 100]).unwrap();
    let e = ModelFile::load(&truncated, &d).unwrap_err().to_string();
    assert!(e.contains("truncated.dcu") && e.contains("truncated"), "{e}");

    // Weights of one configuration under the metadata of another: a smaller network's metadata
    // is refused by burn's shapes, a larger one's before anything is allocated for it.
    let json_len = u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize;
    let weights = &bytes[16 + json_len + 8..bytes.len() - 8];
    for (base_width, why) in [(2, "do not fit the configuration"), (8, "bytes of weights, the file holds")] {
        let other = UNetConfig { base_width, ..config.clone() };
        let mixed = dir.join("mixed.dcu");
        let mut meta: serde_json::Value = serde_json::from_slice(&bytes[16..16 + json_len]).unwrap();
        meta["config"] = serde_json::to_value(&other).unwrap();
        let json = serde_json::to_vec(&meta).unwrap();
        let mut out = bytes[..8].to_vec();
        out.extend_from_slice(&(json.len() as u64).to_le_bytes());
        out.extend_from_slice(&json);
        out.extend_from_slice(&bytes[16 + json_len..16 + json_len + 8]);
        out.extend_from_slice(weights);
        out.extend_from_slice(&fnv(&[&json, weights]).to_le_bytes());
        std::fs::write(&mixed, out).unwrap();
        let e = ModelFile::load(&mixed, &d).unwrap_err().to_string();
        assert!(e.contains("mixed.dcu") && e.contains(why), "base width {base_width}: {e}");
    }

    // One flipped byte anywhere in the weights: the checksum refuses the file.
    for at in [16 + json_len + 8 + 10, bytes.len() / 2, bytes.len() - 9] {
        let mut flipped = bytes.clone();
        flipped[at] ^= 0x10;
        let path = dir.join("flipped.dcu");
        std::fs::write(&path, &flipped).unwrap();
        let e = ModelFile::load(&path, &d).unwrap_err().to_string();
        assert!(e.contains("flipped.dcu") && e.contains("checksum mismatch"), "byte {at}: {e}");
    }

    // NaN weights under a valid checksum (saved by a buggy trainer): refused as not finite.
    let mut poisoned = bytes.clone();
    let end = bytes.len() - 8;
    let weights_at = 16 + json_len + 8;
    let mid = weights_at + (end - weights_at) / 2;
    poisoned[mid..mid + 16].fill(0xff);
    let sum = fnv(&[&poisoned[16..16 + json_len], &poisoned[weights_at..end]]);
    poisoned[end..].copy_from_slice(&sum.to_le_bytes());
    let path = dir.join("nan.dcu");
    std::fs::write(&path, &poisoned).unwrap();
    let e = ModelFile::load(&path, &d).unwrap_err().to_string();
    assert!(e.contains("nan.dcu") && e.contains("not finite"), "{e}");

    // A damaged length does not allocate or overflow: a clear error.
    let mut huge = bytes.clone();
    huge[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
    let path = dir.join("huge.dcu");
    std::fs::write(&path, &huge).unwrap();
    let e = ModelFile::load(&path, &d).unwrap_err().to_string();
    assert!(e.contains("huge.dcu") && e.contains("announces"), "{e}");
}

/// A format-1 file (the same layout without the checksum) is refused by every reader; `upgrade`
/// checks its weights and rewrites it as format 2, which then loads to the same network.
#[test]
fn format_1_model_files_are_refused_until_upgraded() {
    let d = device();
    let dir = scratch("format-1");
    let config = small_net();
    let current = dir.join("m.dcu");
    let meta = meta_for(&config, [16, 16]);
    ModelFile::save(&meta, &config.init(&d), &current).unwrap();
    let bytes = std::fs::read(&current).unwrap();
    let mut v1 = bytes[..bytes.len() - 8].to_vec();
    v1[6..8].copy_from_slice(&1u16.to_le_bytes());
    let old = dir.join("old.dcu");
    std::fs::write(&old, &v1).unwrap();
    for e in [ModelFile::load(&old, &d).unwrap_err(), ModelFile::read_meta(&old).unwrap_err()] {
        let e = e.to_string();
        assert!(e.contains("old.dcu") && e.contains("no checksum") && e.contains("dc-unet upgrade"), "{e}");
    }
    let upgraded = dir.join("upgraded.dcu");
    ModelFile::upgrade(&old, &upgraded, &d).unwrap();
    assert_eq!(std::fs::read(&upgraded).unwrap(), bytes, "upgrade writes what save wrote");
    assert_eq!(ModelFile::load(&upgraded, &d).unwrap().meta, meta);

    // Upgrade still checks what it can: weights that do not fit, or are not finite, are refused
    // and nothing is written.
    let mut poisoned = v1.clone();
    let json_len = u64::from_le_bytes(v1[8..16].try_into().unwrap()) as usize;
    let weights_at = 16 + json_len + 8;
    let mid = weights_at + (v1.len() - weights_at) / 2;
    poisoned[mid..mid + 16].fill(0xff);
    std::fs::write(&old, &poisoned).unwrap();
    let refused = dir.join("refused.dcu");
    let e = ModelFile::upgrade(&old, &refused, &d).unwrap_err().to_string();
    assert!(e.contains("old.dcu") && e.contains("not finite"), "{e}");
    assert!(!refused.exists());
}

/// A device, a FIFO or a folder named as a model is refused by its kind, and a file larger than
/// any model by its size, before anything is read (`/dev/zero` used to grow without end), by
/// every reader, naming the file.
#[test]
fn model_paths_that_are_not_regular_files_or_too_large_are_refused_before_reading() {
    let d = device();
    let dir = scratch("kinds");
    let fifo = dir.join("pipe.dcu");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    // Sparse: 2 GiB long, nothing written.
    let huge = dir.join("huge.dcu");
    std::fs::File::create(&huge).unwrap().set_len(2 << 30).unwrap();
    let folder = dir.join("folder.dcu");
    std::fs::create_dir_all(&folder).unwrap();
    let started = std::time::Instant::now();
    for (path, why) in [
        (Path::new("/dev/zero"), "is a character device, not a model file"),
        (folder.as_path(), "is a directory, not a model file"),
        (fifo.as_path(), "is a FIFO (named pipe), not a model file"),
        (huge.as_path(), "is 2 GiB, larger than any model file (at most 256 MiB)"),
    ] {
        let errors = [
            ModelFile::load(path, &d).unwrap_err(),
            ModelFile::read_meta(path).unwrap_err(),
            ModelFile::upgrade(path, &dir.join("out.dcu"), &d).unwrap_err(),
            Predictor::load(path, &d).err().expect("refused"),
        ];
        for e in errors {
            assert!(matches!(e, UnetError::Io(..)), "{e}");
            assert_eq!(e.to_string(), format!("{}: {why}", path.display()));
        }
    }
    assert!(started.elapsed() < std::time::Duration::from_secs(10), "{:?}", started.elapsed());
    // The binary says the same and ends (it used to read /dev/zero until memory ran out).
    let out = dc_unet(&["info", "/dev/zero"], false);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("/dev/zero: is a character device, not a model file"), "{err}");
    // A network whose weights alone would not fit a model file is refused before training.
    let wide = UNetConfig { levels: 7, base_width: 256, ..small_net() };
    let e = wide.validate().unwrap_err();
    assert!(e.contains("more than a model file holds"), "{e}");
}

fn dc_unet(args: &[&str], validate: bool) -> std::process::Output {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_dc-unet"));
    command.args(args).env_remove("DC_BUS").env_remove("DC_LAUNCHED");
    match validate {
        true => command.env("DC_VALIDATE", "1"),
        false => command.env_remove("DC_VALIDATE"),
    };
    command.output().expect("run dc-unet")
}

/// Numbers outside a flag's range and devices this build cannot make are refused when the flags
/// are parsed (exit status 2, the flag named), under the launcher's check (`DC_VALIDATE=1`) too.
#[test]
fn flags_out_of_range_and_unknown_devices_are_refused_by_name() {
    let train = ["train", "--data", "x.mcap"];
    let cases: &[(&[&str], &str, &[&str])] = &[
        (&[], "--device", &["gpu", "cuda:x", "cuda:64", ""]),
        (&[], "--max-batch", &["0", "-1", "1025"]),
        (&train, "--device", &["gpu"]),
        (&train, "--validation", &["-1", "1e308", "nan", "0.6"]),
        (&train, "--test", &["-1", "inf", "0.51"]),
        (&train, "--h", &["nan", "0", "-1", "1e308"]),
        (&train, "--res", &["nan", "0", "inf"]),
        (&train, "--contact-weight", &["-1", "nan", "inf"]),
        (&train, "--approach-weight", &["0", "nan", "1e308"]),
        (&train, "--levels", &["8", "-1"]),
        (&train, "--base-width", &["0", "257"]),
        (&train, "--dilations", &["0", "2,65"]),
        (&train, "--batch", &["0", "4097"]),
        (&train, "--schedule", &["constant:inf", "cosine:0:nan:100"]),
        (&["lr-find", "--data", "x.mcap"], "--start", &["0", "nan", "-1"]),
        (&["bench"], "--devices", &["flex,gpu"]),
    ];
    for (before, flag, values) in cases {
        for value in *values {
            for validate in [false, true] {
                let arg = format!("{flag}={value}");
                let args: Vec<&str> = before.iter().copied().chain([arg.as_str()]).collect();
                let out = dc_unet(&args, validate);
                let err = String::from_utf8_lossy(&out.stderr);
                assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
                assert!(err.contains(flag), "{args:?}: {err}");
            }
        }
    }
    // A build without libtorch says what `cuda` needs.
    if !cfg!(feature = "tch") {
        let err = String::from_utf8_lossy(&dc_unet(&["--device=cuda:0"], true).stderr).into_owned();
        assert!(err.contains("--features tch"), "{err}");
    }
    let out = dc_unet(&["--device=flex", "--max-batch=4"], true);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// Shares that add up past the simulations there are (from a library caller: the flags bound
/// them) split what there is, never index past it.
#[test]
fn a_split_never_takes_more_simulations_than_there_are() {
    let sims: std::collections::BTreeSet<(u64, u32)> = (0..5).map(|i| (1, i)).collect();
    for (validation, test) in [(1e308, 0.1), (0.9, 0.9), (f64::INFINITY, f64::INFINITY), (f64::NAN, 2.0)] {
        let split = Split::by_simulation(&sims, validation, test, 3);
        let total = split.train.len() + split.validation.len() + split.test.len();
        assert_eq!(total, 5, "{validation}, {test}: {split:?}");
    }
}

/// FNV-1a 64, the model file's checksum.
fn fnv(parts: &[&[u8]]) -> u64 {
    parts
        .iter()
        .flat_map(|p| p.iter())
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3))
}

#[test]
fn a_grid_of_the_wrong_size_or_channels_is_rejected_with_both_shapes() {
    let d = device();
    let config = small_net();
    let predictor = Predictor::new(&config.init(&d), meta_for(&config, [64, 64]), &d);
    let names: Vec<String> = small_spec().input_channels();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let mut good =
        msgs::Grid::zeros(StepHeader { run_id: 1, simulation: 3, step: 9 }, [0.0, 0.0], 0.25, 64, 64, &names);
    // Previous impulses in the input (channels 5, 6): the change channels subtract them.
    let plane = 64 * 64;
    for (i, v) in good.items[5 * plane..7 * plane].iter_mut().enumerate() {
        *v = (i % 13) as f32 * 0.1;
    }
    let out = predictor.predict(&good).unwrap();
    // A temporal model: normal, tangent, and the predicted change of each (for `unet-delta`).
    assert_eq!((out.header.width, out.header.height, out.header.channels), (64, 64, 4));
    let channel = |name: &str| out.channel_data(out.header.channel(name).unwrap()).to_vec();
    for (value, change, before) in [("normal", "d_normal", 5), ("tangent", "d_tangent", 6)] {
        let (v, d) = (channel(value), channel(change));
        let prev = &good.items[before * plane..(before + 1) * plane];
        assert!(v.iter().zip(&d).zip(prev).all(|((v, d), p)| (v - p - d).abs() <= 1e-6 * (1.0 + v.abs())), "{change}");
    }
    assert_eq!(out.header.step, good.header.step);

    let small = msgs::Grid::zeros(StepHeader { run_id: 1, simulation: 3, step: 9 }, [0.0, 0.0], 0.25, 61, 61, &names);
    let e = predictor.predict(&small).unwrap_err().to_string();
    assert!(e.contains("7 x 64 x 64") && e.contains("7 x 61 x 61") && e.contains("step 9"), "{e}");
    let five = msgs::Grid::zeros(StepHeader::default(), [0.0, 0.0], 0.25, 64, 64, &names[..5]);
    let e = predictor.predict(&five).unwrap_err().to_string();
    assert!(e.contains("5 x 64 x 64"), "{e}");
}

#[test]
fn normalisation_round_trips_and_residual_channels_share_the_target_statistics() {
    let n = Normalization {
        input_mean: vec![1.0, -2.0],
        input_std: vec![0.5, 4.0],
        target_mean: vec![0.3, 0.0],
        target_std: vec![2.0, 1.0],
    };
    let original: Vec<f32> = (0..8).map(|i| i as f32 * 0.7 - 1.0).collect();
    let mut v = original.clone();
    n.normalize_target(&mut v);
    assert!((v[0] - (original[0] - 0.3) / 2.0).abs() < 1e-6);
    n.denormalize_target(&mut v);
    for (a, b) in v.iter().zip(&original) {
        assert!((a - b).abs() < 1e-5);
    }
    let sample = |k: u32| unet::Sample {
        key: StepHeader { step: k, ..Default::default() },
        input: vec![k as f32, 1.0, 5.0, 5.0, 2.0, 2.0],
        target: vec![10.0, 10.0, 0.0, 4.0],
        height: 1,
        width: 2,
        points: Vec::new(),
        reference_points: None,
        problem: None,
        sweeps: 1.0,
    };
    let (norm, count) = Normalization::compute((0..4).map(|k| Ok(sample(k))), 3, 2, Some([1, 2])).unwrap();
    assert_eq!(count, 4);
    assert_eq!(norm.input_mean[1], norm.target_mean[0]);
    assert_eq!(norm.input_std[2], norm.target_std[1]);
    assert_eq!(norm.target_mean, vec![10.0, 2.0]);
    assert_eq!(norm.target_std, vec![1.0, 2.0], "a constant channel gets std 1, not 0");
}

/// Steps simulated before the dataset test's recording starts (the balls have landed by then).
const SETTLE: u32 = 150;

#[test]
fn samples_pair_consecutive_steps_of_one_simulation_and_the_split_is_by_simulation() {
    let dir = scratch("dataset");
    let file = dir.join("sims.mcap");
    let seeds: Vec<u64> = (1000..1010).collect();
    // Recorded from step SETTLE on, once the balls have landed: every step has contacts.
    let recorded = record_settled_simulations(&file, 5, &seeds, SETTLE, 6);
    let sims = list_simulations(&file).unwrap();
    assert_eq!(sims.len(), 10);
    let split = Split::by_simulation(&sims, 0.2, 0.1, 7);
    assert_eq!((split.train.len(), split.validation.len(), split.test.len()), (7, 2, 1));
    assert!(split.train.is_disjoint(&split.validation) && split.train.is_disjoint(&split.test));
    assert_eq!(split, Split::by_simulation(&sims, 0.2, 0.1, 7), "same seed, same split");
    let spec = small_spec();
    // The impulse grid (normal, tangent) of the contacts recorded at step `of` of simulation `sim`,
    // over that simulation's box, made here from what the simulation produced.
    let impulses_grid = |sim: u32, of: u32| -> Vec<f32> {
        let (bodies, contacts) = &recorded[&(sim, of)];
        let mut t = sph::Transfer::new(spec.transfer_config().unwrap(), spec.geometry(bodies).unwrap()).unwrap();
        t.contacts_grid(StepHeader { run_id: 5, simulation: sim, step: of }, contacts).unwrap().0.items
    };
    let nodes = 64 * 64;
    let (mut total, mut moved, mut with_impulses) = (0, 0, 0);
    for part in [Part::Train, Part::Validation, Part::Test] {
        for s in SampleStream::open(&file, &spec, &split, part).unwrap() {
            let s = s.unwrap();
            assert!(split.of(part).contains(&(s.key.run_id, s.key.simulation)));
            // 5 of the 6 recorded steps are inputs (the last is only a target): 5 samples per
            // simulation, none across.
            assert!((SETTLE..SETTLE + 5).contains(&s.key.step), "{:?}", s.key);
            assert_eq!((s.height, s.width), (64, 64));
            assert_eq!(s.input.len(), 7 * 64 * 64);
            assert_eq!(s.target.len(), 2 * 64 * 64);
            let (sim, k) = (s.key.simulation, s.key.step);
            // The target is the next step's impulses; the input's previous impulses are step k's.
            let next = impulses_grid(sim, k + 1);
            let own = impulses_grid(sim, k);
            let what = format!("simulation {sim} step {k}");
            assert_close(&s.target, &next, &format!("{what}: target vs step {}'s impulses", k + 1));
            assert_close(&s.input[5 * nodes..], &own, &format!("{what}: prev_normal/prev_tangent vs its own impulses"));
            moved += usize::from(max_abs_diff(&own, &next) > 1e-6);
            with_impulses += usize::from(next.iter().any(|v| *v != 0.0));
            total += 1;
        }
    }
    assert_eq!(total, 10 * 5);
    // The comparison has power: a target paired with step k instead of k + 1 would differ.
    assert!(
        with_impulses == total && moved == total,
        "{moved} of {total} samples change from k to k + 1, {with_impulses} have impulses"
    );
    // The first sample of each simulation: its "previous impulses" are that simulation's first
    // recorded step.
    let first = SampleStream::open(&file, &spec, &split, Part::Train).unwrap().next().unwrap().unwrap();
    assert_eq!(first.key.step, SETTLE);
}

#[test]
fn interleaved_simulations_pair_every_step_with_its_own_predecessor() {
    // Two simulators recorded at once interleave their steps: each step still pairs with its own
    // simulation's previous step (a stream that paired only neighbours in the file lost them all).
    let dir = scratch("interleaved");
    let file = dir.join("sims.mcap");
    let how = Recording { interleaved: true, ..Recording::default() };
    let recorded = record_steps(&file, 6, &[1000, 1001, 1002], SETTLE, 5, how);
    let split = Split::by_simulation(&list_simulations(&file).unwrap(), 0.0, 0.0, 1);
    let spec = small_spec();
    let samples: Vec<unet::Sample> =
        SampleStream::open(&file, &spec, &split, Part::Train).unwrap().map(|s| s.unwrap()).collect();
    assert_eq!(samples.len(), 3 * 4, "every step but each simulation's last is an input");
    for s in &samples {
        let (bodies, contacts) = &recorded[&(s.key.simulation, s.key.step)];
        let mut t = sph::Transfer::new(spec.transfer_config().unwrap(), spec.geometry(bodies).unwrap()).unwrap();
        let own = t.contacts_grid(s.key, contacts).unwrap().0.items;
        assert_close(&s.input[5 * 64 * 64..], &own, &format!("{:?}: the input's impulses are its own step's", s.key));
    }
}

fn train_options(data: &Path, out: &Path) -> TrainOptions {
    TrainOptions {
        data: vec![data.to_path_buf()],
        out: out.to_path_buf(),
        net: small_net(),
        grid: small_spec(),
        epochs: 2,
        batch: 4,
        optimizer: OptimizerKind::Adam,
        schedule: Schedule::Constant { lr: 1e-3 },
        contact_weight: 0.0,
        loss: LossKind::Grid,
        unroll_sweeps: 8,
        approach_weight: 4.0,
        validation_fraction: 0.25,
        test_fraction: 0.0,
        seed: 3,
        shuffle_buffer: 16,
        max_batches: 3,
        resume: false,
        progress: false,
        skip_bad: true,
        command: "test".into(),
    }
}

#[test]
fn training_writes_a_usable_model_and_resume_continues_where_it_stopped() {
    let dir = scratch("train");
    let data = dir.join("data.mcap");
    // Landed balls: contacts, so a non-zero loss that moves the weights.
    record_settled_simulations(&data, 9, &[1000, 1001, 1002, 1003], SETTLE, 8);
    let out = dir.join("model.dcu");
    let d = device();
    let mut opts = train_options(&data, &out);
    opts.epochs = 1;
    let meta = unet::train::train(&opts, &d).unwrap();
    assert_eq!(meta.training.epochs, 1);
    assert_eq!(meta.training.split.train.len(), 3);
    assert!(meta.training.validation_loss_previous.is_some());
    assert!(out.with_extension("loss.png").is_file() && out.with_extension("steps.png").is_file());
    let first_train_loss = meta.training.train_loss.clone();
    assert!(first_train_loss[0] > 0.0, "nothing to learn: {first_train_loss:?}");
    // The checkpoint holds the weights of epoch 1 (those of the model file written).
    let checkpoint = dir.join("model.dcu.checkpoints").join("model.dcu");
    let saved = ModelFile::load(&checkpoint, &d).unwrap();
    let after_one = weights(&saved.model);
    assert_eq!(after_one, weights(&ModelFile::load(&out, &d).unwrap().model));
    // Plant weights no fresh start makes (the same network initialised from another seed): resume
    // must continue from them, not from its own initialisation nor from epoch 1's weights.
    d.seed(77);
    let planted_model = small_net().init(&d);
    let planted = weights(&planted_model);
    let apart = max_abs_diff(&planted, &after_one);
    assert!(apart > 0.1, "the planted weights differ from epoch 1's by only {apart}");
    ModelFile::save(&saved.meta, &planted_model, &checkpoint).unwrap();

    opts.epochs = 2;
    opts.resume = true;
    let meta = unet::train::train(&opts, &d).unwrap();
    assert_eq!(meta.training.epochs, 2);
    assert_eq!(meta.training.train_loss.len(), 2, "epoch 1 kept, epoch 2 added");
    // Kept through the checkpoint's JSON (serde_json may round the last bit of an f64).
    let kept = meta.training.train_loss[0];
    assert!((kept - first_train_loss[0]).abs() <= 1e-12 * first_train_loss[0], "{kept} vs {first_train_loss:?}");
    // One epoch is 3 Adam steps at lr 1e-3: no weight moves by more than ~4 lr per step, 0.012.
    let resumed = weights(&ModelFile::load(&out, &d).unwrap().model);
    let (from_planted, from_one) = (max_abs_diff(&resumed, &planted), max_abs_diff(&resumed, &after_one));
    assert!(
        from_planted > 0.0 && from_planted <= 0.012,
        "the resumed model is {from_planted} from the checkpoint's weights and {from_one} from epoch 1's: \
         it did not continue from the checkpoint"
    );

    // The written model predicts a recorded frame's grid.
    let predictor = Predictor::load(&out, &d).unwrap();
    let sample = SampleStream::open(&data, &small_spec(), &meta.training.split, Part::Validation)
        .unwrap()
        .next()
        .unwrap()
        .unwrap();
    let names = small_spec().input_channels();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let mut grid = msgs::Grid::zeros(sample.key, [0.0, 0.0], 0.25, 64, 64, &names);
    grid.items.copy_from_slice(&sample.input);
    let out = predictor.predict(&grid).unwrap();
    assert!(out.items.iter().all(|v| v.is_finite()));

    // Resuming with another network is refused, naming the checkpoint.
    opts.net.base_width = 8;
    let e = unet::train::train(&opts, &d).unwrap_err();
    assert!(matches!(e, UnetError::Config(_)) && e.to_string().contains("checkpoints"), "{e}");
}

#[test]
fn point_targets_are_the_change_on_persisting_contacts_and_the_impulse_on_new_ones() {
    let geometry = sph::GridGeometry::from_bounds(sph::Bounds::new([0.0, 0.0], [4.0, 4.0]).unwrap(), 0.5, 1).unwrap();
    let contact = |a: u32, feature: u32, x: f32, normal: f32, tangent: f32| msgs::Contact {
        body_a: a,
        body_b: 9,
        feature,
        x,
        y: 1.2,
        normal_impulse: normal,
        tangent_impulse: tangent,
        ..Default::default()
    };
    let before = [contact(1, 0, 1.0, 2.0, 0.5), contact(2, 0, 2.0, 7.0, 0.0)];
    // Contact (1, 9, 0) persists (it moved a little); (1, 9, 1) is another feature of that pair: new.
    let after = [contact(1, 0, 1.1, 3.0, 0.25), contact(1, 1, 3.3, 1.5, -0.5), contact(3, 0, f32::NAN, 1.0, 0.0)];
    let points = unet::data::point_targets(&geometry, &before, &after);
    assert_eq!(points.len(), 2, "a contact at a non-finite point has no grid sample and no target");
    assert!(points[0].persisting && (points[0].normal, points[0].tangent) == (1.0, -0.25));
    assert!(!points[1].persisting && (points[1].normal, points[1].tangent) == (1.5, -0.5));
    // The stencil is the simulator's sample: a linear field read through it gives the field at the point.
    let field: Vec<f32> = geometry.node_positions().iter().map(|p| 3.0 * p[0] - p[1]).collect();
    let read: f32 = points[1].stencil.iter().map(|&(n, w)| field[n as usize] * w).sum();
    assert!((read - (3.0 * 3.3 - 1.2)).abs() < 1e-4, "{read}");
}

/// Options that fit a small recording's steps with `loss`: 12 whole epochs at a high rate.
fn fitting_options(data: &Path, out: &Path, loss: LossKind) -> TrainOptions {
    TrainOptions {
        loss,
        epochs: 12,
        max_batches: 0,
        schedule: Schedule::Constant { lr: 1e-2 },
        ..train_options(data, out)
    }
}

#[test]
fn the_points_loss_fits_the_change_at_contact_points() {
    let dir = scratch("points-loss");
    let data = dir.join("data.mcap");
    record_settled_simulations(&data, 11, &[1000, 1001, 1002, 1003], SETTLE, 8);
    let d = device();
    let mut opts = fitting_options(&data, &dir.join("model.dcu"), LossKind::Points);
    let meta = unet::train::train(&opts, &d).unwrap();
    let losses = &meta.training.train_loss;
    let baseline = meta.training.validation_loss_previous.expect("a residual model has the previous-impulses bar");
    assert!(baseline.is_finite() && baseline > 0.0, "{baseline}");
    // The untrained residual model answers the previous impulses (change 0); fitting the training
    // steps' changes at their contact points must lower that loss well below where it started.
    assert!(losses.iter().all(|l| l.is_finite()) && losses[11] < 0.7 * losses[0], "{losses:?}");
    // A model without the previous impulses has no change to predict.
    opts.net.residual = None;
    let e = unet::train::train(&opts, &d).unwrap_err();
    assert!(matches!(e, UnetError::Config(_)) && e.to_string().contains("residual"), "{e}");
}

#[test]
fn reference_targets_are_the_change_to_the_reference_solution() {
    let geometry = sph::GridGeometry { origin: [0.0, 0.0], spacing: 0.5, width: 16, height: 16 };
    let contact = |feature: u32, normal: f32| msgs::Contact {
        body_a: 1,
        body_b: 9,
        feature,
        x: 2.0,
        y: 1.2,
        normal_impulse: normal,
        ..Default::default()
    };
    let row = |feature: u32, reference: [f32; 2]| msgs::ProblemContact {
        body_a: 1,
        body_b: 9,
        feature,
        reference,
        ..Default::default()
    };
    let before = [contact(0, 2.0)];
    // The run ended step k + 1 with 3.0 on the persisting contact; the reference solution is 4.5.
    let after = [contact(0, 3.0), contact(1, 1.5)];
    let problem = [row(1, [0.75, -0.25]), row(0, [4.5, 0.5])];
    let points = unet::data::reference_point_targets(&geometry, &before, &after, &problem).unwrap();
    assert!(points[0].persisting && (points[0].normal, points[0].tangent) == (2.5, 0.5), "{points:?}");
    assert!(!points[1].persisting && (points[1].normal, points[1].tangent) == (0.75, -0.25), "{points:?}");
    assert_eq!(points[0].stencil, unet::data::point_targets(&geometry, &before, &after)[0].stencil);
    // A contact without a labelled row (unlabelled: NaN, or absent): no reference targets for the step.
    assert!(unet::data::reference_point_targets(&geometry, &before, &after, &problem[..1]).is_none());
    let unlabelled = [row(1, [0.75, -0.25]), row(0, [f32::NAN, f32::NAN])];
    assert!(unet::data::reference_point_targets(&geometry, &before, &after, &unlabelled).is_none());
}

#[test]
fn the_reference_loss_fits_the_reference_solution_and_needs_labelled_problems() {
    let dir = scratch("reference-loss");
    let (labelled, plain) = (dir.join("labelled.mcap"), dir.join("plain.mcap"));
    record_labelled_simulations(&labelled, 12, &[1000, 1001, 1002, 1003], SETTLE, 8);
    record_settled_simulations(&plain, 13, &[1000, 1001], SETTLE, 4);
    let everything = |file: &Path| {
        let split = Split::by_simulation(&list_simulations(file).unwrap(), 0.0, 0.0, 1);
        SampleStream::open(file, &small_spec(), &split, Part::Train).unwrap().map(|s| s.unwrap()).collect::<Vec<_>>()
    };
    let samples = everything(&labelled);
    assert_eq!(samples.len(), 4 * 7);
    let mut differ = 0;
    for s in &samples {
        let reference = s.reference_points.as_ref().expect("every step of a labelled recording has its reference");
        assert_eq!(reference.len(), s.points.len(), "step {:?}", s.key);
        for (r, p) in reference.iter().zip(&s.points) {
            assert_eq!((r.stencil, r.persisting), (p.stencil, p.persisting));
            differ += usize::from((r.normal - p.normal).abs() > 1e-5);
        }
    }
    // The run solved to 1e-4, the reference to 1e-6: the targets are not the recorded impulses.
    assert!(differ > 0);
    assert!(everything(&plain).iter().all(|s| s.reference_points.is_none()));

    let d = device();
    let mut opts = fitting_options(&labelled, &dir.join("model.dcu"), LossKind::Reference);
    let losses = unet::train::train(&opts, &d).unwrap().training.train_loss;
    assert!(losses.iter().all(|l| l.is_finite()) && losses[11] < 0.7 * losses[0], "{losses:?}");
    // A recording without labels cannot give the reference: a clear error naming the step.
    opts.data = vec![plain];
    let e = unet::train::train(&opts, &d).unwrap_err();
    assert!(matches!(e, UnetError::Data(_)) && e.to_string().contains("no labelled problem"), "{e}");
}

#[test]
fn the_lr_finder_writes_its_curve() {
    let dir = scratch("lr-find");
    let data = dir.join("data.mcap");
    record_simulations(&data, 2, &[1000, 1001, 1002], 5);
    let out = dir.join("model.dcu");
    let (curve, _) = unet::train::find_lr(&train_options(&data, &out), 1e-5, 1.0, 12, &device()).unwrap();
    assert!(!curve.is_empty() && curve.len() <= 12);
    assert!(curve.windows(2).all(|w| w[1].0 > w[0].0), "rates grow");
    assert!(out.with_extension("lr.png").is_file() && out.with_extension("lr.csv").is_file());
}

#[test]
fn training_data_that_is_not_a_recording_is_a_clear_error() {
    let dir = scratch("bad-data");
    let file = dir.join("x.mcap");
    std::fs::write(&file, b"not mcap").unwrap();
    let e = unet::train::train(&train_options(&file, &dir.join("m.dcu")), &device()).unwrap_err().to_string();
    assert!(e.contains("x.mcap"), "{e}");
}

/// With `--features tch` (libtorch, see scripts/libtorch.sh): one model file gives the same
/// predictions on libtorch CPU as on flex, so a model trained on one backend serves on the other.
#[cfg(feature = "tch")]
#[test]
fn libtorch_and_flex_predict_the_same_from_one_model_file() {
    let flex = device();
    let torch = unet::device("libtorch").unwrap();
    let config = UNetConfig { residual: None, ..small_net() };
    let dir = scratch("tch");
    let path = dir.join("m.dcu");
    ModelFile::save(&meta_for(&config, [16, 16]), &config.init(&flex), &path).unwrap();
    let on_flex = ModelFile::load(&path, &flex).unwrap().model.valid();
    let on_torch = ModelFile::load(&path, &torch).unwrap().model.valid();
    let x: Vec<f32> = (0..7 * 16 * 16).map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0).collect();
    let input = |d: &Device| Tensor::<4>::from_data(burn::tensor::TensorData::new(x.clone(), [1, 7, 16, 16]), d);
    let (a, b) = (values(on_flex.forward(input(&flex))), values(on_torch.forward(input(&torch))));
    let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
    let scale = a.iter().map(|v| v.abs()).fold(0.0f32, f32::max).max(1e-6);
    assert!(worst <= 1e-4 * scale.max(1.0), "flex and libtorch differ by {worst} (outputs up to {scale})");
}

#[test]
fn a_damaged_recording_in_the_training_folder_is_left_out_and_listed() {
    let dir = scratch("skip-bad");
    let data = dir.join("data");
    std::fs::create_dir_all(&data).unwrap();
    record_simulations(&data.join("a.mcap"), 9, &[1000, 1001, 1002, 1003], 8);
    // A recording cut short mid-chunk (a recorder killed by a full disk, say).
    record_simulations(&data.join("b.mcap"), 10, &[1004, 1005], 8);
    let b = std::fs::read(data.join("b.mcap")).unwrap();
    std::fs::write(data.join("b.mcap"), &b[..b.len() * 2 / 3]).unwrap();

    let mut opts = train_options(&data, &dir.join("m.dcu"));
    opts.epochs = 1;
    let meta = unet::train::train(&opts, &device()).unwrap();
    assert_eq!(meta.training.skipped_files.len(), 1, "{:?}", meta.training.skipped_files);
    assert!(meta.training.skipped_files[0].contains("b.mcap"), "{:?}", meta.training.skipped_files);
    // Only a.mcap's four simulations were split.
    let split = &meta.training.split;
    let all: Vec<_> = split.train.iter().chain(&split.validation).chain(&split.test).collect();
    assert_eq!(all.len(), 4);
    assert!(all.iter().all(|(run, _)| *run == 9), "{all:?}");

    // Without --skip-bad the damaged file stops training, named.
    opts.skip_bad = false;
    opts.out = dir.join("m2.dcu");
    let e = unet::train::train(&opts, &device()).unwrap_err().to_string();
    assert!(e.contains("b.mcap"), "{e}");
}

#[test]
fn recordings_of_several_hosts_train_as_one_data_set() {
    // Two shards' recordings (runs 11 and 12, the same seed 1000 on both: two simulations), named
    // as a list with one of them twice (inside its folder, and as a file): read once each.
    let dir = scratch("several");
    let (host_a, host_b) = (dir.join("shard-0"), dir.join("shard-1"));
    std::fs::create_dir_all(&host_a).unwrap();
    std::fs::create_dir_all(&host_b).unwrap();
    record_simulations(&host_a.join("a.mcap"), 11, &[1000, 1001], 8);
    record_simulations(&host_b.join("b.mcap"), 12, &[1000, 1002], 8);
    let survey =
        unet::data::Recordings::survey(&[host_a.clone(), host_b.clone(), host_b.join("b.mcap")], false).unwrap();
    assert_eq!(survey.files.len(), 2, "{:?}", survey.files);
    let keys: Vec<(u64, u32)> = survey.simulations.iter().copied().collect();
    assert_eq!(keys, [(11, 1000), (11, 1001), (12, 1000), (12, 1002)]);

    let mut opts = train_options(&host_a, &dir.join("m.dcu"));
    opts.data = vec![host_a.clone(), host_b.clone()];
    opts.epochs = 1;
    let meta = unet::train::train(&opts, &device()).unwrap();
    let split = &meta.training.split;
    assert_eq!(split.train.len() + split.validation.len() + split.test.len(), 4, "{split:?}");
    assert!(meta.training.data.contains("shard-0") && meta.training.data.contains("shard-1"), "{}", meta.training.data);

    // A name that is not there stops the survey, named.
    let e = unet::data::Recordings::survey(&[host_a, dir.join("shard-9")], false).unwrap_err().to_string();
    assert!(e.contains("shard-9"), "{e}");
}

#[test]
fn validation_simulations_without_a_usable_sample_stop_training() {
    // Four simulations of eight steps and one of a single step (it pairs no step k with k + 1,
    // as a simulation whose frames do not decode): with a split seed that sets the single-step
    // one aside for validation, training must fail instead of writing a NaN validation loss.
    let dir = scratch("no-validation");
    let data = dir.join("data");
    std::fs::create_dir_all(&data).unwrap();
    record_simulations(&data.join("a.mcap"), 9, &[1000, 1001, 1002, 1003], 8);
    record_simulations(&data.join("b.mcap"), 10, &[1004], 1);
    let keys: std::collections::BTreeSet<(u64, u32)> =
        [(9, 1000), (9, 1001), (9, 1002), (9, 1003), (10, 1004)].into_iter().collect();
    let mut opts = train_options(&data, &dir.join("m.dcu"));
    opts.epochs = 1;
    opts.seed = (0..200)
        .find(|&s| Split::by_simulation(&keys, opts.validation_fraction, 0.0, s).validation == [(10, 1004)].into())
        .expect("a split seed that validates on the single-step simulation");
    let e = unet::train::train(&opts, &device()).unwrap_err().to_string();
    assert!(e.contains("no usable validation data") && e.contains("run 10 simulation 1004"), "{e}");
    assert!(!dir.join("m.dcu").exists(), "no model file is written");
}
