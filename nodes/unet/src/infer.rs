//! Inference: a received bodies grid in, the predicted impulse grid out (de-normalised, with the
//! input's geometry so the simulator samples it where the nodes really are). A temporal model's
//! output also carries the predicted *change*, `d_normal` / `d_tangent` (prediction minus the
//! input's previous impulses), which the `unet-delta` warm start adds to builtin's impulses.

use crate::model::UNet;
use crate::modelfile::{ModelFile, ModelMeta};
use crate::{Result, UnetError};
use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use msgs::Grid;
use std::path::Path;

/// The change channels a temporal model's output carries after `normal` and `tangent`.
pub const DELTA_CHANNELS: [&str; 2] = ["d_normal", "d_tangent"];

/// A loaded model ready to predict.
pub struct Predictor {
    model: UNet,
    meta: ModelMeta,
    device: Device,
}

impl Predictor {
    /// Loads `path` onto `device` in evaluation mode.
    pub fn load(path: &Path, device: &Device) -> Result<Predictor> {
        let file = ModelFile::load(path, device)?;
        Ok(Predictor { model: file.model.valid(), meta: file.meta, device: device.clone() })
    }

    /// A predictor from a model in memory.
    pub fn new(model: &UNet, meta: ModelMeta, device: &Device) -> Predictor {
        Predictor { model: model.valid(), meta, device: device.clone() }
    }

    pub fn meta(&self) -> &ModelMeta {
        &self.meta
    }

    /// Checks that `grid` is what the model was trained on: channel names and order, size.
    pub fn check(&self, grid: &Grid) -> Result<()> {
        let h = &grid.header;
        let names: Vec<&str> = (0..h.channels as usize).map(|c| h.channel_name(c)).collect();
        let [eh, ew] = self.meta.grid_shape;
        let expected_shape = (self.meta.input_channels.len(), eh, ew);
        let actual_shape = (names.len(), h.height as usize, h.width as usize);
        if expected_shape != actual_shape || names.iter().zip(&self.meta.input_channels).any(|(a, b)| a != b) {
            return Err(UnetError::Input(format!(
                "simulation {} step {}: expected a grid of {} x {} x {} (channels x height x width) with channels {:?}, got {} x {} x {} with {:?}",
                h.step.simulation,
                h.step.step,
                expected_shape.0,
                expected_shape.1,
                expected_shape.2,
                self.meta.input_channels,
                actual_shape.0,
                actual_shape.1,
                actual_shape.2,
                names
            )));
        }
        if (h.spacing - self.meta.grid.res).abs() > 1e-6 {
            return Err(UnetError::Input(format!(
                "simulation {} step {}: grid spacing {} but the model was trained at {}",
                h.step.simulation, h.step.step, h.spacing, self.meta.grid.res
            )));
        }
        if grid.items.len() != h.len() {
            return Err(UnetError::Input(format!(
                "grid holds {} values, its header announces {}",
                grid.items.len(),
                h.len()
            )));
        }
        Ok(())
    }

    /// Predicts the impulse grids of several inputs in one batch (all checked first).
    /// The outer error is the batch's (a grid that does not fit, a prediction that cannot be
    /// read); the inner one a grid's own: a prediction with non-finite values (a network whose
    /// finite weights overflow on this input) is refused, never handed to a simulator.
    pub fn predict_batch(&self, grids: &[&Grid]) -> Result<Vec<Result<Grid>>> {
        if grids.is_empty() {
            return Ok(Vec::new());
        }
        // `check` is cheap (names and sizes), so callers that already checked pay little here.
        for g in grids {
            self.check(g)?;
        }
        let [h, w] = self.meta.grid_shape;
        let (c_in, c_out) = (self.meta.config.in_channels, self.meta.config.out_channels);
        let mut input = Vec::with_capacity(grids.len() * c_in * h * w);
        for g in grids {
            let start = input.len();
            input.extend_from_slice(&g.items);
            self.meta.normalization.normalize_input(&mut input[start..]);
        }
        let x = Tensor::<4>::from_data(TensorData::new(input, [grids.len(), c_in, h, w]), &self.device);
        let y: Vec<f32> = self
            .model
            .forward(x)
            .into_data()
            .try_into_vec::<f32>()
            .map_err(|e| UnetError::Input(format!("reading the prediction: {e:?}")))?;
        let per = c_out * h * w;
        let mut names: Vec<&str> = self.meta.output_channels.iter().map(String::as_str).collect();
        // The input channels of the previous impulses, matching the outputs (normal, tangent).
        let previous: Option<Vec<usize>> = sph::TEMPORAL_CHANNELS
            .iter()
            .map(|p| self.meta.input_channels.iter().position(|c| c == p))
            .collect::<Option<Vec<usize>>>()
            .filter(|p| p.len() == c_out);
        if previous.is_some() {
            names.extend(DELTA_CHANNELS);
        }
        Ok(grids
            .iter()
            .zip(y.chunks_exact(per))
            .map(|(g, chunk)| {
                let mut values = chunk.to_vec();
                self.meta.normalization.denormalize_target(&mut values);
                let non_finite = values.iter().filter(|v| !v.is_finite()).count();
                if non_finite > 0 {
                    return Err(UnetError::Input(format!(
                        "step {:?}: the model predicted {non_finite} non-finite values of {}",
                        g.header.step,
                        values.len()
                    )));
                }
                if let Some(previous) = &previous {
                    let plane = h * w;
                    for (c, &p) in previous.iter().enumerate() {
                        let delta: Vec<f32> = values[c * plane..(c + 1) * plane]
                            .iter()
                            .zip(&g.items[p * plane..(p + 1) * plane])
                            .map(|(predicted, before)| predicted - before)
                            .collect();
                        values.extend(delta);
                    }
                }
                let geometry = sph::GridGeometry::from_header(&g.header);
                let header = geometry.header(g.header.step, &names).map_err(|e| UnetError::Input(e.to_string()))?;
                Ok(Grid::new(header, values))
            })
            .collect())
    }

    /// Predicts one grid.
    pub fn predict(&self, grid: &Grid) -> Result<Grid> {
        self.predict_batch(&[grid])?.pop().expect("one in, one out")
    }
}
