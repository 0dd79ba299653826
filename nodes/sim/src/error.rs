//! Errors of the simulator library.

/// Everything that can go wrong when configuring or building a simulation.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SimError {
    /// A scene name that none of the scenes answers to.
    #[error("unknown scene `{0}` (known: ball-box, drum, mixed)")]
    UnknownScene(String),
    /// A warm-start model name that none of the models answers to.
    #[error("unknown warm-start model `{0}` (known: {known})", known = msgs::models::names_list())]
    UnknownModel(String),
    /// A model name or parameter that does not parse (`blend:2`, `builtin:1`).
    #[error("{0}")]
    BadModel(String),
    /// A sampler name that none of the samplers answers to.
    #[error("unknown sampler `{0}` (known: native, numpy)")]
    UnknownSampler(String),
    /// A parameter outside its valid range.
    #[error("invalid parameter `{name}` = {value}: {why}")]
    InvalidParameter {
        /// The parameter's name as the user spells it.
        name: &'static str,
        /// The value given, as text.
        value: String,
        /// What the valid range is.
        why: String,
    },
    /// The bodies do not fit: more bodies than the box can hold, or rejection sampling gave up.
    #[error("scene too dense: {0}")]
    SceneTooDense(String),
    /// A model that another node serves was asked for without the bus to reach it.
    #[error("model `{0}` needs a grid source or warm starts from another node (run it inside a graph with its sph, unet or gnn node)")]
    NoGridSource(String),
    /// A learned model was asked for without its file.
    #[error("model `{0}` needs its model file (dc-sim --gnn-model FILE)")]
    NoModelFile(String),
    /// A learned model's file could not be used.
    #[error("{0}")]
    ModelFile(String),
    /// Where a run's messages go (the bus, a recording) failed.
    #[error("run output: {0}")]
    Output(String),
}
