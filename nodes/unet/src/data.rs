//! Training samples made on the fly from recordings: for two consecutive recorded steps k, k+1 of
//! one simulation, the input is the bodies grid of step k (with step k's impulses in the temporal
//! variant) and the target is the impulse grid of step k+1 — exactly what `dc-sph` publishes and
//! what the simulator asks for at step k+1. Nothing is written to disk but the split.
//!
//! The split is by simulation, never by frame (frames of one simulation are near copies of each
//! other), and a simulation's first step never takes "previous" data from another simulation.

use crate::{Result, UnetError};
use msgs::{Body, Contact, ProblemBody, ProblemContact, StepHeader};
use recorder::Steps;
use serde::{Deserialize, Serialize};
use sph::{Bounds, GridGeometry, KernelKind, Mode, Search, SplitMix64, Transfer, TransferConfig};
use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// How grids are made: the parameters `dc-sph` must be started with for a model to fit its input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridSpec {
    pub kernel: String,
    pub h: f32,
    /// Node spacing.
    pub res: f32,
    pub mode: String,
    /// Grid sides rounded up to a multiple of this.
    pub pad_to: usize,
    /// Whether the input carries the step's impulses (`prev_normal`, `prev_tangent`).
    pub temporal: bool,
}

impl Default for GridSpec {
    fn default() -> Self {
        GridSpec { kernel: "poly6".into(), h: 0.5, res: 0.125, mode: "preserving".into(), pad_to: 128, temporal: true }
    }
}

impl GridSpec {
    /// The transfer these parameters describe.
    pub fn transfer_config(&self) -> Result<TransferConfig> {
        let bad = |e: sph::SphError| UnetError::Config(format!("grid spec: {e}"));
        Ok(TransferConfig {
            kernel: self.kernel.parse::<KernelKind>().map_err(bad)?,
            h: self.h,
            mode: self.mode.parse::<Mode>().map_err(bad)?,
            search: Search::IndexWindow,
            weight_channel: false,
        })
    }

    /// The grid over a scene whose bodies (walls included) are `bodies`, as `dc-sph --bounds auto`
    /// chooses it.
    pub fn geometry(&self, bodies: &[Body]) -> Result<GridGeometry> {
        let bounds = Bounds::from_walls(bodies).unwrap_or(Bounds::THESIS_BOX);
        GridGeometry::from_bounds(bounds, self.res, self.pad_to)
            .map_err(|e| UnetError::Config(format!("grid spec: {e}")))
    }

    /// Input channel names, in order.
    pub fn input_channels(&self) -> Vec<String> {
        let mut c: Vec<String> = sph::BODY_CHANNELS.iter().map(|s| s.to_string()).collect();
        if self.temporal {
            c.extend(sph::TEMPORAL_CHANNELS.iter().map(|s| s.to_string()));
        }
        c
    }

    /// `dc-sph` arguments producing this model's input.
    pub fn sph_args(&self) -> Vec<String> {
        let mut a = vec![
            format!("--kernel={}", self.kernel),
            format!("--h={}", self.h),
            format!("--res={}", self.res),
            format!("--mode={}", self.mode),
            format!("--pad-to={}", self.pad_to),
        ];
        if self.temporal {
            a.push("--temporal".into());
        }
        a
    }
}

/// A (run id, simulation) pair: the unit of the split.
pub type SimKey = (u64, u32);

/// Which simulations train, validate and test. Saved beside the model.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Split {
    pub train: BTreeSet<SimKey>,
    pub validation: BTreeSet<SimKey>,
    pub test: BTreeSet<SimKey>,
}

/// Part of a split.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    Train,
    Validation,
    Test,
}

impl Split {
    /// Shuffles `simulations` with `seed` and cuts them by fraction; with 3 or more simulations a
    /// non-zero fraction gets at least one simulation.
    pub fn by_simulation(simulations: &BTreeSet<SimKey>, validation: f64, test: f64, seed: u64) -> Split {
        let mut keys: Vec<SimKey> = simulations.iter().copied().collect();
        // The seed is the generator's state as is (not `sph::synth`'s frame seeding): splits stay as
        // they were.
        let mut rng = SplitMix64::new(seed);
        for i in (1..keys.len()).rev() {
            keys.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
        }
        let n = keys.len();
        let at_least = |f: f64| if n >= 3 && f > 0.0 { ((f * n as f64).round() as usize).max(1) } else { 0 };
        // Never more than there are (shares that add up past 1, or are not finite, from a caller
        // that skipped the flags' bounds): validation first, then test, the rest trains.
        let n_val = at_least(validation).min(n);
        let n_test = at_least(test).min(n - n_val);
        Split {
            validation: keys[..n_val].iter().copied().collect(),
            test: keys[n_val..n_val + n_test].iter().copied().collect(),
            train: keys[n_val + n_test..].iter().copied().collect(),
        }
    }

    /// The part holding `key`, if any.
    pub fn part(&self, key: SimKey) -> Option<Part> {
        if self.train.contains(&key) {
            Some(Part::Train)
        } else if self.validation.contains(&key) {
            Some(Part::Validation)
        } else if self.test.contains(&key) {
            Some(Part::Test)
        } else {
            None
        }
    }

    /// The simulations of `part`.
    pub fn of(&self, part: Part) -> &BTreeSet<SimKey> {
        match part {
            Part::Train => &self.train,
            Part::Validation => &self.validation,
            Part::Test => &self.test,
        }
    }
}

/// The simulations in a recording (file or folder), read from its steps.
pub fn list_simulations(path: &Path) -> Result<BTreeSet<SimKey>> {
    Ok(Recordings::survey(&[path.to_path_buf()], false)?.simulations)
}

/// The recordings of a training set that read intact, with their simulations, and those left out.
#[derive(Debug, Clone)]
pub struct Recordings {
    /// What the user named (files or folders: several make one data set).
    pub paths: Vec<PathBuf>,
    pub files: Vec<PathBuf>,
    pub simulations: BTreeSet<SimKey>,
    /// Files left out, with why (`skip_bad`).
    pub skipped: Vec<(PathBuf, String)>,
}

impl Recordings {
    /// Reads every recording of `paths` through (each a file or a folder of them: the
    /// recordings of several hosts or shards are one data set; a file named twice, or inside a
    /// folder also named, is read once). A damaged or unreadable one is an error, or with
    /// `skip_bad` is left out and listed (a folder of overnight recordings with one cut short
    /// still trains); no usable simulation at all is an error either way. Simulations are told
    /// apart by their run (`SimKey`), so two hosts' seed 3 are two simulations.
    pub fn survey(paths: &[PathBuf], skip_bad: bool) -> Result<Recordings> {
        if paths.is_empty() {
            return Err(UnetError::Data("no recordings named".into()));
        }
        let mut out =
            Recordings { paths: paths.to_vec(), files: Vec::new(), simulations: BTreeSet::new(), skipped: Vec::new() };
        let mut seen = BTreeSet::new();
        let mut files = Vec::new();
        for path in paths {
            for file in recorder::recording_files(path)? {
                if seen.insert(std::fs::canonicalize(&file).unwrap_or_else(|_| file.clone())) {
                    files.push(file);
                } else {
                    tracing::warn!(file = %file.display(), "named twice: read once");
                }
            }
        }
        for file in files {
            match recorder::Info::read(&file) {
                Ok(info) if info.simulations.is_empty() => out.skipped.push((file, "no simulation steps".into())),
                Ok(info) => {
                    out.simulations.extend(info.simulations.keys().copied());
                    out.files.push(file);
                }
                Err(e) if skip_bad => out.skipped.push((file, e.to_string())),
                Err(e) => return Err(e.into()),
            }
        }
        for (file, why) in &out.skipped {
            tracing::warn!(file = %file.display(), "left out of training: {why}");
        }
        if out.simulations.is_empty() {
            let skipped =
                if out.skipped.is_empty() { String::new() } else { format!(" ({} files left out)", out.skipped.len()) };
            return Err(UnetError::Data(format!("{}: no simulation steps recorded{skipped}", out.named())));
        }
        Ok(out)
    }

    /// What the user named, as messages and the model file say it.
    pub fn named(&self) -> String {
        named(&self.paths)
    }
}

/// Paths as one list for messages (`a.mcap, shards/1`).
pub fn named(paths: &[PathBuf]) -> String {
    paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
}

/// One training example, channel-major (`[channels][height][width]`).
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// The input step (the target is the step after it).
    pub key: StepHeader,
    pub input: Vec<f32>,
    pub target: Vec<f32>,
    pub height: usize,
    pub width: usize,
    /// The target step's contacts as the simulator reads a grid at them: the loss taken at
    /// contact points (`--loss points`).
    pub points: Vec<PointTarget>,
    /// The same contacts with the reference solution as the target (`--loss reference`); `None`
    /// when the recording has no labelled problem for the target step.
    pub reference_points: Option<Vec<PointTarget>>,
    /// The target step's velocity problem, with where the simulator reads the grid for each of
    /// its rows (`--loss unrolled`); `None` when the recording has no problem for that step.
    pub problem: Option<Arc<StepProblem>>,
    /// The sweeps the recorded solver spent on the target step (1 when the recording has no
    /// statistics): steps that cost sweeps weigh more in the points loss.
    pub sweeps: f32,
}

/// The target step's velocity problem as the simulator poses it, and each contact row's grid
/// sample: what `unet-delta`'s warm start is solved from (the loss after unrolled sweeps).
#[derive(Debug, Clone, PartialEq)]
pub struct StepProblem {
    pub bodies: Vec<ProblemBody>,
    pub contacts: Vec<ProblemContact>,
    /// Per row of `contacts`: the grid nodes and weights of the simulator's bilinear sample at
    /// the contact point (`None`: no sample there, builtin's impulse stays).
    pub stencils: Vec<Option<[(u32, f32); 4]>>,
}

impl StepProblem {
    /// `next`'s problem, its rows located by `next`'s contact points (the same contact is the same
    /// bodies and feature).
    pub fn locate(
        geometry: &GridGeometry,
        next: &[Contact],
        bodies: Vec<ProblemBody>,
        contacts: Vec<ProblemContact>,
    ) -> StepProblem {
        let at: HashMap<_, _> = next.iter().map(|c| (contact_key(c), (c.x, c.y))).collect();
        let stencils = contacts
            .iter()
            .map(|c| {
                let (x, y) = *at.get(&(c.body_a, c.body_b, c.feature))?;
                let stencil = geometry.bilinear_stencil(x, y)?;
                Some(stencil.map(|(n, w)| (n as u32, w)))
            })
            .collect();
        StepProblem { bodies, contacts, stencils }
    }
}

/// One contact of the target step, for the loss at contact points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointTarget {
    /// The grid nodes (indices within a channel) the simulator's bilinear sample reads, and their
    /// weights.
    pub stencil: [(u32, f32); 4],
    /// The contact existed in the input step: `unet-delta` adds the predicted change to builtin's
    /// impulse there, so the target is the change; on a new contact it is the impulse itself.
    pub persisting: bool,
    /// Target normal and tangent: the change on persisting contacts, the impulse on new ones.
    pub normal: f32,
    pub tangent: f32,
}

/// Contacts of `next` as point targets against the impulses of `previous` (the same contact is
/// the same bodies and feature): the targets are `next`'s own (recorded) impulses.
pub fn point_targets(geometry: &GridGeometry, previous: &[Contact], next: &[Contact]) -> Vec<PointTarget> {
    targets_at(geometry, previous, next, |c| Some([c.normal_impulse, c.tangent_impulse]))
}

/// [`point_targets`] whose targets are the reference solution of `next`'s problem
/// (`problem/contacts` labelled by `dc-sim --label-tolerance`) instead of the impulses the run
/// ended with: what a warm start for a sweep budget should approach, where the recorded impulse
/// is itself the unconverged result of the budget. `None` when a contact of `next` has no
/// labelled row in `problem`.
pub fn reference_point_targets(
    geometry: &GridGeometry,
    previous: &[Contact],
    next: &[Contact],
    problem: &[ProblemContact],
) -> Option<Vec<PointTarget>> {
    let reference: HashMap<_, _> = problem.iter().map(|c| ((c.body_a, c.body_b, c.feature), c.reference)).collect();
    let mut unlabelled = false;
    let targets = targets_at(geometry, previous, next, |c| {
        let r = reference.get(&contact_key(c)).copied().filter(|r| r.iter().all(|v| v.is_finite()));
        unlabelled |= r.is_none();
        r
    });
    (!unlabelled).then_some(targets)
}

fn contact_key(c: &Contact) -> (u32, u32, u32) {
    (c.body_a, c.body_b, c.feature)
}

/// The point targets of `next`'s contacts with a grid sample, `target` giving each one's impulse:
/// the change from `previous` on a persisting contact, the impulse itself on a new one.
fn targets_at(
    geometry: &GridGeometry,
    previous: &[Contact],
    next: &[Contact],
    mut target: impl FnMut(&Contact) -> Option<[f32; 2]>,
) -> Vec<PointTarget> {
    let before: HashMap<_, _> = previous.iter().map(|c| (contact_key(c), c)).collect();
    next.iter()
        .filter_map(|c| {
            let stencil = geometry.bilinear_stencil(c.x, c.y)?;
            let [a, b, cc, d] = stencil.map(|(n, w)| (n as u32, w));
            let [normal, tangent] = target(c)?;
            Some(match before.get(&contact_key(c)) {
                Some(p) => PointTarget {
                    stencil: [a, b, cc, d],
                    persisting: true,
                    normal: normal - p.normal_impulse,
                    tangent: tangent - p.tangent_impulse,
                },
                None => PointTarget { stencil: [a, b, cc, d], persisting: false, normal, tangent },
            })
        })
        .collect()
}

/// The samples of one part of a split, streamed from recordings in recorded order.
pub struct SampleStream {
    steps: Steps,
    spec: GridSpec,
    config: TransferConfig,
    split: Split,
    part: Part,
    /// The transfers of the simulations seen last, newest last (a recording of several
    /// simulators interleaves their steps; each simulation has its own box).
    transfers: Vec<(SimKey, Transfer)>,
    /// Per simulation, its last step: what its next step pairs with.
    previous: HashMap<SimKey, (StepHeader, Vec<Body>, Vec<Contact>)>,
    /// The recordings read, as errors name them.
    source: String,
}

/// Simulations whose transfers are kept (more interleave only when more simulators ran at once).
const KEPT_TRANSFERS: usize = 8;

/// A recorded step's sweeps, 1 when unknown.
fn sweeps_of(stats: Option<&msgs::SolveStats>) -> f32 {
    stats.map(|s| s.header.sweeps.max(1) as f32).unwrap_or(1.0)
}

impl SampleStream {
    /// Samples of `part` from the recording(s) at `path`.
    pub fn open(path: &Path, spec: &GridSpec, split: &Split, part: Part) -> Result<SampleStream> {
        SampleStream::of(Steps::open(path)?, path.display().to_string(), spec, split, part)
    }

    /// Samples of `part` from the intact recordings of a survey.
    pub fn open_recordings(data: &Recordings, spec: &GridSpec, split: &Split, part: Part) -> Result<SampleStream> {
        SampleStream::of(Steps::of_files(data.files.clone()), data.named(), spec, split, part)
    }

    fn of(steps: Steps, source: String, spec: &GridSpec, split: &Split, part: Part) -> Result<SampleStream> {
        Ok(SampleStream {
            steps,
            config: spec.transfer_config()?,
            spec: spec.clone(),
            split: split.clone(),
            part,
            transfers: Vec::new(),
            previous: HashMap::new(),
            source,
        })
    }

    fn make(
        &mut self,
        prev: &(StepHeader, Vec<Body>, Vec<Contact>),
        next_contacts: &[Contact],
        next_problem: Option<(Vec<ProblemBody>, Vec<ProblemContact>)>,
        next_sweeps: f32,
    ) -> Result<Sample> {
        let (key, bodies, contacts) = prev;
        let sim = (key.run_id, key.simulation);
        match self.transfers.iter().position(|(k, _)| *k == sim) {
            Some(i) => {
                let kept = self.transfers.remove(i);
                self.transfers.push(kept);
            }
            None => {
                let geometry = self.spec.geometry(bodies)?;
                let transfer = Transfer::new(self.config, geometry).map_err(|e| UnetError::Config(e.to_string()))?;
                if self.transfers.len() == KEPT_TRANSFERS {
                    self.transfers.remove(0);
                }
                self.transfers.push((sim, transfer));
            }
        }
        let (_, transfer) = self.transfers.last_mut().expect("pushed above");
        let context = |e: sph::SphError| {
            UnetError::Data(format!("{}: simulation {} step {}: {e}", self.source, key.simulation, key.step))
        };
        let temporal = self.spec.temporal.then_some(contacts.as_slice());
        let (input, _) = transfer.bodies_grid(*key, bodies, temporal).map_err(context)?;
        let (target, _) = transfer.contacts_grid(*key, next_contacts).map_err(context)?;
        let g = transfer.geometry();
        Ok(Sample {
            key: *key,
            input: input.items,
            target: target.items,
            height: g.height,
            width: g.width,
            points: point_targets(g, contacts, next_contacts),
            reference_points: next_problem
                .as_ref()
                .and_then(|(_, p)| reference_point_targets(g, contacts, next_contacts, p)),
            problem: next_problem.map(|(b, c)| Arc::new(StepProblem::locate(g, next_contacts, b, c))),
            sweeps: next_sweeps,
        })
    }
}

impl Iterator for SampleStream {
    type Item = Result<Sample>;

    fn next(&mut self) -> Option<Result<Sample>> {
        loop {
            let step = match self.steps.next()? {
                Ok(s) => s,
                Err(e) => return Some(Err(e.into())),
            };
            let key = step.key;
            if self.split.part((key.run_id, key.simulation)) != Some(self.part) {
                continue;
            }
            let sweeps = sweeps_of(step.stats.as_ref());
            let problem = step.problem.map(|(bodies, contacts)| (bodies.items, contacts.items));
            let current = (key, step.bodies.items, step.contacts.items);
            // Only the direct predecessor in the same run and simulation pairs with this step
            // (simulators running at once interleave their steps in a recording).
            let sim = (key.run_id, key.simulation);
            let pair = self.previous.remove(&sim).filter(|(p, _, _)| p.step + 1 == key.step);
            let out = pair.map(|p| self.make(&p, &current.2, problem, sweeps));
            self.previous.insert(sim, current);
            if let Some(sample) = out {
                return Some(sample);
            }
        }
    }
}

/// Per-channel mean and standard deviation of inputs and targets over the training samples,
/// stored with the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    pub input_mean: Vec<f32>,
    pub input_std: Vec<f32>,
    pub target_mean: Vec<f32>,
    pub target_std: Vec<f32>,
}

impl Normalization {
    /// Statistics of `samples`. With `residual` (the input channels holding the previous
    /// impulses) those channels share the target's statistics, so that "previous + correction"
    /// is the same sum in normalised units.
    pub fn compute<I: IntoIterator<Item = Result<Sample>>>(
        samples: I,
        in_channels: usize,
        out_channels: usize,
        residual: Option<[usize; 2]>,
    ) -> Result<(Normalization, usize)> {
        let mut input = vec![Moments::default(); in_channels];
        let mut target = vec![Moments::default(); out_channels];
        let mut n = 0;
        for s in samples {
            let s = s?;
            let nodes = s.height * s.width;
            if s.input.len() != in_channels * nodes || s.target.len() != out_channels * nodes {
                return Err(UnetError::Data(format!(
                    "sample of step {} has {} input / {} target values, expected {} / {} channels of {nodes}",
                    s.key.step,
                    s.input.len(),
                    s.target.len(),
                    in_channels,
                    out_channels
                )));
            }
            for (c, m) in input.iter_mut().enumerate() {
                m.add(&s.input[c * nodes..(c + 1) * nodes]);
            }
            for (c, m) in target.iter_mut().enumerate() {
                m.add(&s.target[c * nodes..(c + 1) * nodes]);
            }
            n += 1;
        }
        if n == 0 {
            return Err(UnetError::Data("no training samples".into()));
        }
        let mut norm = Normalization {
            input_mean: input.iter().map(Moments::mean).collect(),
            input_std: input.iter().map(Moments::std).collect(),
            target_mean: target.iter().map(Moments::mean).collect(),
            target_std: target.iter().map(Moments::std).collect(),
        };
        if let Some(r) = residual {
            for (t, &c) in r.iter().enumerate() {
                norm.input_mean[c] = norm.target_mean[t];
                norm.input_std[c] = norm.target_std[t];
            }
        }
        Ok((norm, n))
    }

    /// Normalises a channel-major input in place.
    pub fn normalize_input(&self, values: &mut [f32]) {
        apply(values, &self.input_mean, &self.input_std, |v, m, s| (v - m) / s);
    }

    /// Normalises a channel-major target in place.
    pub fn normalize_target(&self, values: &mut [f32]) {
        apply(values, &self.target_mean, &self.target_std, |v, m, s| (v - m) / s);
    }

    /// Turns a normalised network output back into impulses, in place.
    pub fn denormalize_target(&self, values: &mut [f32]) {
        apply(values, &self.target_mean, &self.target_std, |v, m, s| v * s + m);
    }
}

fn apply(values: &mut [f32], mean: &[f32], std: &[f32], f: impl Fn(f32, f32, f32) -> f32) {
    let nodes = values.len() / mean.len().max(1);
    for (c, chunk) in values.chunks_mut(nodes.max(1)).enumerate().take(mean.len()) {
        let (m, s) = (mean[c], std[c]);
        for v in chunk {
            *v = f(*v, m, s);
        }
    }
}

/// Running sums in f64 (a million nodes per sample would lose f32 precision).
#[derive(Debug, Clone, Default)]
struct Moments {
    n: f64,
    sum: f64,
    sum_sq: f64,
}

impl Moments {
    fn add(&mut self, values: &[f32]) {
        for &v in values {
            self.sum += v as f64;
            self.sum_sq += (v as f64) * (v as f64);
        }
        self.n += values.len() as f64;
    }
    fn mean(&self) -> f32 {
        (self.sum / self.n.max(1.0)) as f32
    }
    fn std(&self) -> f32 {
        let m = self.sum / self.n.max(1.0);
        let var = (self.sum_sq / self.n.max(1.0) - m * m).max(0.0);
        // A constant channel (e.g. a scene of equal masses seen nowhere) must not divide by zero.
        if var.sqrt() > 1e-8 {
            var.sqrt() as f32
        } else {
            1.0
        }
    }
}
