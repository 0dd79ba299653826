//! The U-Net warm-start model of Deep Contact (THESIS.md, "U-Net"), in burn: the network, the
//! dataset made on the fly from MCAP recordings with the SPH library, training (Adam / SGD,
//! cyclical and cosine-restart schedules, the learning-rate finder, checkpoints), one-file models
//! and inference. The `dc-unet` binary is the inference node plus `train`, `lr-find`, `info`
//! and `bench`.
//!
//! Backends are chosen at run time by [`device`]: `flex` (pure Rust CPU, the default build) or,
//! with the `tch` feature, libtorch on CPU or CUDA.

pub mod data;
pub mod infer;
pub mod model;
pub mod modelfile;
pub mod schedule;
pub mod train;

pub use data::{GridSpec, Normalization, Part, Sample, SampleStream, Split};
pub use infer::Predictor;
pub use model::{UNet, UNetConfig};
pub use modelfile::{ModelFile, ModelMeta};

use burn::tensor::Device;

/// Errors of the U-Net crate; each names the file, grid or option at fault.
#[derive(Debug, thiserror::Error)]
pub enum UnetError {
    #[error("{0}: {1}")]
    Io(String, #[source] std::io::Error),
    /// A model file that cannot be used.
    #[error("model file {0}: {1}")]
    Model(String, String),
    #[error("configuration: {0}")]
    Config(String),
    #[error("training data: {0}")]
    Data(String),
    /// A grid that does not fit the model.
    #[error("input grid: {0}")]
    Input(String),
    #[error("recording: {0}")]
    Recording(#[from] recorder::Error),
    #[error("training diverged at epoch {epoch}, step {step} (learning rate {lr:.3e}): the loss is not finite; lower the rate")]
    Diverged { epoch: usize, step: usize, lr: f64 },
}

pub type Result<T, E = UnetError> = std::result::Result<T, E>;

/// Backends this build can run on, by name.
pub fn backends() -> &'static [&'static str] {
    if cfg!(feature = "tch") {
        &["flex", "libtorch", "cuda"]
    } else {
        &["flex"]
    }
}

/// Most CUDA devices a `cuda:N` may name (`N` below it).
pub const MAX_CUDA_DEVICES: usize = 64;

/// `name` if [`device`] can make a device of it in this build, without making it: the
/// `--device` flags' parser, so that a wrong device is refused when the parameters are checked
/// (a launch file's check too), not when the node starts. `libtorch`, `cuda` and `cuda:N` need
/// the `tch` feature; a build without it says so.
pub fn device_name(name: &str) -> std::result::Result<String, String> {
    let cuda_index = name.strip_prefix("cuda:");
    if !matches!(name, "flex" | "cpu" | "libtorch" | "tch" | "cuda") && cuda_index.is_none() {
        return Err(format!(
            "unknown device `{name}`; this build has {:?}{}",
            backends(),
            if cfg!(feature = "tch") {
                ""
            } else {
                " (libtorch and cuda need `--features tch`, see scripts/libtorch.sh)"
            }
        ));
    }
    if !matches!(name, "flex" | "cpu") && !cfg!(feature = "tch") {
        return Err(format!(
            "device `{name}` needs the libtorch backend, which this build lacks (it has only flex): \
             build with `--features tch`, see scripts/libtorch.sh"
        ));
    }
    if let Some(index) = cuda_index {
        match index.parse::<usize>() {
            Ok(i) if i < MAX_CUDA_DEVICES => {}
            _ => {
                return Err(format!("device `{name}`: `cuda:N` with N a GPU index from 0 to {}", MAX_CUDA_DEVICES - 1))
            }
        }
    }
    Ok(name.to_string())
}

/// The device called `name`: `flex` (pure-Rust CPU); with the `tch` feature also `libtorch`
/// (libtorch CPU) and `cuda` / `cuda:N` (libtorch CUDA). Names are checked by [`device_name`].
// burn 0.22 marks burn-tch deprecated in favour of CubeCL backends; libtorch is the GPU route
// this project chose, and it still builds and runs here.
#[allow(deprecated)]
pub fn device(name: &str) -> Result<Device> {
    device_name(name).map_err(UnetError::Config)?;
    match name {
        "flex" | "cpu" => Ok(Device::flex()),
        #[cfg(feature = "tch")]
        "libtorch" | "tch" => Ok(Device::libtorch()),
        #[cfg(feature = "tch")]
        n if n == "cuda" || n.starts_with("cuda:") => {
            let index = n
                .strip_prefix("cuda:")
                .map(|i| i.parse::<usize>())
                .transpose()
                .map_err(|e| UnetError::Config(format!("device `{n}`: {e}")))?;
            Ok(Device::libtorch_cuda(index.unwrap_or(0)))
        }
        other => Err(UnetError::Config(format!(
            "unknown device `{other}`; this build has {:?}{}",
            backends(),
            if cfg!(feature = "tch") { "" } else { " (libtorch needs `--features tch`, see scripts/libtorch.sh)" }
        ))),
    }
}
