//! The registry: every warm-start model by name ([`ModelKind`], mirroring the contract's table
//! `msgs::models::MODELS` row for row), with its parameter ([`ModelSpec`], what `--model
//! blend:0.75` names), and the one place that builds a model from its spec, grouped as the
//! rooms are: product, references, probes.

use crate::error::SimError;
use crate::solver::rows::Impulse;
use crate::warm::model::{ContactWarmSource, GridSource, WarmStartModel, WarmStarter};
use crate::warm::probes::{BuiltinReappear, Coarse, ConjugateGradient, Continue, Extrapolate, Subspace};
use crate::warm::product::{
    Builtin, Constant, GnnEveryModel, GnnModel, GnnNodeModel, GnnPipelinedModel, GridModel, ProblemSender,
};
use crate::warm::references::{Ablation, Copy, OracleAblation, Random};
use msgs::models::ModelGroup;
use std::str::FromStr;

/// What the bus delivers to the models another node serves.
#[derive(Default)]
pub struct Served {
    /// The grids of the grid-based models (`grid`, `unet`, `unet-delta`).
    pub grid: Option<Box<dyn GridSource>>,
    /// `gnn-node`: the step's problem goes out through the sender, the warm start comes back.
    pub contact: Option<(ProblemSender, Box<dyn ContactWarmSource>)>,
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
    /// The network every N-th step, its correction carried on in between.
    GnnEvery,
    /// The network's correction as a direction, amplitudes from the step's Galerkin system.
    GnnSubspace,
    /// The contact-graph network over the bus.
    GnnNode,
    /// The contact-graph network over the bus, one step ahead.
    GnnPipelined,
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
    /// A user's own model served by any process of the graph (`external:NAME`).
    External,
}

impl ModelKind {
    /// Every model, in the order of the thesis's table.
    pub const ALL: [ModelKind; 31] = [
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
        ModelKind::GnnEvery,
        ModelKind::GnnSubspace,
        ModelKind::GnnNode,
        ModelKind::GnnPipelined,
        ModelKind::CopyGrid,
        ModelKind::CopyGridSph,
        ModelKind::Grid,
        ModelKind::Unet,
        ModelKind::UnetDelta,
        ModelKind::External,
    ];

    /// The model's row in the contract's model table (`msgs::models::MODELS`, same order).
    pub fn info(self) -> &'static msgs::models::ModelInfo {
        &msgs::models::MODELS[self as usize]
    }

    /// The model's name.
    pub fn name(self) -> &'static str {
        self.info().name
    }

    /// Whether the model sends problems to a `dc-gnn` node and reads its answers
    /// ([`Served::contact`]).
    pub fn sends_problems(self) -> bool {
        self.warm_topic().is_some()
    }

    /// The topic the warm starts of a model that sends problems come back on.
    pub fn warm_topic(self) -> Option<msgs::topics::Topic<msgs::StepHeader, msgs::Contact>> {
        match self {
            ModelKind::GnnNode | ModelKind::GnnPipelined => Some(msgs::topics::WARM_GNN),
            ModelKind::External => Some(msgs::topics::WARM_EXTERNAL),
            _ => None,
        }
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

    /// Which room the model belongs to.
    pub fn group(self) -> ModelGroup {
        self.info().group
    }

    /// Builds a model computed in the simulator with its default parameter; grid-based ones
    /// need [`ModelKind::build_with_source`].
    pub fn build(self, seed: u64) -> Result<Box<dyn WarmStartModel>, SimError> {
        ModelSpec::of(self).build(seed)
    }

    /// The model computed in the simulator with its default parameter, `builtin` standing in
    /// when it is unavailable.
    pub fn starter(self, seed: u64) -> Result<WarmStarter, SimError> {
        Ok(WarmStarter::new(self.build(seed)?, ModelKind::Builtin.build(seed)?))
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
    /// The user's name of an external model (`external:NAME`), None otherwise.
    pub label: Option<msgs::Name16>,
}

impl ModelSpec {
    /// The model with its default parameter.
    pub fn of(kind: ModelKind) -> ModelSpec {
        ModelSpec { kind, param: kind.info().param.map(|p| p.default), label: None }
    }

    /// The name in statistics and control messages (`blend:0.75`; unparametrised models' own).
    pub fn name(&self) -> String {
        match &self.label {
            Some(label) => msgs::name16_str(label).to_string(),
            None => msgs::models::spec_name(self.kind.info(), self.param),
        }
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

    /// Builds a model computed in the simulator; models another node serves need
    /// [`ModelSpec::build_with`].
    pub fn build(&self, seed: u64) -> Result<Box<dyn WarmStartModel>, SimError> {
        self.build_with(seed, Served::default(), &ModelFiles::default())
    }

    /// Builds any model; `source` feeds the grid-based ones and is ignored by the others.
    pub fn build_with_source(
        &self,
        seed: u64,
        source: Option<Box<dyn GridSource>>,
    ) -> Result<Box<dyn WarmStartModel>, SimError> {
        self.build_with(seed, Served { grid: source, contact: None }, &ModelFiles::default())
    }

    /// Builds any model: the served ones from `served`, the learned ones from their files.
    pub fn build_with(
        &self,
        seed: u64,
        served: Served,
        files: &ModelFiles,
    ) -> Result<Box<dyn WarmStartModel>, SimError> {
        let param = self.param.unwrap_or_default();
        let ablation = |a: Ablation| -> Box<dyn WarmStartModel> { Box::new(OracleAblation::new(self.name(), a, seed)) };
        let net = || -> Result<gnn::net::Net, SimError> {
            let path = files.gnn.as_ref().ok_or_else(|| SimError::NoModelFile(self.name()))?;
            Ok(gnn::ModelFile::load(path).map_err(|e| SimError::ModelFile(e.to_string()))?.net)
        };
        let network = || -> Result<Box<dyn WarmStartModel>, SimError> { Ok(Box::new(GnnModel::new(net()?))) };
        let no_source = || SimError::NoGridSource(self.name());
        Ok(match self.kind {
            // Product.
            ModelKind::None => Box::new(Constant::zero()),
            ModelKind::Builtin => Box::new(Builtin),
            ModelKind::Grid | ModelKind::Unet => {
                Box::new(GridModel::new(self.kind.name(), served.grid.ok_or_else(no_source)?))
            }
            ModelKind::UnetDelta => Box::new(GridModel::delta(self.kind.name(), served.grid.ok_or_else(no_source)?)),
            ModelKind::Gnn => network()?,
            ModelKind::GnnEvery => Box::new(GnnEveryModel::new(self.name(), net()?, param.round() as u32)),
            ModelKind::GnnNode => {
                let (send, source) = served.contact.ok_or_else(no_source)?;
                Box::new(GnnNodeModel::new(send, source))
            }
            ModelKind::External => {
                let (send, source) = served.contact.ok_or_else(no_source)?;
                Box::new(GnnNodeModel::named(self.name(), send, source))
            }
            ModelKind::GnnPipelined => {
                let (send, source) = served.contact.ok_or_else(no_source)?;
                Box::new(GnnPipelinedModel::new(send, source))
            }
            // References.
            ModelKind::Copy => Box::new(Copy::exact()),
            ModelKind::Copy0 => Box::new(Copy::rounded_to_units()),
            ModelKind::Copy2 => Box::new(Copy::rounded_to_hundredths()),
            ModelKind::CopyGrid => Box::new(Copy::through_grid(sph::Mode::Preserving)),
            ModelKind::CopyGridSph => Box::new(Copy::through_grid(sph::Mode::Sph)),
            ModelKind::Bad => Box::new(Constant::new("bad", Impulse { normal: 50.0, tangent: 50.0 })),
            ModelKind::Random => Box::new(Random::new(seed)),
            ModelKind::CopyPersisting => ablation(Ablation::CopyPersisting),
            ModelKind::CopyNew => ablation(Ablation::CopyNew),
            ModelKind::CopyPrevious => ablation(Ablation::CopyPrevious),
            ModelKind::Blend => ablation(Ablation::Blend(param)),
            ModelKind::Noise => ablation(Ablation::Noise(param)),
            ModelKind::SmoothError => ablation(Ablation::SmoothError),
            ModelKind::RoughError => ablation(Ablation::RoughError),
            // Probes.
            ModelKind::Extrapolate => Box::new(Extrapolate::new(self.name(), param)),
            ModelKind::Continue => Box::new(Continue::new(self.name(), param)),
            ModelKind::BuiltinReappear => Box::new(BuiltinReappear),
            ModelKind::Subspace => Box::new(Subspace::new(self.name(), param.round() as usize)),
            ModelKind::Coarse => Box::new(Coarse::new(self.name(), param)),
            ModelKind::Cg => Box::new(ConjugateGradient::new(self.name(), param.round() as usize)),
            ModelKind::GnnSubspace => {
                Box::new(Subspace::with_direction(self.name(), param.round() as usize, network()?))
            }
        })
    }
}

impl FromStr for ModelSpec {
    type Err = SimError;
    fn from_str(s: &str) -> Result<Self, SimError> {
        let (info, param) = msgs::models::parse(s).map_err(SimError::BadModel)?;
        let kind = ModelKind::ALL.into_iter().find(|k| k.name() == info.name).expect("the table and the enum agree");
        let label = msgs::models::external_name(s).map(msgs::name16);
        Ok(ModelSpec { kind, param, label })
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

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn no_product_or_probe_model_reads_the_oracle() {
        for kind in ModelKind::ALL {
            // The served and file-backed models cannot be built here; they read no oracle either.
            let Ok(model) = kind.build(0) else { continue };
            let reads_oracle = model.needs().exact;
            if kind.group() != ModelGroup::Reference {
                assert!(!reads_oracle, "{} is {:?} but reads the exact solution", kind.name(), kind.group());
            }
            if kind.name().starts_with("copy") || matches!(kind, ModelKind::Blend | ModelKind::Noise) {
                assert!(reads_oracle, "{} is built from the oracle", kind.name());
            }
        }
    }

    #[test]
    fn served_models_are_built_from_what_the_bus_delivers() {
        use crate::warm::model::ContactWarmSource;
        struct Silent;
        impl ContactWarmSource for Silent {
            fn warm(&mut self, _: u64, _: u32, _: u32) -> Option<msgs::Contacts> {
                None
            }
        }
        let gnn_node = ModelSpec::of(ModelKind::GnnNode);
        let err = gnn_node.build(0).err().expect("gnn-node needs the bus").to_string();
        assert!(err.contains("gnn-node"), "{err}");
        let served =
            Served { grid: None, contact: Some((Box::new(|_: &crate::problem::Problem| Ok(())), Box::new(Silent))) };
        let model = gnn_node.build_with(0, served, &ModelFiles::default()).unwrap();
        assert_eq!(model.name(), "gnn-node");
        assert!(model.needs().problem);
        let err = ModelSpec::of(ModelKind::Gnn).build(0).err().expect("gnn needs its file").to_string();
        assert!(err.contains("gnn"), "{err}");
        let unet =
            ModelSpec::of(ModelKind::UnetDelta).build_with_source(0, Some(Box::new(|_: u64, _: u32, _: u32| None)));
        assert_eq!(unet.unwrap().name(), "unet-delta");
    }
}
