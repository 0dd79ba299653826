//! The U-Net of THESIS.md: StdBlock (conv 3x3 + BatchNorm + ReLU), StdDownsample (average pool 2
//! + BatchNorm), a dilated bottom whose branches are summed, StdUpsample (transposed conv stride 2
//! + BatchNorm) and skip connections by concatenation.
//!
//! One addition: with `residual` the network predicts a *correction* to the previous step's
//! impulse grid (input channels `prev_normal`, `prev_tangent`) instead of the impulses themselves.
//! Its last convolution starts at zero, so an untrained residual model is exactly the thesis's
//! `grid` warm start, and training can only move it from there.

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::pool::{AvgPool2d, AvgPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, Initializer, PaddingConfig2d};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

/// Most input or output channels of a network.
pub const MAX_CHANNELS: usize = 64;
/// Widest first level (the bottom is `2^levels` times wider).
pub const MAX_BASE_WIDTH: usize = 256;
/// Most parallel dilated convolutions at the bottom, and the largest dilation.
pub const MAX_DILATIONS: usize = 8;
pub const MAX_DILATION: usize = 64;

/// Shape of the network: everything needed to rebuild it before loading weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UNetConfig {
    /// Input channels: 5 (bodies) or 7 (bodies + previous impulses, the temporal variant).
    pub in_channels: usize,
    /// Output channels: 2 (normal and tangent impulse).
    pub out_channels: usize,
    /// Number of downsampling steps; grids must be a multiple of 2^levels.
    pub levels: usize,
    /// Channels of the first level; each level below doubles it.
    pub base_width: usize,
    /// Dilations of the parallel 3x3 convolutions at the bottom (summed).
    pub dilations: Vec<usize>,
    /// Input channels added to the output (the previous impulses), or `None`.
    pub residual: Option<[usize; 2]>,
}

impl Default for UNetConfig {
    fn default() -> Self {
        UNetConfig {
            in_channels: 7,
            out_channels: 2,
            levels: 3,
            base_width: 8,
            dilations: vec![2, 4, 8],
            residual: Some([5, 6]),
        }
    }
}

impl UNetConfig {
    /// Channels of level `l` (0 = full resolution).
    pub fn width(&self, level: usize) -> usize {
        self.base_width << level
    }

    /// The multiple that grid sides must have.
    pub fn size_multiple(&self) -> usize {
        1 << self.levels
    }

    /// Checks the numbers before building.
    pub fn validate(&self) -> Result<(), String> {
        if self.in_channels == 0 || self.out_channels == 0 || self.base_width == 0 {
            return Err("channels and width must be > 0".into());
        }
        if self.in_channels > MAX_CHANNELS || self.out_channels > MAX_CHANNELS || self.base_width > MAX_BASE_WIDTH {
            return Err(format!(
                "{} input / {} output channels, base width {}: at most {MAX_CHANNELS} channels and width {MAX_BASE_WIDTH}",
                self.in_channels, self.out_channels, self.base_width
            ));
        }
        if self.levels > 7 {
            return Err(format!("{} levels: at most 7 (grids of 128 nodes)", self.levels));
        }
        if self.dilations.is_empty() || self.dilations.contains(&0) {
            return Err("dilations must be a non-empty list of positive numbers".into());
        }
        if self.dilations.len() > MAX_DILATIONS || self.dilations.iter().any(|&d| d > MAX_DILATION) {
            return Err(format!(
                "dilations {:?}: at most {MAX_DILATIONS} of them, each at most {MAX_DILATION}",
                self.dilations
            ));
        }
        if let Some(r) = self.residual {
            if r.iter().any(|&c| c >= self.in_channels) || self.out_channels != 2 {
                return Err(format!("residual channels {r:?} must be input channels and the output 2 channels"));
            }
        }
        // A network whose model file no reader would take (4 bytes a weight).
        let bytes = self.convolution_weights().saturating_mul(4);
        if bytes > runtime::files::MAX_MODEL_BYTES {
            return Err(format!(
                "{} levels of base width {} with {} dilations: {} of weights, more than a model file holds (at most {})",
                self.levels,
                self.base_width,
                self.dilations.len(),
                runtime::files::size_text(bytes),
                runtime::files::size_text(runtime::files::MAX_MODEL_BYTES)
            ));
        }
        Ok(())
    }

    /// The network's convolution weights (biases and norms left out): what its weights must hold
    /// at least, checked against a file before [`UNetConfig::init`] allocates them. Call after
    /// [`UNetConfig::validate`] (whose bounds keep this far from overflowing).
    pub fn convolution_weights(&self) -> u64 {
        let w = |l: usize| self.width(l) as u64;
        let conv3 = |c_in: u64, c_out: u64| c_in * c_out * 9;
        let mut n = conv3(self.in_channels as u64, w(0));
        for l in 1..=self.levels {
            n += conv3(w(l - 1), w(l)) + w(l) * w(l - 1) * 4 + conv3(2 * w(l - 1), w(l - 1));
        }
        n + self.dilations.len() as u64 * conv3(w(self.levels), w(self.levels)) + w(0) * self.out_channels as u64
    }

    /// A freshly initialised network on `device`.
    pub fn init(&self, device: &Device) -> UNet {
        let block = |c_in: usize, c_out: usize| StdBlock::new(c_in, c_out, 1, device);
        let mut encoder = vec![block(self.in_channels, self.width(0))];
        let mut down = Vec::new();
        for l in 1..=self.levels {
            down.push(StdDownsample::new(self.width(l - 1), device));
            encoder.push(block(self.width(l - 1), self.width(l)));
        }
        let bottom_width = self.width(self.levels);
        let bottom = self.dilations.iter().map(|&d| StdBlock::new(bottom_width, bottom_width, d, device)).collect();
        let mut up = Vec::new();
        let mut decoder = Vec::new();
        for l in (1..=self.levels).rev() {
            up.push(StdUpsample::new(self.width(l), self.width(l - 1), device));
            decoder.push(block(2 * self.width(l - 1), self.width(l - 1)));
        }
        let mut head = Conv2dConfig::new([self.width(0), self.out_channels], [1, 1]);
        if self.residual.is_some() {
            // Start as the identity on the previous impulses: the `grid` model. (Zeroing an
            // initialised parameter with `map` would make it a constant that never trains.)
            head = head.with_initializer(Initializer::Zeros);
        }
        let head = head.init(device);
        UNet { encoder, down, bottom, up, decoder, head, residual: self.residual.map(|r| r.to_vec()) }
    }
}

/// Conv 3x3 (padding = dilation, so the size stays) + BatchNorm + ReLU.
#[derive(Module, Debug)]
pub struct StdBlock {
    conv: Conv2d,
    norm: BatchNorm,
}

impl StdBlock {
    fn new(c_in: usize, c_out: usize, dilation: usize, device: &Device) -> StdBlock {
        StdBlock {
            conv: Conv2dConfig::new([c_in, c_out], [3, 3])
                .with_dilation([dilation, dilation])
                .with_padding(PaddingConfig2d::Explicit(dilation, dilation, dilation, dilation))
                .init(device),
            norm: BatchNormConfig::new(c_out).init(device),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        relu(self.norm.forward(self.conv.forward(x)))
    }
}

/// Average pool 2x2 + BatchNorm.
#[derive(Module, Debug)]
pub struct StdDownsample {
    pool: AvgPool2d,
    norm: BatchNorm,
}

impl StdDownsample {
    fn new(channels: usize, device: &Device) -> StdDownsample {
        StdDownsample { pool: AvgPool2dConfig::new([2, 2]).init(), norm: BatchNormConfig::new(channels).init(device) }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.norm.forward(self.pool.forward(x))
    }
}

/// Transposed conv 2x2 stride 2 (doubles the size) + BatchNorm.
#[derive(Module, Debug)]
pub struct StdUpsample {
    conv: ConvTranspose2d,
    norm: BatchNorm,
}

impl StdUpsample {
    fn new(c_in: usize, c_out: usize, device: &Device) -> StdUpsample {
        StdUpsample {
            conv: ConvTranspose2dConfig::new([c_in, c_out], [2, 2]).with_stride([2, 2]).init(device),
            norm: BatchNormConfig::new(c_out).init(device),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.norm.forward(self.conv.forward(x))
    }
}

/// The network. Build it with [`UNetConfig::init`].
#[derive(Module, Debug)]
pub struct UNet {
    encoder: Vec<StdBlock>,
    down: Vec<StdDownsample>,
    bottom: Vec<StdBlock>,
    up: Vec<StdUpsample>,
    decoder: Vec<StdBlock>,
    head: Conv2d,
    /// Input channels added to the output (empty: none).
    residual: Option<Vec<usize>>,
}

impl UNet {
    /// `[batch, in_channels, H, W]` -> `[batch, out_channels, H, W]`; H and W multiples of 2^levels.
    pub fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        let mut x = self.encoder[0].forward(input.clone());
        let mut skips = Vec::with_capacity(self.down.len());
        for (down, block) in self.down.iter().zip(&self.encoder[1..]) {
            skips.push(x.clone());
            x = block.forward(down.forward(x));
        }
        let mut branches = self.bottom.iter().map(|b| b.forward(x.clone()));
        let first = branches.next().expect("at least one dilation");
        x = branches.fold(first, |sum, b| sum + b);
        for ((up, block), skip) in self.up.iter().zip(&self.decoder).zip(skips.into_iter().rev()) {
            x = block.forward(Tensor::cat(vec![up.forward(x), skip], 1));
        }
        let out = self.head.forward(x);
        match &self.residual {
            Some(r) => out + select_channels(&input, r),
            None => out,
        }
    }
}

/// Channels `channels` of `x`, in that order.
pub fn select_channels(x: &Tensor<4>, channels: &[usize]) -> Tensor<4> {
    let [b, _, h, w] = x.dims();
    Tensor::cat(channels.iter().map(|&c| x.clone().slice([0..b, c..c + 1, 0..h, 0..w])).collect(), 1)
}
