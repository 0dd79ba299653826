//! Training by replaying recordings: normalisation pass, shuffled mini-batches, Adam or SGD under
//! a schedule, validation each epoch, checkpoints with resume, loss curves as PNG, and the
//! learning-rate finder.

use crate::data::{GridSpec, Normalization, Part, Recordings, Sample, SampleStream, Split, StepProblem};
use crate::model::{UNet, UNetConfig};
use crate::modelfile::{ModelFile, ModelMeta, TrainingSummary};
use crate::schedule::{self, Schedule};
use crate::{Result, UnetError};
use burn::module::Module;
use burn::optim::{momentum::MomentumConfig, AdamConfig, GradientsParams, ModuleOptimizer, SgdConfig};
use burn::tensor::{Bytes, Device, Int, Tensor, TensorData};
use charts::{chart, Axis, Mark, Panel, Series};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use sph::SplitMix64;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Optimiser choice.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OptimizerKind {
    Adam,
    /// SGD with momentum 0.9.
    Sgd,
}

impl std::str::FromStr for OptimizerKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "adam" => Ok(OptimizerKind::Adam),
            "sgd" => Ok(OptimizerKind::Sgd),
            _ => Err(format!("unknown optimiser `{s}` (adam, sgd)")),
        }
    }
}

/// What training minimises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LossKind {
    /// The thesis's: MSE over every grid node (`--contact-weight` weighs nodes under contacts).
    Grid,
    /// At the target step's contact points, read from the grid as `unet-delta` reads it: on a
    /// persisting contact the predicted *change* against the recorded change, on a new one the
    /// predicted impulse against the recorded impulse; each step weighted by the sweeps the
    /// solver spent on it. Needs a residual temporal model (its previous-impulse channels).
    Points,
    /// As `points`, but the target is the step's reference solution (recordings whose problems
    /// `dc-sim --label-tolerance` labelled): a warm start for a sweep budget, where the recorded
    /// impulse is the budget's unconverged result.
    Reference,
    /// What a warm start for a sweep budget is judged on: the residual left after
    /// `--unroll-sweeps` PGS sweeps of the target step's problem (recordings with
    /// `--publish-problem`) from `unet-delta`'s warm start read off the predicted grid, its
    /// gradient computed by hand ([`gnn::unroll`], as the `gnn-budget*` networks are trained).
    Unrolled,
}

impl LossKind {
    /// Read at the contact points (needs the residual model's previous impulses).
    fn at_points(self) -> bool {
        matches!(self, LossKind::Points | LossKind::Reference | LossKind::Unrolled)
    }
}

impl std::str::FromStr for LossKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "grid" => Ok(LossKind::Grid),
            "points" => Ok(LossKind::Points),
            "reference" => Ok(LossKind::Reference),
            "unrolled" => Ok(LossKind::Unrolled),
            _ => Err(format!("unknown loss `{s}` (grid, points, reference, unrolled)")),
        }
    }
}

/// Everything a training run is given.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainOptions {
    /// Recordings or folders of them: one data set.
    pub data: Vec<PathBuf>,
    /// The model file to write; checkpoints go to `<out>.checkpoints/`.
    pub out: PathBuf,
    pub net: UNetConfig,
    pub grid: GridSpec,
    pub epochs: usize,
    pub batch: usize,
    pub optimizer: OptimizerKind,
    pub schedule: Schedule,
    /// Extra loss weight on nodes where the target impulse is non-zero (0 = plain MSE).
    pub contact_weight: f32,
    pub loss: LossKind,
    /// `--loss unrolled`: the sweep budget the warm start is trained for.
    pub unroll_sweeps: usize,
    /// `--loss unrolled`: weight of a normal row still adding impulse after the sweeps (too little
    /// push, which accumulates as penetration) against 1 for the rest.
    pub approach_weight: f64,
    pub validation_fraction: f64,
    pub test_fraction: f64,
    pub seed: u64,
    pub shuffle_buffer: usize,
    /// Stop an epoch after this many batches (0 = the whole training set).
    pub max_batches: usize,
    /// Continue from the last checkpoint.
    pub resume: bool,
    /// Show progress bars.
    pub progress: bool,
    /// Leave out (and list) recordings that do not read intact, instead of failing.
    pub skip_bad: bool,
    /// The command line, kept in the model file.
    pub command: String,
}

/// Where a run is, saved after every epoch.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct CheckpointState {
    epoch: usize,
    optimizer_step: usize,
    meta: ModelMeta,
}

fn checkpoint_dir(out: &Path) -> PathBuf {
    let mut s = out.as_os_str().to_owned();
    s.push(".checkpoints");
    PathBuf::from(s)
}

/// A mini-batch as tensors: normalised input, target, and loss weights.
struct Batch {
    input: Tensor<4>,
    target: Tensor<4>,
    weight: Option<Tensor<4>>,
    points: Option<PointBatch>,
    unrolled: Option<UnrolledBatch>,
    len: usize,
}

/// The batch's problems for `--loss unrolled`: one row per (contact row with a grid sample,
/// channel), gathered from the planes as [`PointBatch`]'s.
struct UnrolledBatch {
    index: Tensor<1, Int>,
    stencil: Tensor<2>,
    /// Per row: its sample, contact row and channel (0 normal, 1 tangent).
    rows: Vec<(usize, usize, usize)>,
    problems: Vec<Arc<StepProblem>>,
    /// Per sample: its step's sweeps over the batch's mean.
    weights: Vec<f64>,
}

/// The batch's contact points, one row per (contact, channel): the four grid values the
/// simulator's bilinear sample reads, gathered from `cat([output, output - previous], 1)` (the
/// impulse planes for new contacts, the change planes for persisting ones).
struct PointBatch {
    /// `[rows * 4]` flat indices into the `[batch, 4, height, width]` planes.
    index: Tensor<1, Int>,
    /// `[rows, 4]` bilinear weights.
    stencil: Tensor<2>,
    /// `[rows]` normalised targets.
    target: Tensor<1>,
    /// `[rows]` the step's sweeps over the batch's mean.
    weight: Tensor<1>,
    rows: usize,
}

fn make_batch(samples: &[Sample], meta: &ModelMeta, objective: Objective, device: &Device) -> Result<Batch> {
    let [h, w] = meta.grid_shape;
    let (c_in, c_out) = (meta.config.in_channels, meta.config.out_channels);
    let b = samples.len();
    let mut input = Vec::with_capacity(b * c_in * h * w);
    let mut target = Vec::with_capacity(b * c_out * h * w);
    let mut weight = Vec::new();
    for s in samples {
        let start = input.len();
        input.extend_from_slice(&s.input);
        meta.normalization.normalize_input(&mut input[start..]);
        if objective.contact_weight > 0.0 {
            weight.extend(s.target.iter().map(|&t| if t != 0.0 { 1.0 + objective.contact_weight } else { 1.0 }));
        }
        let start = target.len();
        target.extend_from_slice(&s.target);
        meta.normalization.normalize_target(&mut target[start..]);
    }
    let points = match objective.loss {
        LossKind::Points | LossKind::Reference => point_batch(samples, meta, objective.loss, device)?,
        LossKind::Grid | LossKind::Unrolled => None,
    };
    let unrolled =
        if objective.loss == LossKind::Unrolled { Some(unrolled_batch(samples, h * w, device)?) } else { None };
    Ok(Batch {
        input: Tensor::from_data(TensorData::new(input, [b, c_in, h, w]), device),
        target: Tensor::from_data(TensorData::new(target, [b, c_out, h, w]), device),
        weight: (!weight.is_empty()).then(|| Tensor::from_data(TensorData::new(weight, [b, c_out, h, w]), device)),
        points,
        unrolled,
        len: b,
    })
}

fn sweeps_weights(samples: &[Sample]) -> Vec<f64> {
    let mean_sweeps = samples.iter().map(|s| s.sweeps as f64).sum::<f64>() / samples.len().max(1) as f64;
    samples.iter().map(|s| s.sweeps as f64 / mean_sweeps).collect()
}

/// The unrolled loss's rows of `samples` on grids of `nodes` nodes a channel.
fn unrolled_batch(samples: &[Sample], nodes: usize, device: &Device) -> Result<UnrolledBatch> {
    let (mut index, mut stencil, mut rows, mut problems) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (b, s) in samples.iter().enumerate() {
        let problem = s.problem.clone().ok_or_else(|| {
            UnetError::Data(format!(
                "--loss unrolled: simulation {} step {} has no recorded problem (record with `dc-sim --publish-problem`)",
                s.key.simulation,
                s.key.step + 1
            ))
        })?;
        for (c, (contact, at)) in problem.contacts.iter().zip(&problem.stencils).enumerate() {
            let Some(at) = at else { continue };
            // As `unet-delta` reads the grid: the change on a persisting contact, the value on a new one.
            let persisting = contact.age > 0;
            for channel in 0..2 {
                let plane = b * 4 + channel + if persisting { 2 } else { 0 };
                for &(node, w) in at {
                    index.push((plane * nodes + node as usize) as i64);
                    stencil.push(w);
                }
                rows.push((b, c, channel));
            }
        }
        problems.push(problem);
    }
    let n = rows.len();
    Ok(UnrolledBatch {
        index: Tensor::<1, Int>::from_data(TensorData::new(index, [n * 4]), device),
        stencil: Tensor::from_data(TensorData::new(stencil, [n, 4]), device),
        rows,
        problems,
        weights: sweeps_weights(samples),
    })
}

/// The batch's point targets: the recorded impulses (`points`) or the reference solution
/// (`reference`, an error naming the step when its problem is not labelled). `None`: no contact.
fn point_batch(samples: &[Sample], meta: &ModelMeta, kind: LossKind, device: &Device) -> Result<Option<PointBatch>> {
    let nodes = meta.grid_shape[0] * meta.grid_shape[1];
    let norm = &meta.normalization;
    let weights = sweeps_weights(samples);
    let (mut index, mut stencil, mut target, mut weight) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (b, s) in samples.iter().enumerate() {
        let step_weight = weights[b] as f32;
        let targets = match kind {
            LossKind::Reference => s.reference_points.as_ref().ok_or_else(|| {
                UnetError::Data(format!(
                    "--loss reference: simulation {} step {} has no labelled problem (record with \
                     `dc-sim --publish-problem --label-tolerance`)",
                    s.key.simulation,
                    s.key.step + 1
                ))
            })?,
            _ => &s.points,
        };
        for p in targets {
            for (channel, value) in [(0, p.normal), (1, p.tangent)] {
                let plane = b * 4 + channel + if p.persisting { 2 } else { 0 };
                for &(node, w) in &p.stencil {
                    index.push((plane * nodes + node as usize) as i64);
                    stencil.push(w);
                }
                let (mean, std) = (norm.target_mean[channel], norm.target_std[channel]);
                // A change is a difference of two values with the same statistics: no mean.
                target.push(if p.persisting { value / std } else { (value - mean) / std });
                weight.push(step_weight);
            }
        }
    }
    let rows = target.len();
    Ok((rows > 0).then(|| PointBatch {
        index: Tensor::<1, Int>::from_data(TensorData::new(index, [rows * 4]), device),
        stencil: Tensor::from_data(TensorData::new(stencil, [rows, 4]), device),
        target: Tensor::from_data(TensorData::new(target, [rows]), device),
        weight: Tensor::from_data(TensorData::new(weight, [rows]), device),
        rows,
    }))
}

/// The loss and what it needs beyond the batch.
#[derive(Debug, Clone, Copy)]
struct Objective {
    loss: LossKind,
    contact_weight: f32,
    unroll_sweeps: usize,
    approach_weight: f64,
    /// The targets' normalisation (normal, tangent): the unrolled loss reads impulses.
    target_mean: [f32; 2],
    target_std: [f32; 2],
    /// The residual model's previous-impulse input channels (the points loss needs them).
    residual: Option<[usize; 2]>,
}

impl Objective {
    fn of(opts: &TrainOptions) -> Result<Objective> {
        if opts.loss.at_points() && opts.net.residual.is_none() {
            return Err(UnetError::Config(
                "--loss points/reference/unrolled reads predicted changes: it needs a residual temporal model".into(),
            ));
        }
        if opts.loss == LossKind::Unrolled && opts.unroll_sweeps == 0 {
            return Err(UnetError::Config("--loss unrolled needs --unroll-sweeps of at least 1".into()));
        }
        Ok(Objective {
            loss: opts.loss,
            contact_weight: opts.contact_weight,
            unroll_sweeps: opts.unroll_sweeps,
            approach_weight: opts.approach_weight,
            target_mean: [0.0; 2],
            target_std: [1.0; 2],
            residual: opts.net.residual,
        })
    }

    /// With the model's target normalisation (known once the training data are surveyed).
    fn normalized_by(self, norm: &Normalization) -> Objective {
        let two = |v: &[f32]| [v.first().copied().unwrap_or(0.0), v.get(1).copied().unwrap_or(1.0)];
        Objective { target_mean: two(&norm.target_mean), target_std: two(&norm.target_std), ..self }
    }

    /// The plain objective validation reports (no contact weight).
    fn unweighted(self) -> Objective {
        Objective { contact_weight: 0.0, ..self }
    }

    fn loss(&self, prediction: Tensor<4>, batch: &Batch) -> Tensor<1> {
        if let (LossKind::Unrolled, Some(unrolled), Some(residual)) = (self.loss, &batch.unrolled, self.residual) {
            return self.unrolled_loss(prediction, &batch.input, unrolled, residual);
        }
        match (self.loss, &batch.points, self.residual) {
            (LossKind::Points | LossKind::Reference, Some(points), Some(residual)) => {
                let previous = crate::model::select_channels(&batch.input, &residual);
                let planes = Tensor::cat(vec![prediction.clone(), prediction - previous], 1);
                let len = planes.dims().iter().product::<usize>();
                let gathered = planes.reshape([len]).select(0, points.index.clone()).reshape([points.rows, 4]);
                let at_points = (gathered * points.stencil.clone()).sum_dim(1).reshape([points.rows]);
                ((at_points - points.target.clone()).square() * points.weight.clone()).mean()
            }
            // A batch without a single contact: nothing to fit at points; zero that keeps the graph.
            (LossKind::Points | LossKind::Reference | LossKind::Unrolled, _, _) => (prediction * 0.0).mean(),
            (LossKind::Grid, _, _) => {
                let sq = (prediction - batch.target.clone()).square();
                match &batch.weight {
                    Some(w) => (sq * w.clone()).mean(),
                    None => sq.mean(),
                }
            }
        }
    }
}

impl Objective {
    /// The mean over the batch's steps of the residual after `unroll_sweeps` PGS sweeps from the
    /// warm start `unet-delta` reads off `prediction`. The sweeps and their gradient are computed
    /// by hand in f64 ([`gnn::unroll::Unrolled`]); the returned tensor has the residual's value
    /// and carries that gradient into the network (`sum(read * gradient)`, its value swapped).
    fn unrolled_loss(
        &self,
        prediction: Tensor<4>,
        input: &Tensor<4>,
        batch: &UnrolledBatch,
        residual: [usize; 2],
    ) -> Tensor<1> {
        if batch.rows.is_empty() {
            return (prediction * 0.0).mean();
        }
        let previous = crate::model::select_channels(input, &residual);
        let planes = Tensor::cat(vec![prediction.clone(), prediction - previous], 1);
        let len = planes.dims().iter().product::<usize>();
        let n = batch.rows.len();
        let gathered = planes.reshape([len]).select(0, batch.index.clone()).reshape([n, 4]);
        let read = (gathered * batch.stencil.clone()).sum_dim(1).reshape([n]);
        let values: Vec<f32> = read.clone().into_data().try_into_vec::<f32>().expect("f32 planes");
        // Builtin's impulse on every row, the grid's where the simulator reads it.
        let mut warm: Vec<Vec<[f64; 2]>> = batch
            .problems
            .iter()
            .map(|p| p.contacts.iter().map(|c| [c.previous[0] as f64, c.previous[1] as f64]).collect())
            .collect();
        let (mean, std) = (self.target_mean, self.target_std);
        for (&(b, c, ch), &v) in batch.rows.iter().zip(&values) {
            let contact = &batch.problems[b].contacts[c];
            warm[b][c][ch] = if contact.age > 0 {
                contact.previous[ch] as f64 + (std[ch] * v) as f64
            } else {
                (mean[ch] + std[ch] * v) as f64
            };
        }
        let steps = batch.problems.len() as f64;
        let (total, grads) = self.residuals(batch, &warm);
        let g: Vec<f32> = batch
            .rows
            .iter()
            .map(|&(b, c, ch)| (batch.weights[b] * grads[b][c][ch] * std[ch] as f64 / steps) as f32)
            .collect();
        let g = Tensor::<1>::from_data(TensorData::new(g, [n]), &read.device());
        let surrogate = (read * g).sum();
        surrogate.clone() - surrogate.detach() + (total / steps) as f32
    }

    /// The weighted sum over the batch's steps of the residual after the sweeps from `warm`
    /// (per step, per contact row), and each step's gradient.
    fn residuals(&self, batch: &UnrolledBatch, warm: &[Vec<[f64; 2]>]) -> (f64, Vec<Vec<[f64; 2]>>) {
        let mut total = 0.0;
        let mut grads = Vec::with_capacity(batch.problems.len());
        for ((p, w), warm) in batch.problems.iter().zip(&batch.weights).zip(warm) {
            let mut unrolled = gnn::unroll::Unrolled::new(&p.bodies, &p.contacts);
            unrolled.approach_weight = self.approach_weight;
            let (r, g) = unrolled.loss_and_gradient(warm, self.unroll_sweeps);
            total += w * r;
            grads.push(g);
        }
        (total, grads)
    }

    /// The unrolled loss of builtin's warm start (the previous impulses, 0 on new contacts): the
    /// bar `unet-delta` must beat.
    fn builtin_unrolled_loss(&self, batch: &UnrolledBatch) -> f64 {
        let warm: Vec<Vec<[f64; 2]>> = batch
            .problems
            .iter()
            .map(|p| p.contacts.iter().map(|c| [c.previous[0] as f64, c.previous[1] as f64]).collect())
            .collect();
        self.residuals(batch, &warm).0 / batch.problems.len().max(1) as f64
    }
}

/// Yields shuffled batches from a sample stream through a shuffle buffer.
struct Batcher {
    stream: SampleStream,
    buffer: Vec<Sample>,
    capacity: usize,
    rng: SplitMix64,
    exhausted: bool,
}

impl Batcher {
    fn new(stream: SampleStream, capacity: usize, seed: u64) -> Batcher {
        Batcher { stream, buffer: Vec::new(), capacity: capacity.max(1), rng: SplitMix64::new(seed), exhausted: false }
    }

    /// Tops the buffer up to capacity from the stream.
    fn fill(&mut self) -> Result<()> {
        while !self.exhausted && self.buffer.len() < self.capacity {
            match self.stream.next() {
                Some(s) => self.buffer.push(s?),
                None => self.exhausted = true,
            }
        }
        Ok(())
    }

    /// The next batch of up to `size` samples, each drawn at random from a full buffer; empty at
    /// the end.
    fn next_batch(&mut self, size: usize) -> Result<Vec<Sample>> {
        let mut out = Vec::with_capacity(size);
        while out.len() < size {
            self.fill()?;
            if self.buffer.is_empty() {
                break;
            }
            let i = (self.rng.next_u64() % self.buffer.len() as u64) as usize;
            out.push(self.buffer.swap_remove(i));
        }
        Ok(out)
    }
}

/// In recorded order (validation needs no shuffle).
fn batches_in_order(stream: SampleStream, size: usize) -> impl Iterator<Item = Result<Vec<Sample>>> {
    let mut stream = stream;
    std::iter::from_fn(move || {
        let mut out = Vec::with_capacity(size);
        while out.len() < size {
            match stream.next() {
                Some(Ok(s)) => out.push(s),
                Some(Err(e)) => return Some(Err(e)),
                None => break,
            }
        }
        (!out.is_empty()).then_some(Ok(out))
    })
}

fn optimizer(kind: OptimizerKind) -> ModuleOptimizer {
    match kind {
        OptimizerKind::Adam => AdamConfig::new().init(),
        OptimizerKind::Sgd => SgdConfig::new().with_momentum(Some(MomentumConfig::new())).init(),
    }
}

/// Validation losses: the model's (the training objective, unweighted by contact nodes) and, for
/// residual models, the loss of answering "the previous impulses".
fn evaluate(
    model: &UNet,
    meta: &ModelMeta,
    data: &Recordings,
    (part, split): (Part, &Split),
    batch: usize,
    objective: Objective,
    device: &Device,
) -> Result<(f64, Option<f64>, usize)> {
    let objective = objective.unweighted();
    let model = model.valid();
    let stream = SampleStream::open_recordings(data, &meta.grid, split, part)?;
    let (mut sum, mut sum_prev, mut n) = (0.0f64, 0.0f64, 0usize);
    for samples in batches_in_order(stream, batch) {
        let samples = samples?;
        check_shapes(&samples, meta)?;
        let b = make_batch(&samples, meta, objective, device)?;
        let l: f32 = objective.loss(model.forward(b.input.clone()), &b).into_scalar();
        sum += l as f64 * b.len as f64;
        if let Some(unrolled) = &b.unrolled {
            // The bar for a warm start at a budget is builtin's own.
            sum_prev += objective.builtin_unrolled_loss(unrolled) * b.len as f64;
        } else if let Some(prev) = previous_impulses(&b.input, meta.config.residual) {
            let lp: f32 = objective.loss(prev, &b).into_scalar();
            sum_prev += lp as f64 * b.len as f64;
        }
        n += b.len;
    }
    let simulations = match part {
        Part::Train => &split.train,
        Part::Validation => &split.validation,
        Part::Test => &split.test,
    };
    if n == 0 && !simulations.is_empty() {
        // Simulations were set aside for this part but none of their steps made a sample (frames
        // that do not decode or pair): a NaN loss would be written as if measured.
        let sims: Vec<String> = simulations.iter().map(|(run, sim)| format!("run {run} simulation {sim}")).collect();
        return Err(UnetError::Data(format!(
            "{}: the {what} simulations ({}) yielded no sample (their frames did not decode or pair; see the warnings above): no usable {what} data",
            data.named(),
            sims.join(", "),
            what = format!("{part:?}").to_lowercase()
        )));
    }
    if n == 0 {
        return Ok((f64::NAN, None, 0));
    }
    Ok((sum / n as f64, meta.config.residual.map(|_| sum_prev / n as f64), n))
}

/// The normalised previous impulses of a residual model's input (the `grid` model's answer).
fn previous_impulses(input: &Tensor<4>, residual: Option<[usize; 2]>) -> Option<Tensor<4>> {
    residual.map(|r| crate::model::select_channels(input, &r))
}

fn check_shapes(samples: &[Sample], meta: &ModelMeta) -> Result<()> {
    for s in samples {
        if [s.height, s.width] != meta.grid_shape {
            return Err(UnetError::Data(format!(
                "simulation {} step {}: grid is {} x {}, the model trains on {} x {} (scenes of one size per model)",
                s.key.simulation, s.key.step, s.height, s.width, meta.grid_shape[0], meta.grid_shape[1]
            )));
        }
    }
    Ok(())
}

/// Splits the data, computes the normalisation, and returns the metadata of a fresh model.
fn prepare(opts: &TrainOptions, data: &Recordings) -> Result<(ModelMeta, usize)> {
    let split = Split::by_simulation(&data.simulations, opts.validation_fraction, opts.test_fraction, opts.seed);
    if split.train.is_empty() {
        return Err(UnetError::Data(format!("{}: no simulation left for training", crate::data::named(&opts.data))));
    }
    tracing::info!(
        train = split.train.len(),
        validation = split.validation.len(),
        test = split.test.len(),
        "split by simulation"
    );
    let stream = SampleStream::open_recordings(data, &opts.grid, &split, Part::Train)?;
    let mut shape = None;
    let shaped = stream.map(|s| {
        let s = s?;
        shape.get_or_insert([s.height, s.width]);
        Ok(s)
    });
    let (normalization, train_samples) =
        Normalization::compute(shaped, opts.net.in_channels, opts.net.out_channels, opts.net.residual)?;
    let grid_shape = shape.expect("at least one sample");
    if grid_shape.iter().any(|&n| n % opts.net.size_multiple() != 0) {
        return Err(UnetError::Config(format!(
            "grid {} x {} is not a multiple of 2^levels = {}: set the grid's pad_to to a multiple of it",
            grid_shape[0],
            grid_shape[1],
            opts.net.size_multiple()
        )));
    }
    let meta = ModelMeta {
        config: opts.net.clone(),
        grid: opts.grid.clone(),
        normalization,
        input_channels: opts.grid.input_channels(),
        output_channels: sph::CONTACT_CHANNELS.iter().map(|s| s.to_string()).collect(),
        grid_shape,
        training: TrainingSummary {
            data: crate::data::named(&opts.data),
            skipped_files: data.skipped.iter().map(|(f, why)| format!("{}: {why}", f.display())).collect(),
            train_samples,
            split,
            command: opts.command.clone(),
            ..Default::default()
        },
    };
    Ok((meta, train_samples))
}

fn progress_bar(len: u64, enabled: bool, prefix: String) -> ProgressBar {
    if !enabled {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} batches {msg} ({elapsed}, eta {eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(prefix);
    bar
}

/// Trains a model as `opts` says and writes the model file; returns its metadata.
pub fn train(opts: &TrainOptions, device: &Device) -> Result<ModelMeta> {
    opts.net.validate().map_err(UnetError::Config)?;
    let objective = Objective::of(opts)?;
    if opts.net.in_channels != opts.grid.input_channels().len() {
        return Err(UnetError::Config(format!(
            "the network takes {} input channels, the grid spec makes {} ({:?})",
            opts.net.in_channels,
            opts.grid.input_channels().len(),
            opts.grid.input_channels()
        )));
    }
    let started = Instant::now();
    let data = Recordings::survey(&opts.data, opts.skip_bad)?;
    let dir = checkpoint_dir(&opts.out);
    let train_device = device.clone().autodiff();
    let (mut meta, mut model, mut optim, first_epoch, mut step) = match resume_state(opts, &dir, &train_device)? {
        Some(r) => r,
        None => {
            let (meta, _) = prepare(opts, &data)?;
            device.seed(opts.seed);
            train_device.seed(opts.seed);
            let model = meta.config.init(&train_device);
            (meta, model, optimizer(opts.optimizer), 0, 0)
        }
    };
    let objective = objective.normalized_by(&meta.normalization);
    let split = meta.training.split.clone();
    let batches_per_epoch = {
        let full = meta.training.train_samples.div_ceil(opts.batch.max(1));
        if opts.max_batches > 0 {
            full.min(opts.max_batches)
        } else {
            full
        }
    };
    tracing::info!(
        params = model.num_params(),
        train_samples = meta.training.train_samples,
        batches_per_epoch,
        grid = ?meta.grid_shape,
        "training"
    );
    if meta.training.validation_loss_previous.is_none() && !split.validation.is_empty() {
        let (_, prev, n) = evaluate(&model, &meta, &data, (Part::Validation, &split), opts.batch, objective, device)?;
        meta.training.validation_loss_previous = prev;
        meta.training.validation_samples = n;
        if let Some(p) = prev {
            tracing::info!(
                validation_loss = p,
                "answering the previous step's impulses (the bar to beat; builtin's with --loss unrolled)"
            );
        }
    }
    std::fs::create_dir_all(&dir).map_err(|e| UnetError::Io(dir.display().to_string(), e))?;
    let mut step_losses: Vec<(f64, f64)> = Vec::new();
    for epoch in first_epoch..opts.epochs {
        let stream = SampleStream::open_recordings(&data, &meta.grid, &split, Part::Train)?;
        let mut batcher =
            Batcher::new(stream, opts.shuffle_buffer, opts.seed ^ (epoch as u64 + 1).wrapping_mul(0x9E37_79B9));
        let bar = progress_bar(batches_per_epoch as u64, opts.progress, format!("epoch {}/{}", epoch + 1, opts.epochs));
        let (mut sum, mut seen) = (0.0f64, 0usize);
        let epoch_start = Instant::now();
        for _ in 0..batches_per_epoch {
            let samples = batcher.next_batch(opts.batch)?;
            if samples.is_empty() {
                break;
            }
            check_shapes(&samples, &meta)?;
            let batch = make_batch(&samples, &meta, objective, &train_device)?;
            let l = objective.loss(model.forward(batch.input.clone()), &batch);
            let value: f32 = l.clone().into_scalar();
            if !value.is_finite() {
                return Err(UnetError::Diverged { epoch: epoch + 1, step, lr: opts.schedule.lr(step) });
            }
            let grads = GradientsParams::from_grads(l.backward(), &model);
            model = optim.step(opts.schedule.lr(step), model, grads);
            step += 1;
            sum += value as f64 * batch.len as f64;
            seen += batch.len;
            step_losses.push((step as f64, value as f64));
            bar.set_message(format!(
                "loss {:.4} lr {:.2e} {:.1} samples/s",
                sum / seen as f64,
                opts.schedule.lr(step),
                seen as f64 / epoch_start.elapsed().as_secs_f64()
            ));
            bar.inc(1);
        }
        bar.finish_and_clear();
        let train_loss = sum / seen.max(1) as f64;
        let (val_loss, _, _) =
            evaluate(&model, &meta, &data, (Part::Validation, &split), opts.batch, objective, device)?;
        meta.training.train_loss.push(train_loss);
        meta.training.validation_loss.push(val_loss);
        meta.training.epochs = epoch + 1;
        meta.training.seconds += epoch_start.elapsed().as_secs_f64();
        tracing::info!(
            epoch = epoch + 1,
            train_loss,
            validation_loss = val_loss,
            previous_baseline = meta.training.validation_loss_previous,
            secs = epoch_start.elapsed().as_secs_f32(),
            "epoch done"
        );
        save_checkpoint(&dir, epoch, step, &meta, &model, &optim)?;
    }
    ModelFile::save(&meta, &model.valid(), &opts.out)?;
    write_loss_plot(&opts.out, &meta, opts.loss, &step_losses)?;
    tracing::info!(out = %opts.out.display(), secs = started.elapsed().as_secs_f32(), "model written");
    Ok(meta)
}

fn save_checkpoint(
    dir: &Path,
    epoch: usize,
    step: usize,
    meta: &ModelMeta,
    model: &UNet,
    optim: &ModuleOptimizer,
) -> Result<()> {
    let io = |p: &Path, e: std::io::Error| UnetError::Io(p.display().to_string(), e);
    ModelFile::save(meta, model, &dir.join("model.dcu"))?;
    let bytes = optim
        .into_bytes()
        .map_err(|e| UnetError::Model(dir.display().to_string(), format!("optimiser state: {e:?}")))?;
    let opt_path = dir.join("optimizer.bpk");
    std::fs::write(&opt_path, &*bytes).map_err(|e| io(&opt_path, e))?;
    let state = CheckpointState { epoch, optimizer_step: step, meta: meta.clone() };
    let state_path = dir.join("state.json");
    let json = serde_json::to_vec_pretty(&state).expect("state serialises");
    // Written last: a checkpoint counts only once its state names it.
    std::fs::write(&state_path, json).map_err(|e| io(&state_path, e))
}

type Resumed = (ModelMeta, UNet, ModuleOptimizer, usize, usize);

/// Largest checkpoint state (`state.json`: the metadata with its per-epoch losses).
const MAX_STATE_BYTES: u64 = 64 << 20;
/// Largest optimiser state: Adam keeps two moments a weight, and a model's weights are at most
/// [`runtime::files::MAX_MODEL_BYTES`].
const MAX_OPTIMIZER_BYTES: u64 = 4 * runtime::files::MAX_MODEL_BYTES;

fn resume_state(opts: &TrainOptions, dir: &Path, device: &Device) -> Result<Option<Resumed>> {
    if !opts.resume {
        return Ok(None);
    }
    let state_path = dir.join("state.json");
    // The checkpoint's files are read as model files are: regular files of a bounded size.
    let text = match runtime::files::read_bounded(&state_path, "checkpoint state", MAX_STATE_BYTES) {
        Ok(text) => text,
        Err(runtime::files::UserFileError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => {
            tracing::warn!(dir = %dir.display(), "no checkpoint to resume from; starting afresh");
            return Ok(None);
        }
        Err(e) => return Err(UnetError::Io(state_path.display().to_string(), e.into())),
    };
    let state: CheckpointState =
        serde_json::from_slice(&text).map_err(|e| UnetError::Model(state_path.display().to_string(), e.to_string()))?;
    if state.meta.config != opts.net || state.meta.grid != opts.grid {
        return Err(UnetError::Config(format!(
            "{}: the checkpoint was made with another network or grid ({:?}, {:?}); remove it or match the options",
            dir.display(),
            state.meta.config,
            state.meta.grid
        )));
    }
    let file = ModelFile::load(&dir.join("model.dcu"), device)?;
    let opt_path = dir.join("optimizer.bpk");
    let bytes = runtime::files::read_bounded(&opt_path, "optimiser state", MAX_OPTIMIZER_BYTES)
        .map_err(|e| UnetError::Io(opt_path.display().to_string(), e.into()))?;
    let optim = optimizer(opts.optimizer)
        .from_bytes(Bytes::from_bytes_vec(bytes))
        .map_err(|e| UnetError::Model(opt_path.display().to_string(), format!("{e:?}")))?;
    tracing::info!(epoch = state.epoch + 1, step = state.optimizer_step, "resuming");
    Ok(Some((state.meta, file.model.train(), optim, state.epoch + 1, state.optimizer_step)))
}

/// A PNG at `path` of loss curves: a line per series, x linear, the loss on a log axis.
fn loss_chart(path: &Path, title: &str, x_label: &str, series: &[Series]) -> Result<()> {
    let panel = Panel::new(Axis::linear(x_label), Axis::log("loss"), series, Mark::Lines);
    chart(path, title, &[panel]).map_err(|e| UnetError::Data(e.to_string()))
}

fn write_loss_plot(out: &Path, meta: &ModelMeta, loss: LossKind, step_losses: &[(f64, f64)]) -> Result<()> {
    let per_epoch = |v: &[f64]| v.iter().enumerate().map(|(i, &l)| ((i + 1) as f64, l)).collect::<Vec<_>>();
    let mut series = vec![
        Series { name: "train".into(), points: per_epoch(&meta.training.train_loss), band: None },
        Series { name: "validation".into(), points: per_epoch(&meta.training.validation_loss), band: None },
    ];
    if let Some(p) = meta.training.validation_loss_previous {
        series.push(Series {
            name: "validation: previous impulses".into(),
            points: vec![(1.0, p), (meta.training.epochs.max(1) as f64, p)],
            band: None,
        });
    }
    let path = out.with_extension("loss.png");
    let title = match loss {
        LossKind::Points => "U-Net loss per epoch (at contact points, sweeps-weighted)",
        LossKind::Reference => "U-Net loss per epoch (reference solution at contact points, sweeps-weighted)",
        LossKind::Unrolled => "U-Net loss per epoch (residual after the unrolled sweeps)",
        LossKind::Grid => "U-Net loss per epoch (normalised MSE)",
    };
    loss_chart(&path, title, "epoch", &series)?;
    if !step_losses.is_empty() {
        let smooth = schedule::smoothed(step_losses, 0.98);
        let path = out.with_extension("steps.png");
        loss_chart(
            &path,
            "U-Net training loss per optimiser step",
            "step",
            &[
                Series { name: "batch loss".into(), points: step_losses.to_vec(), band: None },
                Series { name: "smoothed".into(), points: smooth, band: None },
            ],
        )?;
    }
    Ok(())
}

/// A learning-rate curve (rate, loss) and the suggested rate.
pub type LrCurve = (Vec<(f64, f64)>, Option<f64>);

/// The learning-rate finder: trains a fresh model for `steps` batches with the rate growing
/// exponentially from `start` to `end`, stops when the loss blows up, writes the curve as CSV and
/// PNG beside `opts.out`, and returns the curve and the suggested rate.
pub fn find_lr(opts: &TrainOptions, start: f64, end: f64, steps: usize, device: &Device) -> Result<LrCurve> {
    let objective = Objective::of(opts)?;
    let data = Recordings::survey(&opts.data, opts.skip_bad)?;
    let (meta, _) = prepare(opts, &data)?;
    let objective = objective.normalized_by(&meta.normalization);
    let train_device = device.clone().autodiff();
    train_device.seed(opts.seed);
    let mut model = meta.config.init(&train_device);
    let mut optim = optimizer(opts.optimizer);
    let mut curve = Vec::new();
    let mut best = f64::INFINITY;
    let bar = progress_bar(steps as u64, opts.progress, "lr finder".into());
    let mut epoch = 0u64;
    let mut batcher = Batcher::new(
        SampleStream::open_recordings(&data, &meta.grid, &meta.training.split, Part::Train)?,
        opts.shuffle_buffer,
        opts.seed,
    );
    for i in 0..steps {
        let mut samples = batcher.next_batch(opts.batch)?;
        if samples.is_empty() {
            epoch += 1;
            batcher = Batcher::new(
                SampleStream::open_recordings(&data, &meta.grid, &meta.training.split, Part::Train)?,
                opts.shuffle_buffer,
                opts.seed + epoch,
            );
            samples = batcher.next_batch(opts.batch)?;
        }
        let lr = schedule::sweep_lr(start, end, steps, i);
        let batch = make_batch(&samples, &meta, objective, &train_device)?;
        let l = objective.loss(model.forward(batch.input.clone()), &batch);
        let value: f32 = l.clone().into_scalar();
        curve.push((lr, value as f64));
        bar.inc(1);
        let smooth = schedule::smoothed(&curve, 0.9).last().map(|p| p.1).unwrap_or(f64::NAN);
        if !smooth.is_finite() || smooth > 4.0 * best {
            break;
        }
        best = best.min(smooth);
        let grads = GradientsParams::from_grads(l.backward(), &model);
        model = optim.step(lr, model, grads);
    }
    bar.finish_and_clear();
    let suggestion = schedule::suggest_lr(&curve);
    let csv_path = opts.out.with_extension("lr.csv");
    let mut csv = String::from("lr,loss,smoothed\n");
    for ((lr, l), (_, s)) in curve.iter().zip(schedule::smoothed(&curve, 0.9)) {
        csv.push_str(&format!("{lr},{l},{s}\n"));
    }
    if let Some(dir) = csv_path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| UnetError::Io(dir.display().to_string(), e))?;
    }
    std::fs::write(&csv_path, csv).map_err(|e| UnetError::Io(csv_path.display().to_string(), e))?;
    let log_x = |c: &[(f64, f64)]| c.iter().map(|&(lr, l)| (lr.log10(), l)).collect::<Vec<_>>();
    loss_chart(
        &opts.out.with_extension("lr.png"),
        &format!("LR finder (suggested {})", suggestion.map(|s| format!("{s:.2e}")).unwrap_or("none".into())),
        "log10 learning rate",
        &[
            Series { name: "batch loss".into(), points: log_x(&curve), band: None },
            Series { name: "smoothed".into(), points: log_x(&schedule::smoothed(&curve, 0.9)), band: None },
        ],
    )?;
    Ok((curve, suggestion))
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::{ProblemBody, ProblemContact};

    /// Two balls stacked on the floor (body 0): the floor contact persists (age 3, builtin's
    /// impulse known), the contact between the balls is new. Grid 4 x 4, the contacts at nodes.
    fn stacked_sample() -> Sample {
        let ball = |vy: f32| ProblemBody { v: [0.05, vy], w: 0.1, inv_mass: 1.0, inv_inertia: 4.0 };
        let contacts = vec![
            ProblemContact {
                body_a: 0,
                body_b: 1,
                age: 3,
                ra: [0.0, 0.0],
                rb: [0.0, -0.5],
                normal: [0.0, 1.0],
                friction: 0.5,
                previous: [0.15, 0.01],
                ..Default::default()
            },
            ProblemContact {
                body_a: 1,
                body_b: 2,
                ra: [0.1, 0.5],
                rb: [-0.1, -0.5],
                normal: [0.2f32.sin(), 0.2f32.cos()],
                friction: 0.5,
                ..Default::default()
            },
        ];
        let at = |node: u32| Some([(node, 0.5), (node + 1, 0.25), (node + 4, 0.25), (node + 5, 0.0)]);
        Sample {
            key: msgs::StepHeader::default(),
            input: Vec::new(),
            target: Vec::new(),
            height: 4,
            width: 4,
            points: Vec::new(),
            reference_points: None,
            problem: Some(Arc::new(StepProblem {
                bodies: vec![ProblemBody::default(), ball(-0.2), ball(-0.3)],
                contacts,
                stencils: vec![at(5), at(6)],
            })),
            sweeps: 8.0,
        }
    }

    #[test]
    fn the_unrolled_loss_is_the_residual_after_the_sweeps_and_its_gradient() {
        let device = Device::flex();
        let ad = device.clone().autodiff();
        let sample = stacked_sample();
        let batch = unrolled_batch(std::slice::from_ref(&sample), 16, &ad).unwrap();
        assert_eq!(batch.rows.len(), 4, "two contacts, two channels each");
        let objective = Objective {
            loss: LossKind::Unrolled,
            contact_weight: 0.0,
            unroll_sweeps: 3,
            approach_weight: 4.0,
            target_mean: [0.1, 0.0],
            target_std: [0.2, 0.05],
            residual: Some([0, 1]),
        };
        // Input channels 0 and 1 are the previous impulses (normalised), prediction 2 channels.
        let input_values: Vec<f32> = (0..32).map(|i| ((i * 7) % 11) as f32 * 0.1 - 0.5).collect();
        let prediction_values: Vec<f32> = (0..32).map(|i| ((i * 5) % 13) as f32 * 0.1 - 0.6).collect();
        let input = Tensor::<4>::from_data(TensorData::new(input_values.clone(), [1, 2, 4, 4]), &ad);
        let value_at = |prediction: &[f32]| -> f64 {
            let p = Tensor::<4>::from_data(TensorData::new(prediction.to_vec(), [1, 2, 4, 4]), &ad);
            objective.unrolled_loss(p, &input, &batch, [0, 1]).into_scalar::<f32>() as f64
        };
        // By hand: the warm start `unet-delta` reads, then the sweeps.
        let problem = sample.problem.as_ref().unwrap();
        let read = |values: &[f32], channel: usize, node: u32| -> f32 {
            let stencil = [(node, 0.5f32), (node + 1, 0.25), (node + 4, 0.25), (node + 5, 0.0)];
            stencil.iter().map(|&(n, w)| values[channel * 16 + n as usize] * w).sum()
        };
        let change = |ch: usize, node: u32| read(&prediction_values, ch, node) - read(&input_values, ch, node);
        let warm = vec![
            [0.15 + (0.2 * change(0, 5)) as f64, 0.01 + (0.05 * change(1, 5)) as f64],
            [(0.1 + 0.2 * read(&prediction_values, 0, 6)) as f64, (0.05 * read(&prediction_values, 1, 6)) as f64],
        ];
        let mut unrolled = gnn::unroll::Unrolled::new(&problem.bodies, &problem.contacts);
        unrolled.approach_weight = 4.0;
        let (expected, _) = unrolled.loss_and_gradient(&warm, 3);
        assert!(expected > 1e-6, "a residual to take: {expected}");
        let got = value_at(&prediction_values);
        assert!((got - expected).abs() <= 1e-4 * expected, "{got} vs {expected}");

        // The gradient the network receives equals the residual's own, by central differences.
        let p = Tensor::<4>::from_data(TensorData::new(prediction_values.clone(), [1, 2, 4, 4]), &ad).require_grad();
        let grads = objective.unrolled_loss(p.clone(), &input, &batch, [0, 1]).backward();
        let grad: Vec<f32> = p.grad(&grads).expect("a gradient").into_data().try_into_vec::<f32>().unwrap();
        let mut checked = 0;
        for i in [5usize, 6, 9, 10, 16 + 5, 16 + 6, 16 + 10] {
            let eps = 1e-2f32;
            let (mut plus, mut minus) = (prediction_values.clone(), prediction_values.clone());
            plus[i] += eps;
            minus[i] -= eps;
            let numeric = (value_at(&plus) - value_at(&minus)) / (2.0 * eps as f64);
            let analytic = grad[i] as f64;
            assert!(
                (numeric - analytic).abs() <= 0.02 * numeric.abs().max(analytic.abs()) + 1e-7,
                "node {i}: numeric {numeric} vs backward {analytic}"
            );
            checked += usize::from(analytic.abs() > 1e-6);
        }
        assert!(checked >= 4, "the checked nodes carry gradient");
        // Nodes no contact reads get none.
        assert_eq!(grad[0], 0.0);
    }

    #[test]
    fn the_unrolled_loss_needs_recorded_problems() {
        let mut sample = stacked_sample();
        sample.problem = None;
        let e = unrolled_batch(&[sample], 16, &Device::flex()).err().expect("refused");
        assert!(e.to_string().contains("no recorded problem"), "{e}");
    }
}
