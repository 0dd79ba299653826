//! Warm-start models: where the solver's initial guess comes from.
//!
//! A model is one implementation of [`WarmStartModel`]; the solver never knows which one ran.
//! Local models live here; the grid-based ones ([`GridModel`]) sample a 2-channel `msgs::Grid`
//! ("normal", "tangent") that a [`GridSource`] delivers (the bus, in the node). A model that cannot
//! deliver (a late grid) answers [`Unavailable`] and the [`WarmStarter`] falls back to a named
//! model, counting it.

use crate::contact::{ContactPoint, ImpulseHistory};
use crate::error::SimError;
use crate::rng::{Sampler, Xoshiro};
use crate::solver::Impulse;
use sph::sample_bilinear;
use std::str::FromStr;

/// What a model may look at to produce a warm start.
pub struct WarmStartInput<'a> {
    /// Run id of the graph.
    pub run_id: u64,
    /// Simulation index (its seed).
    pub simulation: u32,
    /// Step being solved.
    pub step: u32,
    /// The step's contacts, sorted by key; one impulse per contact is expected.
    pub contacts: &'a [ContactPoint],
    /// Final impulses of the two previous steps.
    pub history: &'a ImpulseHistory,
    /// Per body id: whether it has infinite mass (static or kinematic).
    pub fixed: &'a [bool],
    /// The step's velocity problem, for models that want it ([`WarmStartModel::wants_problem`]).
    pub problem: Option<&'a crate::problem::Problem>,
    /// The step's solver rows, one per contact (empty where a caller has none).
    pub rows: &'a [crate::solver::ContactRow],
    /// The solver's bodies: velocities after external forces, inverse masses.
    pub bodies: &'a [crate::solver::SolverBody],
    /// The solver's relative compliance (`SolveParams::compliance`; 0: rigid).
    pub compliance: f32,
    /// Solves the step's contact problem from builtin's warm start to the oracle's tolerance on
    /// scratch velocities and writes the solution (the oracle behind `copy` and the ablations);
    /// the world's velocities are untouched.
    pub oracle: &'a mut dyn FnMut(&mut [Impulse]),
}

/// Why a model gave no warm start this step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Unavailable(pub String);

/// A source of warm starts. One implementation per model; adding one never touches the solver.
pub trait WarmStartModel {
    /// The model's name (in statistics).
    fn name(&self) -> &str;

    /// Called before the first step of every simulation.
    fn begin_simulation(&mut self, _simulation: u32, _seed: u64) {}

    /// Whether the model reads the step's velocity problem ([`WarmStartInput::problem`]); the
    /// world captures it only for models that do.
    fn wants_problem(&self) -> bool {
        false
    }

    /// Writes one impulse per contact of `input` into `out` (zeroed beforehand), or says why it
    /// cannot this step.
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable>;
}

/// `none`: start from zero.
#[derive(Debug, Default)]
pub struct NoWarmStart;

impl WarmStartModel for NoWarmStart {
    fn name(&self) -> &str {
        "none"
    }
    fn warm_start(&mut self, _: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        out.fill(Impulse::default());
        Ok(())
    }
}

/// `builtin`: the previous step's impulse of the same contact (temporal coherence), 0 for new ones.
#[derive(Debug, Default)]
pub struct Builtin;

impl WarmStartModel for Builtin {
    fn name(&self) -> &str {
        "builtin"
    }
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        input.history.fill_previous(input.contacts, out);
        Ok(())
    }
}

/// `copy`, `copy0`, `copy2`: the step's own solution (optionally rounded to some decimals), the oracle.
#[derive(Debug)]
pub struct Copy {
    decimals: Option<i32>,
    name: &'static str,
}

impl Copy {
    /// The exact solution (`copy`).
    pub fn exact() -> Copy {
        Copy { decimals: None, name: "copy" }
    }
    /// The solution rounded to `decimals` decimals (`copy0`, `copy2`).
    pub fn rounded(decimals: i32) -> Copy {
        let name = match decimals {
            0 => "copy0",
            1 => "copy1",
            2 => "copy2",
            _ => "copyN",
        };
        Copy { decimals: Some(decimals), name }
    }
}

impl WarmStartModel for Copy {
    fn name(&self) -> &str {
        self.name
    }
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        (input.oracle)(out);
        if let Some(d) = self.decimals {
            let s = 10f32.powi(d);
            for o in out.iter_mut() {
                o.normal = (o.normal * s).round() / s;
                o.tangent = (o.tangent * s).round() / s;
            }
        }
        Ok(())
    }
}

/// `copy-grid`, `copy-grid-sph`: the step's exact solution sent through the SPH grid and back
/// (particle -> grid -> bilinear at the contacts). The gate for every grid-based model: no
/// prediction on that grid can do better than the solution itself after the transfer.
pub struct CopyGrid {
    name: &'static str,
    config: sph::TransferConfig,
    /// Grid spacing (the thesis's 0.125).
    spacing: f32,
}

impl CopyGrid {
    /// Through the value-preserving transfer (`copy-grid`) or the thesis's (`copy-grid-sph`).
    pub fn new(mode: sph::Mode) -> CopyGrid {
        let name = match mode {
            sph::Mode::Preserving => "copy-grid",
            sph::Mode::Sph => "copy-grid-sph",
        };
        CopyGrid { name, config: sph::TransferConfig { mode, ..Default::default() }, spacing: 0.125 }
    }

    /// A grid over the contacts, on the lattice of a scene grid with origin (0, 0) (so the result
    /// is the same as on the scene-sized grid: only nodes within the kernel radius matter).
    fn geometry(&self, contacts: &[ContactPoint]) -> Result<sph::GridGeometry, sph::SphError> {
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for c in contacts {
            for (i, v) in [c.point.x, c.point.y].into_iter().enumerate() {
                lo[i] = lo[i].min(v);
                hi[i] = hi[i].max(v);
            }
        }
        let margin = self.config.h + self.spacing;
        let snap_lo = |v: f32| ((v - margin) / self.spacing).floor() * self.spacing;
        let snap_hi = |v: f32| ((v + margin) / self.spacing).ceil() * self.spacing;
        let bounds = sph::Bounds::new([snap_lo(lo[0]), snap_lo(lo[1])], [snap_hi(hi[0]), snap_hi(hi[1])])?;
        sph::GridGeometry::from_bounds(bounds, self.spacing, 1)
    }
}

impl WarmStartModel for CopyGrid {
    fn name(&self) -> &str {
        self.name
    }
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        (input.oracle)(out);
        if input.contacts.is_empty() {
            return Ok(());
        }
        let unavailable = |e: sph::SphError| Unavailable(format!("grid transfer: {e}"));
        let mut particles = sph::ParticleSet::new(&["normal", "tangent"]);
        for (c, o) in input.contacts.iter().zip(out.iter()) {
            let source = sph::Source::Contact { body_a: c.key.body_a, body_b: c.key.body_b };
            particles.push(source, [c.point.x, c.point.y], &[o.normal, o.tangent]).map_err(unavailable)?;
        }
        let mut transfer = sph::Transfer::new(self.config, self.geometry(input.contacts).map_err(unavailable)?)
            .map_err(unavailable)?;
        let (back, _) = transfer.round_trip(&particles).map_err(unavailable)?;
        for (o, v) in out.iter_mut().zip(back.chunks_exact(2)) {
            *o = Impulse { normal: v[0], tangent: v[1] };
        }
        Ok(())
    }
}

/// `bad`: 50 for normal and tangent impulses.
#[derive(Debug, Default)]
pub struct Bad;

impl WarmStartModel for Bad {
    fn name(&self) -> &str {
        "bad"
    }
    fn warm_start(&mut self, _: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        out.fill(Impulse { normal: 50.0, tangent: 50.0 });
        Ok(())
    }
}

/// `random`: normal uniform in [0, 5], tangent uniform in [-2, 2]; reseeded from the simulation's
/// seed, so runs repeat.
#[derive(Clone)]
pub struct Random {
    seed: u64,
    rng: Xoshiro,
}

impl Random {
    /// A random model whose stream derives from `seed` and each simulation's seed.
    pub fn new(seed: u64) -> Random {
        Random { seed, rng: Xoshiro::new(seed) }
    }
}

impl WarmStartModel for Random {
    fn name(&self) -> &str {
        "random"
    }
    fn begin_simulation(&mut self, _simulation: u32, seed: u64) {
        // Distinct from the scene sampler's stream of the same seed.
        self.rng = Xoshiro::new(self.seed ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x5eed);
    }
    fn warm_start(&mut self, _: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        for o in out.iter_mut() {
            o.normal = self.rng.uniform_range(0.0, 5.0) as f32;
            o.tangent = self.rng.uniform_range(-2.0, 2.0) as f32;
        }
        Ok(())
    }
}

/// `extrapolate[:beta]`: `l(k-1) + beta (l(k-1) - l(k-2))` on contacts that persisted two steps
/// (beta 1: linear extrapolation), `l(k-1)` on those that persisted one, clamped to the friction
/// cone.
#[derive(Debug)]
pub struct Extrapolate {
    name: String,
    beta: f32,
}

impl Extrapolate {
    pub fn new(name: String, beta: f32) -> Extrapolate {
        Extrapolate { name, beta }
    }
}

impl WarmStartModel for Extrapolate {
    fn name(&self) -> &str {
        &self.name
    }
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let beta = self.beta;
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            *o = match (input.history.previous(&c.key), input.history.before_previous(&c.key)) {
                (Some(l1), Some(l2)) => {
                    let n = (l1.normal + beta * (l1.normal - l2.normal)).max(0.0);
                    let t_max = c.friction * n;
                    Impulse { normal: n, tangent: (l1.tangent + beta * (l1.tangent - l2.tangent)).clamp(-t_max, t_max) }
                }
                (Some(l1), None) => l1,
                _ => Impulse::default(),
            };
        }
        Ok(())
    }
}

/// `continue[:G]`: builtin plus `G` times the distance the previous solve still had to go along
/// its last sweep's direction. A PGS solve stopped at its tolerance has long been converging like
/// its slowest (smooth, pile-wide) mode, `change(k+1) ~ rate * change(k)`, so the rest of the way
/// is the geometric series `last_change * rate / (1 - rate)` (Aitken's extrapolation): exactly the
/// smooth error that the next solve would otherwise spend its sweeps removing.
#[derive(Debug)]
pub struct Continue {
    name: String,
    gain: f32,
}

/// The largest rate [`Continue`] believes (a solve at its cap converges at a rate near 1, and the
/// series' factor `rate / (1 - rate)` would explode).
pub const MAX_CONTINUE_RATE: f32 = 0.995;

impl Continue {
    pub fn new(name: String, gain: f32) -> Continue {
        Continue { name, gain }
    }

    /// The factor on the last sweep's change: `gain * rate / (1 - rate)`, rate capped.
    pub fn factor(gain: f32, rate: f32) -> f32 {
        let r = rate.clamp(0.0, MAX_CONTINUE_RATE);
        gain * r / (1.0 - r)
    }
}

impl WarmStartModel for Continue {
    fn name(&self) -> &str {
        &self.name
    }
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let factor = Continue::factor(self.gain, input.history.previous_rate());
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            let (Some(l), Some(d)) = (input.history.previous(&c.key), input.history.previous_last_change(&c.key))
            else {
                continue;
            };
            let n = (l.normal + factor * d.normal).max(0.0);
            let t_max = c.friction * n;
            *o = Impulse { normal: n, tangent: (l.tangent + factor * d.tangent).clamp(-t_max, t_max) };
        }
        Ok(())
    }
}

/// `builtin-reappear`: builtin, and a contact new this step that existed two steps ago (it
/// flickered off for one step) starts from its impulse then.
#[derive(Debug, Default)]
pub struct BuiltinReappear;

impl WarmStartModel for BuiltinReappear {
    fn name(&self) -> &str {
        "builtin-reappear"
    }
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            *o = input.history.previous(&c.key).or_else(|| input.history.before_previous(&c.key)).unwrap_or_default();
        }
        Ok(())
    }
}

/// Delivers the impulse grid computed from step `step` of simulation `simulation`, or `None` when
/// it is late (the source owns the deadline) or will never come.
pub trait GridSource {
    /// The grid of `(simulation, step)`, waiting up to the source's deadline.
    fn grid(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Grid>;
}

impl<F> GridSource for F
where
    F: FnMut(u64, u32, u32) -> Option<msgs::Grid>,
{
    fn grid(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Grid> {
        self(run_id, simulation, step)
    }
}

/// Delivers the per-contact warm start a node computed from step `step`'s own problem, or `None`
/// when it is late (the source owns the deadline) or will never come.
pub trait ContactWarmSource {
    fn warm(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Contacts>;
}

/// `grid` / `unet`: the previous step's impulse grid (channels "normal" and "tangent"), sampled
/// bilinearly at the new contact points. `unet-delta` (the U-Net's fair second chance): builtin's
/// own impulse on persisting contacts plus the grid's predicted change there (channels
/// "d_normal", "d_tangent"), the grid's value on new contacts.
pub struct GridModel {
    name: &'static str,
    source: Box<dyn GridSource>,
    delta: bool,
}

impl GridModel {
    /// A grid-based model called `name` fed by `source`.
    pub fn new(name: &'static str, source: Box<dyn GridSource>) -> GridModel {
        GridModel { name, source, delta: false }
    }

    /// Builtin plus the grid's predicted change on persisting contacts.
    pub fn delta(name: &'static str, source: Box<dyn GridSource>) -> GridModel {
        GridModel { name, source, delta: true }
    }
}

impl WarmStartModel for GridModel {
    fn name(&self) -> &str {
        self.name
    }
    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        if input.step == 0 {
            // No previous step exists, hence no grid: zero is the model's own answer here.
            out.fill(Impulse::default());
            return Ok(());
        }
        // Always fetch, even without contacts: in lockstep the producer waits for us to consume.
        let grid = self
            .source
            .grid(input.run_id, input.simulation, input.step - 1)
            .ok_or_else(|| Unavailable(format!("no grid for step {} in time", input.step - 1)))?;
        let (Some(cn), Some(ct)) = (grid.header.channel("normal"), grid.header.channel("tangent")) else {
            return Err(Unavailable("grid lacks a `normal` or `tangent` channel".into()));
        };
        if grid.items.len() < grid.header.len() {
            return Err(Unavailable("grid holds fewer values than its header announces".into()));
        }
        let (normal, tangent) = (grid.channel_data(cn), grid.channel_data(ct));
        let change = match (self.delta, grid.header.channel("d_normal"), grid.header.channel("d_tangent")) {
            (false, _, _) => None,
            (true, Some(dn), Some(dt)) => Some((grid.channel_data(dn), grid.channel_data(dt))),
            (true, _, _) => {
                return Err(Unavailable("grid lacks `d_normal` / `d_tangent` (a temporal U-Net makes them)".into()))
            }
        };
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            let sample = |field: &[f32]| sample_bilinear(&grid.header, field, c.point.x, c.point.y);
            *o = match (change, input.history.previous(&c.key)) {
                (Some((dn, dt)), Some(before)) => {
                    Impulse { normal: before.normal + sample(dn), tangent: before.tangent + sample(dt) }
                }
                _ => Impulse { normal: sample(normal), tangent: sample(tangent) },
            };
        }
        Ok(())
    }
}

/// The warm-start models by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelKind {
    /// Zero.
    None,
    /// Previous step's impulse of the same contact.
    Builtin,
    /// The step's own solution.
    Copy,
    /// The solution rounded to 0 decimals.
    Copy0,
    /// The solution rounded to 2 decimals.
    Copy2,
    /// 50 everywhere.
    Bad,
    /// Uniform noise.
    Random,
    /// Damped extrapolation of the last two steps.
    Extrapolate,
    /// Builtin plus where the previous solve was still going.
    Continue,
    /// Builtin corrected along the previous solve's last sweeps.
    Subspace,
    /// Builtin plus the step's own coarse-grid (piecewise-uniform stress) correction.
    Coarse,
    /// Builtin plus a few CG iterations on the step's own linear problem.
    Cg,
    /// Builtin, reappearing contacts from two steps back.
    BuiltinReappear,
    /// Oracle ablation: exact on persisting contacts.
    CopyPersisting,
    /// Oracle ablation: exact on new contacts.
    CopyNew,
    /// Oracle ablation: the previous step's exact solution.
    CopyPrevious,
    /// Oracle ablation: a fraction of builtin's error removed.
    Blend,
    /// Oracle ablation: the oracle plus noise of builtin's size.
    Noise,
    /// Oracle ablation: the oracle plus the smooth part of builtin's error.
    SmoothError,
    /// Oracle ablation: the oracle plus the rough part of builtin's error.
    RoughError,
    /// The contact-graph network.
    Gnn,
    /// The network's correction as a direction, amplitudes from the step's Galerkin system.
    GnnSubspace,
    /// The contact-graph network over the bus.
    GnnNode,
    /// The exact solution through the value-preserving grid transfer and back.
    CopyGrid,
    /// The exact solution through the thesis's grid transfer and back.
    CopyGridSph,
    /// Impulse grid from the sph node.
    Grid,
    /// Impulse grid predicted by the U-Net.
    Unet,
    /// Builtin plus the U-Net's predicted change on persisting contacts.
    UnetDelta,
}

impl ModelKind {
    /// Every model, in the order of the thesis's table.
    pub const ALL: [ModelKind; 28] = [
        ModelKind::None,
        ModelKind::Builtin,
        ModelKind::Copy,
        ModelKind::Copy0,
        ModelKind::Copy2,
        ModelKind::Bad,
        ModelKind::Random,
        ModelKind::Extrapolate,
        ModelKind::Continue,
        ModelKind::Subspace,
        ModelKind::Coarse,
        ModelKind::Cg,
        ModelKind::BuiltinReappear,
        ModelKind::CopyPersisting,
        ModelKind::CopyNew,
        ModelKind::CopyPrevious,
        ModelKind::Blend,
        ModelKind::Noise,
        ModelKind::SmoothError,
        ModelKind::RoughError,
        ModelKind::Gnn,
        ModelKind::GnnSubspace,
        ModelKind::GnnNode,
        ModelKind::CopyGrid,
        ModelKind::CopyGridSph,
        ModelKind::Grid,
        ModelKind::Unet,
        ModelKind::UnetDelta,
    ];

    /// The model's row in the contract's model table (`msgs::models::MODELS`, same order).
    pub fn info(self) -> &'static msgs::models::ModelInfo {
        &msgs::models::MODELS[self as usize]
    }

    /// The model's name.
    pub fn name(self) -> &'static str {
        self.info().name
    }

    /// Whether the model needs a [`GridSource`].
    pub fn is_grid_based(self) -> bool {
        self.info().is_grid_based()
    }

    /// The topic a grid-based model reads its warm starts from.
    pub fn grid_topic(self) -> Option<msgs::topics::Topic<msgs::GridHeader, f32>> {
        self.info().grid_topic().map(msgs::topics::Topic::new)
    }

    /// The topic another node serves the model on (grids, or `warm/gnn`): it needs the bus.
    pub fn served_on(self) -> Option<&'static str> {
        self.info().served_on
    }

    /// Builds a local model with its default parameter; grid-based ones need
    /// [`ModelKind::build_with_source`].
    pub fn build(self, seed: u64) -> Result<Box<dyn WarmStartModel>, SimError> {
        ModelSpec::of(self).build(seed)
    }

    /// Builds any model with its default parameter; `source` feeds the grid-based ones.
    pub fn build_with_source(
        self,
        seed: u64,
        source: Option<Box<dyn GridSource>>,
    ) -> Result<Box<dyn WarmStartModel>, SimError> {
        ModelSpec::of(self).build_with_source(seed, source)
    }
}

/// The files of the learned models that run in the simulator.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ModelFiles {
    /// The contact-graph network (`gnn`), a `dc-gnn` model file.
    pub gnn: Option<std::path::PathBuf>,
}

/// A model with its parameter: what `--model blend:0.75` names.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelSpec {
    pub kind: ModelKind,
    /// The parameter of a parametrised model (its default when not given), None otherwise.
    pub param: Option<f32>,
}

impl ModelSpec {
    /// The model with its default parameter.
    pub fn of(kind: ModelKind) -> ModelSpec {
        ModelSpec { kind, param: kind.info().param.map(|p| p.default) }
    }

    /// The name in statistics and control messages (`blend:0.75`; unparametrised models' own).
    pub fn name(&self) -> String {
        msgs::models::spec_name(self.kind.info(), self.param)
    }

    pub fn is_grid_based(&self) -> bool {
        self.kind.is_grid_based()
    }

    pub fn grid_topic(&self) -> Option<msgs::topics::Topic<msgs::GridHeader, f32>> {
        self.kind.grid_topic()
    }

    pub fn served_on(&self) -> Option<&'static str> {
        self.kind.served_on()
    }

    /// Builds a local model; grid-based ones need [`ModelSpec::build_with_source`].
    pub fn build(&self, seed: u64) -> Result<Box<dyn WarmStartModel>, SimError> {
        use crate::oracle::{Ablation, OracleAblation};
        let param = self.param.unwrap_or_default();
        let ablation = |a: Ablation| -> Box<dyn WarmStartModel> { Box::new(OracleAblation::new(self.name(), a, seed)) };
        Ok(match self.kind {
            ModelKind::None => Box::new(NoWarmStart),
            ModelKind::Builtin => Box::new(Builtin),
            ModelKind::Copy => Box::new(Copy::exact()),
            ModelKind::Copy0 => Box::new(Copy::rounded(0)),
            ModelKind::Copy2 => Box::new(Copy::rounded(2)),
            ModelKind::Bad => Box::new(Bad),
            ModelKind::Random => Box::new(Random::new(seed)),
            ModelKind::Extrapolate => Box::new(Extrapolate::new(self.name(), param)),
            ModelKind::Continue => Box::new(Continue::new(self.name(), param)),
            ModelKind::Subspace => Box::new(crate::subspace::Subspace::new(self.name(), param.round() as usize)),
            ModelKind::Coarse => Box::new(crate::coarse::Coarse::new(self.name(), param)),
            ModelKind::Cg => Box::new(crate::cg::ConjugateGradient::new(self.name(), param.round() as usize)),
            ModelKind::BuiltinReappear => Box::new(BuiltinReappear),
            ModelKind::CopyPersisting => ablation(Ablation::CopyPersisting),
            ModelKind::CopyNew => ablation(Ablation::CopyNew),
            ModelKind::CopyPrevious => ablation(Ablation::CopyPrevious),
            ModelKind::Blend => ablation(Ablation::Blend(param)),
            ModelKind::Noise => ablation(Ablation::Noise(param)),
            ModelKind::SmoothError => ablation(Ablation::SmoothError),
            ModelKind::RoughError => ablation(Ablation::RoughError),
            ModelKind::Gnn | ModelKind::GnnSubspace => return Err(SimError::NoModelFile(self.name())),
            ModelKind::GnnNode => return Err(SimError::NoGridSource(self.name())),
            ModelKind::CopyGrid => Box::new(CopyGrid::new(sph::Mode::Preserving)),
            ModelKind::CopyGridSph => Box::new(CopyGrid::new(sph::Mode::Sph)),
            ModelKind::Grid | ModelKind::Unet | ModelKind::UnetDelta => {
                return Err(SimError::NoGridSource(self.name()))
            }
        })
    }

    /// Builds any model; `source` feeds the grid-based ones and is ignored by the others.
    pub fn build_with_source(
        &self,
        seed: u64,
        source: Option<Box<dyn GridSource>>,
    ) -> Result<Box<dyn WarmStartModel>, SimError> {
        match (self.is_grid_based(), source) {
            (true, Some(s)) if self.kind == ModelKind::UnetDelta => Ok(Box::new(GridModel::delta(self.kind.name(), s))),
            (true, Some(s)) => Ok(Box::new(GridModel::new(self.kind.name(), s))),
            _ => self.build(seed),
        }
    }

    /// Builds any model, the learned ones from their files in `files`.
    pub fn build_with(
        &self,
        seed: u64,
        source: Option<Box<dyn GridSource>>,
        files: &ModelFiles,
    ) -> Result<Box<dyn WarmStartModel>, SimError> {
        match (self.kind, &files.gnn) {
            (ModelKind::Gnn, Some(path)) => {
                let file = gnn::ModelFile::load(path).map_err(|e| SimError::ModelFile(e.to_string()))?;
                Ok(Box::new(crate::learned::GnnModel::new(file.net)))
            }
            (ModelKind::GnnSubspace, Some(path)) => {
                let file = gnn::ModelFile::load(path).map_err(|e| SimError::ModelFile(e.to_string()))?;
                let network = Box::new(crate::learned::GnnModel::new(file.net));
                let trail = self.param.unwrap_or_default().round() as usize;
                Ok(Box::new(crate::subspace::Subspace::with_direction(self.name(), trail, network)))
            }
            _ => self.build_with_source(seed, source),
        }
    }
}

impl FromStr for ModelSpec {
    type Err = SimError;
    fn from_str(s: &str) -> Result<Self, SimError> {
        let (info, param) = msgs::models::parse(s).map_err(SimError::BadModel)?;
        let kind = ModelKind::ALL.into_iter().find(|k| k.name() == info.name).expect("the table and the enum agree");
        Ok(ModelSpec { kind, param })
    }
}

// The enum mirrors the contract's table, row for row (checked in the tests too).
const _: () = assert!(ModelKind::ALL.len() == msgs::models::MODELS.len());

impl FromStr for ModelKind {
    type Err = SimError;
    fn from_str(s: &str) -> Result<Self, SimError> {
        ModelKind::ALL.into_iter().find(|m| m.name() == s).ok_or_else(|| SimError::UnknownModel(s.to_string()))
    }
}

/// A model and the model that stands in when it is unavailable, with the fallback count.
pub struct WarmStarter {
    /// The model asked for.
    pub model: Box<dyn WarmStartModel>,
    /// The stand-in (a local model, never unavailable in practice).
    pub fallback: Box<dyn WarmStartModel>,
    fallbacks_total: u32,
}

impl WarmStarter {
    /// `model`, falling back to `fallback`.
    pub fn new(model: Box<dyn WarmStartModel>, fallback: Box<dyn WarmStartModel>) -> WarmStarter {
        WarmStarter { model, fallback, fallbacks_total: 0 }
    }

    /// Builds a local model by name with `builtin` as its fallback.
    pub fn local(kind: ModelKind, seed: u64) -> Result<WarmStarter, SimError> {
        Ok(WarmStarter::new(kind.build(seed)?, ModelKind::Builtin.build(seed)?))
    }

    /// Resets per-simulation state (models and the fallback count).
    pub fn begin_simulation(&mut self, simulation: u32, seed: u64) {
        self.fallbacks_total = 0;
        self.model.begin_simulation(simulation, seed);
        self.fallback.begin_simulation(simulation, seed);
    }

    /// Whether the model or its fallback reads the step's problem ([`WarmStartInput::problem`]).
    pub fn wants_problem(&self) -> bool {
        self.model.wants_problem() || self.fallback.wants_problem()
    }

    /// Fallbacks in this simulation so far.
    pub fn fallbacks_total(&self) -> u32 {
        self.fallbacks_total
    }

    /// Runs the model, or the fallback when it is unavailable; returns whether it fell back.
    pub fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> bool {
        out.fill(Impulse::default());
        match self.model.warm_start(input, out) {
            Ok(()) => false,
            Err(Unavailable(why)) => {
                tracing::debug!(model = self.model.name(), step = input.step, "fallback: {why}");
                self.fallbacks_total += 1;
                out.fill(Impulse::default());
                if let Err(Unavailable(why)) = self.fallback.warm_start(input, out) {
                    // A fallback that fails too leaves the zero guess: still a valid start.
                    tracing::warn!(model = self.fallback.name(), "fallback unavailable too: {why}");
                    out.fill(Impulse::default());
                }
                true
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::contact::ContactKey;

    fn point(body_b: u32) -> ContactPoint {
        floor_contact(body_b, 0, 0.0)
    }

    /// Runs `model` on `contacts` after two steps of history.
    fn guess(model: &mut dyn WarmStartModel, contacts: &[ContactPoint], history: &ImpulseHistory) -> Vec<Impulse> {
        guess_with_oracle(model, contacts, history, &[])
    }

    /// Runs `model` on `contacts` (step 2, body 0 fixed); the oracle answers `exact`.
    pub(crate) fn guess_with_oracle(
        model: &mut dyn WarmStartModel,
        contacts: &[ContactPoint],
        history: &ImpulseHistory,
        exact: &[Impulse],
    ) -> Vec<Impulse> {
        run_step(model, contacts, history, exact, &[], &[], 0.0)
    }

    /// Runs `model` on `contacts` with the solver's `rows` and `bodies` and its `compliance`
    /// (step 2, body 0 fixed, no oracle): the models that solve the step's own problem.
    pub(crate) fn guess_on_rows(
        model: &mut dyn WarmStartModel,
        contacts: &[ContactPoint],
        history: &ImpulseHistory,
        rows: &[crate::solver::ContactRow],
        bodies: &[crate::solver::SolverBody],
        compliance: f32,
    ) -> Vec<Impulse> {
        run_step(model, contacts, history, &[], rows, bodies, compliance)
    }

    /// The contact of ball `body_b` on the floor (body 0) at `x`, feature `feature`.
    pub(crate) fn floor_contact(body_b: u32, feature: u32, x: f32) -> ContactPoint {
        ContactPoint {
            key: ContactKey { body_a: 0, body_b, feature },
            point: rapier2d::math::Vec2::new(x, 0.0),
            normal: rapier2d::math::Vec2::Y,
            penetration: 0.0,
            friction: 0.5,
        }
    }

    fn run_step(
        model: &mut dyn WarmStartModel,
        contacts: &[ContactPoint],
        history: &ImpulseHistory,
        exact: &[Impulse],
        rows: &[crate::solver::ContactRow],
        bodies: &[crate::solver::SolverBody],
        compliance: f32,
    ) -> Vec<Impulse> {
        let mut oracle = |out: &mut [Impulse]| {
            if !exact.is_empty() {
                out.copy_from_slice(exact)
            }
        };
        let mut input = WarmStartInput {
            run_id: 0,
            simulation: 0,
            step: 2,
            contacts,
            history,
            fixed: &[true, false, false, false],
            problem: None,
            rows,
            bodies,
            compliance,
            oracle: &mut oracle,
        };
        let mut out = vec![Impulse::default(); contacts.len()];
        model.warm_start(&mut input, &mut out).unwrap();
        out
    }

    #[test]
    fn reappearing_contacts_and_damped_extrapolation() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let mut history = ImpulseHistory::default();
        // Two steps ago: contacts 1 and 2; last step: contacts 1 and 3 (2 flickered off).
        history.push(
            [point(1).key, point(2).key].into_iter(),
            &[imp(1.0, 0.1), imp(2.0, 0.2)],
            ImpulseHistory::no_trail(),
        );
        history.push(
            [point(1).key, point(3).key].into_iter(),
            &[imp(1.5, 0.2), imp(3.0, 0.3)],
            ImpulseHistory::no_trail(),
        );
        let contacts = [point(1), point(2), point(3)];
        assert_eq!(guess(&mut Builtin, &contacts, &history), [imp(1.5, 0.2), imp(0.0, 0.0), imp(3.0, 0.3)]);
        assert_eq!(guess(&mut BuiltinReappear, &contacts, &history), [imp(1.5, 0.2), imp(2.0, 0.2), imp(3.0, 0.3)]);
        // l1 + beta (l1 - l2) on the contact with two steps of history, l1 on the one with one.
        let mut half = Extrapolate::new("extrapolate:0.5".into(), 0.5);
        let g = guess(&mut half, &contacts, &history);
        assert_eq!((g[0].normal, g[1], g[2]), (1.75, imp(0.0, 0.0), imp(3.0, 0.3)));
        assert!((g[0].tangent - 0.25).abs() < 1e-6);
    }

    #[test]
    fn continue_follows_the_last_sweep_by_the_geometric_series() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let mut history = ImpulseHistory::default();
        let zero = imp(0.0, 0.0);
        let changes = [[imp(0.01, -0.002), zero, zero, zero], [imp(-0.5, 0.0), zero, zero, zero]];
        let trail = crate::contact::SolveTrail { changes: &changes, rate: 0.9 };
        history.push([point(1).key, point(2).key].into_iter(), &[imp(1.0, 0.1), imp(0.2, 0.0)], trail);
        let contacts = [point(1), point(2), point(3)];
        // rate 0.9: the rest of the way is 9 times the last change; gain 0.5 takes half of it.
        assert!((Continue::factor(0.5, 0.9) - 4.5).abs() < 1e-5);
        let g = guess(&mut Continue::new("continue:0.5".into(), 0.5), &contacts, &history);
        assert!((g[0].normal - 1.045).abs() < 1e-6 && (g[0].tangent - 0.091).abs() < 1e-6, "{g:?}");
        assert_eq!(g[1], imp(0.0, 0.0), "a negative normal is projected to 0 (and its tangent with it)");
        assert_eq!(g[2], imp(0.0, 0.0), "a new contact starts at 0");
        // A solve at its cap converges at a rate near 1: the factor stays bounded.
        assert!(Continue::factor(1.0, 1.0).is_finite() && Continue::factor(1.0, 1.0) <= 200.0);
        assert_eq!(Continue::factor(1.0, 0.0), 0.0);
    }

    #[test]
    fn unet_delta_adds_the_predicted_change_to_builtin_on_persisting_contacts_only() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let mut history = ImpulseHistory::default();
        history.push([point(1).key].into_iter(), &[imp(1.0, 0.1)], ImpulseHistory::no_trail());
        // A uniform grid: value (2, 0.2), change (0.5, -0.05), over the contacts at the origin.
        let source = |_: u64, _: u32, step: u32| {
            let mut g = msgs::Grid::zeros(
                msgs::StepHeader { run_id: 0, simulation: 0, step },
                [-1.0, -1.0],
                1.0,
                3,
                3,
                &["normal", "tangent", "d_normal", "d_tangent"],
            );
            for (c, v) in [2.0, 0.2, 0.5, -0.05].into_iter().enumerate() {
                g.items[c * 9..(c + 1) * 9].fill(v);
            }
            Some(g)
        };
        let contacts = [point(1), point(2)];
        let mut delta = GridModel::delta("unet-delta", Box::new(source));
        let g = guess(&mut delta, &contacts, &history);
        assert!((g[0].normal - 1.5).abs() < 1e-6 && (g[0].tangent - 0.05).abs() < 1e-6, "builtin + change: {g:?}");
        assert!((g[1].normal - 2.0).abs() < 1e-6 && (g[1].tangent - 0.2).abs() < 1e-6, "a new contact: the value");
        // The plain model overwrites every contact with the grid's value.
        let g = guess(&mut GridModel::new("unet", Box::new(source)), &contacts, &history);
        assert!((g[0].normal - 2.0).abs() < 1e-6, "{g:?}");
    }

    #[test]
    fn model_kinds_mirror_the_contract_table() {
        for (i, kind) in ModelKind::ALL.into_iter().enumerate() {
            assert_eq!(kind as usize, i);
            assert_eq!(kind.name(), msgs::models::MODELS[i].name);
            assert_eq!(kind.name().parse::<ModelKind>().unwrap(), kind);
        }
        assert_eq!(ModelKind::Unet.grid_topic().unwrap().name, msgs::topics::GRID_UNET.name);
        assert!(ModelKind::Builtin.grid_topic().is_none());
        let err = "nope".parse::<ModelKind>().unwrap_err().to_string();
        assert!(err.contains("copy-grid-sph"), "{err}");
        let spec: ModelSpec = "blend:0.75".parse().unwrap();
        assert_eq!((spec.kind, spec.param, spec.name()), (ModelKind::Blend, Some(0.75), "blend:0.75".to_string()));
        assert_eq!(spec.build(0).unwrap().name(), "blend:0.75");
        assert_eq!("extrapolate".parse::<ModelSpec>().unwrap().name(), "extrapolate:1");
        assert!("blend:2".parse::<ModelSpec>().is_err());
    }
}
