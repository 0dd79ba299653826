//! One model file holds everything inference needs: the network's shape, its weights, the
//! normalisation, the grid parameters and a training summary.
//!
//! Layout: `DCUNET` magic + format version (8 bytes), little-endian u64 length + JSON metadata,
//! little-endian u64 length + burnpack weights (burn's own tensor format), and (format 2) the
//! FNV-1a 64 checksum of the metadata and weight bytes. A file whose checksum does not match, or
//! whose weights are not all finite, is refused. Format 1 files (no checksum) are refused by
//! [`ModelFile::load`]; [`ModelFile::upgrade`] (`dc-unet upgrade`) rewrites one as format 2 after
//! checking that its weights fit its configuration and are finite.

use crate::data::{GridSpec, Normalization, Split};
use crate::model::{UNet, UNetConfig};
use crate::{Result, UnetError};
use burn::module::Module;
use burn::store::ModuleRecord;
use burn::tensor::{Bytes, Device};
use serde::{Deserialize, Serialize};
use std::path::Path;

const MAGIC: &[u8; 6] = b"DCUNET";
/// Largest grid side a model file may name (the thesis's grids have 128).
const MAX_GRID_SIDE: usize = 4096;
const FORMAT_VERSION: u16 = 2;
/// The oldest format this build reads (1: no checksum).
const OLDEST_FORMAT: u16 = 1;

/// FNV-1a 64 of `parts`, in order.
fn checksum(parts: &[&[u8]]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for byte in parts.iter().flat_map(|p| p.iter()) {
        h ^= *byte as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// Counts the non-finite values of every float parameter of a module.
struct NonFinite {
    values: u64,
}

impl burn::module::ModuleVisitor for NonFinite {
    fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<burn::tensor::Tensor<D>>) {
        let bad: i64 = param.val().is_finite().bool_not().int().sum().into_scalar();
        self.values += bad.max(0) as u64;
    }
}

/// What a model file says about itself besides the weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelMeta {
    pub config: UNetConfig,
    pub grid: GridSpec,
    pub normalization: Normalization,
    /// Input channel names, in order (checked against received grids).
    pub input_channels: Vec<String>,
    /// Output channel names (`normal`, `tangent`).
    pub output_channels: Vec<String>,
    /// Grid size the model was trained on: `[height, width]`.
    pub grid_shape: [usize; 2],
    #[serde(default)]
    pub training: TrainingSummary,
}

/// How the model came to be.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TrainingSummary {
    pub data: String,
    /// Recordings left out because they did not read intact (`--skip-bad`), with why.
    #[serde(default)]
    pub skipped_files: Vec<String>,
    pub epochs: usize,
    pub train_samples: usize,
    pub validation_samples: usize,
    /// Mean training loss per epoch (normalised MSE).
    pub train_loss: Vec<f64>,
    /// Validation loss per epoch.
    pub validation_loss: Vec<f64>,
    /// Validation loss of the untrained model's answer "the previous impulses" (residual models;
    /// with `--loss unrolled`, builtin's warm start: 0 on new contacts), the bar to beat.
    pub validation_loss_previous: Option<f64>,
    pub split: Split,
    pub seconds: f64,
    pub command: String,
}

/// A model with its metadata.
#[derive(Debug)]
pub struct ModelFile {
    pub meta: ModelMeta,
    pub model: UNet,
}

impl ModelFile {
    /// Writes the model to `path` (atomically: a temporary file renamed over it).
    pub fn save(meta: &ModelMeta, model: &UNet, path: &Path) -> Result<()> {
        let json = serde_json::to_vec(meta).map_err(|e| UnetError::Model(path.display().to_string(), e.to_string()))?;
        let weights = model
            .clone()
            .into_record()
            .into_bytes()
            .map_err(|e| UnetError::Model(path.display().to_string(), format!("serialising weights: {e:?}")))?;
        write(path, &json, &weights)
    }

    /// Reads a model file onto `device`. A file that is not a model, is cut short, or whose weights
    /// do not fit its configuration is an error naming the file.
    /// A format-1 file (no checksum) is refused: nothing would catch a damaged one.
    pub fn load(path: &Path, device: &Device) -> Result<ModelFile> {
        Self::read(path, device, false)
    }

    /// Rewrites the model at `path` as a current-format file at `out` (which may be `path`): a
    /// format-1 file is accepted here once its weights load into its configuration and are finite,
    /// which is all a file without a checksum can be checked for.
    /// The metadata and weight bytes are kept as they were.
    pub fn upgrade(path: &Path, out: &Path, device: &Device) -> Result<ModelFile> {
        let bytes = read_file(path)?;
        let model = |what| UnetError::Model(path.display().to_string(), what);
        let file = Self::from_bytes(&bytes, device, true).map_err(model)?;
        let (json, weights) = sections(&bytes).map_err(model)?;
        write(out, json, weights)?;
        Ok(file)
    }

    fn read(path: &Path, device: &Device, accept_unchecked: bool) -> Result<ModelFile> {
        let bytes = read_file(path)?;
        Self::from_bytes(&bytes, device, accept_unchecked)
            .map_err(|what| UnetError::Model(path.display().to_string(), what))
    }

    /// Only the metadata (no weights are built).
    pub fn read_meta(path: &Path) -> Result<ModelMeta> {
        let bytes = read_file(path)?;
        parse(&bytes, false).map(|(m, _)| m).map_err(|what| UnetError::Model(path.display().to_string(), what))
    }

    fn from_bytes(bytes: &[u8], device: &Device, accept_unchecked: bool) -> std::result::Result<ModelFile, String> {
        let (meta, weights) = parse(bytes, accept_unchecked)?;
        let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(weights.to_vec()))
            .map_err(|e| format!("weights are not a valid burnpack: {e:?}"))?;
        let model = meta
            .config
            .init(device)
            .try_load_record(record)
            .map_err(|e| format!("weights do not fit the configuration {:?}: {e:?}", meta.config))?;
        let mut non_finite = NonFinite { values: 0 };
        model.visit(&mut non_finite);
        if non_finite.values > 0 {
            return Err(format!("{} weights are not finite (NaN or infinite): refusing the model", non_finite.values));
        }
        Ok(ModelFile { meta, model })
    }
}

/// The bytes of the model file `path`: only a regular file of at most
/// [`runtime::files::MAX_MODEL_BYTES`] is read (`/dev/zero`, a FIFO or a folder is refused by its
/// kind, an oversized file by its size, before reading).
fn read_file(path: &Path) -> Result<Vec<u8>> {
    runtime::files::read_bounded(path, "model file", runtime::files::MAX_MODEL_BYTES)
        .map_err(|e| UnetError::Io(path.display().to_string(), e.into()))
}

/// Writes a current-format file of `json` metadata and `weights` at `path`, atomically.
fn write(path: &Path, json: &[u8], weights: &[u8]) -> Result<()> {
    let mut out = Vec::with_capacity(32 + json.len() + weights.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(json);
    out.extend_from_slice(&(weights.len() as u64).to_le_bytes());
    out.extend_from_slice(weights);
    out.extend_from_slice(&checksum(&[json, weights]).to_le_bytes());
    runtime::files::replace_file(path, &out).map_err(|e| UnetError::Io(path.display().to_string(), e))
}

/// The metadata and weight bytes of a model file of any format this build reads, the
/// checksum verified where the format has one.
fn sections(bytes: &[u8]) -> std::result::Result<(&[u8], &[u8]), String> {
    if bytes.len() < 8 || &bytes[..6] != MAGIC {
        return Err("not a Deep Contact U-Net model file (no DCUNET header)".into());
    }
    let version = u16::from_le_bytes([bytes[6], bytes[7]]);
    if !(OLDEST_FORMAT..=FORMAT_VERSION).contains(&version) {
        return Err(format!(
            "model format version {version}, this build reads versions {OLDEST_FORMAT} to {FORMAT_VERSION}"
        ));
    }
    let mut at = 8;
    let mut section = |what: &str| -> std::result::Result<&[u8], String> {
        let len = bytes
            .get(at..at + 8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
            .ok_or_else(|| format!("file ends before the {what} length (truncated?)"))?;
        let held = bytes.len().saturating_sub(at + 8);
        // Checked: a damaged length must not overflow or index past the file.
        let body =
            usize::try_from(len).ok().filter(|&l| l <= held).map(|l| &bytes[at + 8..at + 8 + l]).ok_or_else(|| {
                format!("{what} announces {len} bytes, the file holds {held} (truncated or damaged?)")
            })?;
        let len = body.len();
        at += 8 + len;
        Ok(body)
    };
    let json = section("metadata")?;
    let weights = section("weights")?;
    if version >= 2 {
        let stored = bytes
            .get(at..at + 8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
            .ok_or("file ends before the checksum (truncated?)")?;
        let computed = checksum(&[json, weights]);
        if stored != computed {
            return Err(format!(
                "checksum mismatch (stored {stored:016x}, computed {computed:016x}): the file is damaged"
            ));
        }
        at += 8;
    }
    if at != bytes.len() {
        return Err(format!("{} bytes after the model's end (damaged?)", bytes.len() - at));
    }
    Ok((json, weights))
}

/// The metadata and weight bytes of a model file; `accept_unchecked` lets a format-1 file (no
/// checksum) through, for [`ModelFile::upgrade`] only.
fn parse(bytes: &[u8], accept_unchecked: bool) -> std::result::Result<(ModelMeta, &[u8]), String> {
    let (json, weights) = sections(bytes)?;
    let version = u16::from_le_bytes([bytes[6], bytes[7]]);
    if version < FORMAT_VERSION && !accept_unchecked {
        return Err(format!(
            "model format version {version} has no checksum, so damage would go unnoticed: \
             `dc-unet upgrade FILE` checks its weights and rewrites it as version {FORMAT_VERSION}"
        ));
    }
    let meta: ModelMeta = serde_json::from_slice(json).map_err(|e| format!("metadata: {e}"))?;
    meta.config.validate().map_err(|e| format!("configuration: {e}"))?;
    // Before anything is allocated for it: a damaged configuration must not ask for a network
    // larger than the weights the file holds (4 bytes a weight).
    let needed = meta.config.convolution_weights().saturating_mul(4);
    if (weights.len() as u64) < needed {
        return Err(format!(
            "the configuration {:?} needs at least {needed} bytes of weights, the file holds {}",
            meta.config,
            weights.len()
        ));
    }
    if meta.grid_shape.iter().any(|&side| side == 0 || side > MAX_GRID_SIDE) {
        return Err(format!("grid shape {:?}: sides from 1 to {MAX_GRID_SIDE}", meta.grid_shape));
    }
    let n = &meta.normalization;
    if meta.input_channels.len() != meta.config.in_channels
        || meta.output_channels.len() != meta.config.out_channels
        || n.input_mean.len() != meta.config.in_channels
        || n.input_std.len() != meta.config.in_channels
        || n.target_mean.len() != meta.config.out_channels
        || n.target_std.len() != meta.config.out_channels
    {
        return Err("metadata is inconsistent: channel lists, normalisation and configuration disagree".into());
    }
    let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
    if !(finite(&n.input_mean) && finite(&n.target_mean))
        || n.input_std.iter().chain(&n.target_std).any(|s| !(s.is_finite() && *s > 0.0))
    {
        return Err("normalisation: means must be finite and deviations finite and positive".into());
    }
    Ok((meta, weights))
}
