//! The encoder in the loop, for the paper's two pretraining arms: `--init tokenizer` (the
//! shipped tokenizer's encoder, fine-tuned with the heads) and `--init scratch` (the same
//! encoder, freshly initialised, trained with them).
//!
//! - Each keyframe's encoder inputs (camera images, pillars, the fusion's reference points) are
//!   made once, as the tokenizer's own training and the `encode` node make them, and kept as
//!   host arrays.
//! - A training batch's input is the encoder's product (the latent or the fused feature) under
//!   autodiff, standardised with fixed statistics and, for two frames, the previous keyframe's
//!   map brought into the current frame by the same bilinear taps as
//!   `bevworld_types::warp_latent` (a gather and a weighted sum, so the gradient flows). The
//!   previous keyframe's map is made by the same encoder but carries no gradient: it is the
//!   reference the current frame is compared with, made by the inference kernels (a third of
//!   the cost under autodiff), and its backward pass would double a step's cost.
//! - Validation and the test score detect on the maps the encoder makes of those sets at the
//!   time (`encode_maps`), the same inference path as the `encode` node.

use std::collections::HashMap;
use std::path::Path;

use bevworld_heads::{InputKind, InputSpec};
use bevworld_pillarize::{Limits, Pillarizer, ego_points_into};
use bevworld_sensors::DatasetOptions;
use bevworld_tokenizer::{EncoderArrays, FrameInputs, Tokenizer};
use bevworld_types::{BevGrid, LatentGrid, PlanarMotion, warp_taps};
use burn::prelude::*;

use crate::data::{DataError, DetectionSet, LabelledFrame, read_keyframes};

/// The product of the encoder a detector reads.
pub fn product(
    tokenizer: &Tokenizer,
    arrays: &EncoderArrays,
    kind: InputKind,
    device: &Device,
) -> Tensor<4> {
    let encoded = tokenizer.encode(arrays.to_input(device));
    match kind {
        InputKind::Feature => encoded.fused,
        // The latent; the pillar statistics have no encoder (refused before a run starts).
        InputKind::Latent | InputKind::BevStats => encoded.latent,
    } // [1, C, h, w]
}

/// A set's keyframes (maps left empty, for `encode_maps` to fill) and each keyframe's encoder
/// inputs, in the set's order.
pub fn load_encoder_set(
    dataset: &Path,
    config: &bevworld_heads::DetectorConfig,
    inputs: &FrameInputs,
    kind: InputKind,
    model: &str,
    weights_hash: &str,
) -> Result<(DetectionSet, Vec<EncoderArrays>), DataError> {
    let mut pillarizer = Pillarizer::new(inputs.pillar_grid(), Limits::default());
    let mut points = Vec::new();
    let mut arrays = Vec::new();
    let (frames, truth) = read_keyframes(dataset, &DatasetOptions::default(), config, |frame| {
        ego_points_into(&frame.lidar, &mut points);
        let pillars = pillarizer.run(&points);
        let frame_arrays =
            inputs
                .encoder_arrays(frame, &pillars)
                .map_err(|error| DataError::Dataset {
                    path: dataset.to_path_buf(),
                    message: format!("keyframe {}: {error}", frame.sample_token),
                })?;
        arrays.push(frame_arrays);
        Ok(Vec::new())
    })?;
    let tokenizer = inputs.config();
    let grid = bevworld_tokenizer::nodes::encode::latent_grid(tokenizer);
    let channels = match kind {
        InputKind::Feature => tokenizer.fused_channels(),
        InputKind::Latent | InputKind::BevStats => tokenizer.latent_channels,
    };
    Ok((
        DetectionSet {
            frames,
            truth,
            model: model.to_string(),
            weights_hash: weights_hash.to_string(),
            grid,
            channels,
        },
        arrays,
    ))
}

/// Every keyframe's map as `tokenizer` makes it now (on an inference device), into `set`.
pub fn encode_maps(
    tokenizer: &Tokenizer,
    kind: InputKind,
    set: &mut DetectionSet,
    arrays: &[EncoderArrays],
    device: &Device,
) -> Result<(), DataError> {
    for (frame, frame_arrays) in set.frames.iter_mut().zip(arrays) {
        let values = product(tokenizer, frame_arrays, kind, device)
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|error| DataError::Keyframe {
                sample: frame.sample_token.clone(),
                message: format!("reading the encoder's map back: {error:?}"),
            })?;
        if let Some(bad) = values.iter().position(|v| !v.is_finite()) {
            return Err(DataError::Keyframe {
                sample: frame.sample_token.clone(),
                message: format!("the encoder's map has a non-finite value at {bad}"),
            });
        }
        frame.map = values;
    }
    Ok(())
}

/// The bilinear taps of a two-frame input's warp, per pair of keyframes, as index and weight
/// tensors: `[4, H·W]` each, a missing corner as index 0 with weight 0.
struct WarpTensors {
    indices: Tensor<2, Int>,
    weights: Tensor<2>,
}

fn warp_tensors(
    grid: &BevGrid,
    previous_from_current: &PlanarMotion,
    device: &Device,
) -> WarpTensors {
    let latent_grid = LatentGrid::of(grid, 1);
    let taps = warp_taps(&latent_grid, previous_from_current);
    let cells = taps.len();
    let mut indices = vec![0i64; 4 * cells];
    let mut weights = vec![0.0f32; 4 * cells];
    for (cell, cell_taps) in taps.iter().enumerate() {
        for (k, &(index, weight)) in cell_taps.iter().enumerate().take(4) {
            indices[k * cells + cell] = i64::from(index);
            weights[k * cells + cell] = weight;
        }
    }
    WarpTensors {
        indices: Tensor::from_data(TensorData::new(indices, [4, cells]), device),
        weights: Tensor::from_data(TensorData::new(weights, [4, cells]), device),
    }
}

/// `map` `[1, C, H, W]` seen from the current frame: each cell the weighted sum of its taps in
/// `map`, 0 (the standardised mean) where a tap falls outside. Differentiable in `map`.
fn warp(map: Tensor<4>, taps: &WarpTensors) -> Tensor<4> {
    let [_, channels, height, width] = map.dims();
    let cells = height * width;
    let table = map.reshape([channels, cells]).transpose(); // [H·W, C]
    let mut warped: Option<Tensor<2>> = None;
    for k in 0..4 {
        let index = taps.indices.clone().narrow(0, k, 1).reshape([cells]);
        let weight = taps.weights.clone().narrow(0, k, 1).reshape([cells, 1]);
        let term = table.clone().select(0, index).mul(weight); // [H·W, C]
        warped = Some(match warped {
            Some(sum) => sum + term,
            None => term,
        });
    }
    warped
        .unwrap_or_else(|| Tensor::zeros([cells, channels], &table.device()))
        .transpose()
        .reshape([1, channels, height, width])
}

/// The detector's input `[N, C·F, H, W]` for `frames[draws]`, made by `tokenizer` on `device`
/// (an autodiff device in training): what `crate::evaluate::input_batch` builds from exported
/// maps, with the current frame's map carrying the encoder's gradient.
pub fn encoded_batch(
    tokenizer: &Tokenizer,
    spec: &InputSpec,
    frames: &[LabelledFrame],
    arrays: &[EncoderArrays],
    draws: &[usize],
    device: &Device,
) -> Tensor<4> {
    let shape = [1, spec.channels, 1, 1];
    let mean = Tensor::<4>::from_data(TensorData::new(spec.mean.clone(), shape), device);
    let std = Tensor::<4>::from_data(TensorData::new(spec.std.clone(), shape), device);
    let standardised = |map: Tensor<4>| map.sub(mean.clone()).div(std.clone()); // [1, C, H, W]
    let mut warps: HashMap<(usize, usize), WarpTensors> = HashMap::new();
    let mut reference: Option<Tokenizer> = None;
    let inputs: Vec<Tensor<4>> = draws
        .iter()
        .map(|&i| {
            let current = standardised(product(tokenizer, &arrays[i], spec.kind, device));
            if spec.frames < 2 {
                return current;
            }
            let behind = match frames[i].previous {
                Some(p) => {
                    // No gradient: made on the inference device, by the host kernels.
                    let reference = reference.get_or_insert_with(|| tokenizer.valid());
                    let previous = Tensor::from_inner(product(
                        reference,
                        &arrays[p],
                        spec.kind,
                        &device.clone().inner(),
                    ));
                    let previous = standardised(previous);
                    let taps = warps.entry((p, i)).or_insert_with(|| {
                        let motion = PlanarMotion::between(
                            &frames[p].global_from_ego,
                            &frames[i].global_from_ego,
                        );
                        warp_tensors(&spec.grid, &motion, device)
                    });
                    warp(previous, taps)
                }
                // A scene's first keyframe reads its own map twice: no motion seen.
                None => current.clone(),
            };
            Tensor::cat(vec![current, behind], 1) // [1, 2C, H, W]
        })
        .collect();
    Tensor::cat(inputs, 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevworld_types::warp_latent;

    #[test]
    fn the_tensor_warp_is_the_host_warp() {
        let grid = BevGrid {
            x_range: [-8.0, 8.0],
            y_range: [-8.0, 8.0],
            resolution: 2.0,
            height: 8,
            width: 8,
        };
        let device = Device::flex();
        let values: Vec<f32> = (0..2 * 64).map(|v| ((v * 37) % 23) as f32 - 11.0).collect();
        let motion = PlanarMotion {
            x: 1.3,
            y: -0.7,
            yaw: 0.4,
        };
        let map = Tensor::<4>::from_data(TensorData::new(values.clone(), [1, 2, 8, 8]), &device);
        let warped = warp(map, &warp_tensors(&grid, &motion, &device))
            .into_data()
            .try_to_vec::<f32>()
            .expect("f32");
        let latent_grid = LatentGrid {
            channels: 2,
            height: 8,
            width: 8,
            x_range: [-8.0, 8.0],
            y_range: [-8.0, 8.0],
        };
        let host = warp_latent(&values, &latent_grid, &motion, 0.0);
        let mut edge_cells = 0;
        for (a, b) in warped.iter().zip(&host) {
            assert!((a - b).abs() < 1e-5, "{a} against {b}");
            edge_cells += usize::from(*b == 0.0);
        }
        // The motion moves part of the grid off the map: those cells read the mean.
        assert!(edge_cells > 0);
    }
}
