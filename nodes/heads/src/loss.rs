//! The detector's losses on a batch:
//!
//! - heatmap: CenterNet's focal loss (α = 2, β = 4) over every cell, divided by the number of
//!   agents: `−Σ (1−p)^α log p` at centres, `−Σ (1−y)^β p^α log(1−p)` elsewhere;
//! - box: L1 on the regression channels at each agent's centre cell (velocity only where the
//!   dataset tells it);
//! - motion: winner-takes-all over the K modes (the average displacement of the closest mode,
//!   over the annotated steps) plus the cross-entropy of the mode logits toward that mode.
//!
//! With `moving` above 1, an agent that moves (`MOVING_SPEED_MPS`) counts that many times in
//! its velocity and its motion terms: where most agents stand, an L1 velocity is minimised by
//! the median, a standing agent's zero, and the standing mode takes the most probability.

use burn::prelude::*;
use burn::tensor::activation::{log_sigmoid, log_softmax, sigmoid};

use bevworld_types::object_box::MOVING_SPEED_MPS;

use crate::config::{BOX_CHANNELS, DetectorConfig};
use crate::model::HeadOutputs;
use crate::targets::FrameTargets;

/// The focal loss's exponents.
pub const FOCAL_ALPHA: i32 = 2;
pub const FOCAL_BETA: i32 = 4;

/// Each term of the loss, summed into `total` with its weight.
pub struct DetectionLoss {
    pub total: Tensor<1>,
    pub heatmap: Tensor<1>,
    pub boxes: Tensor<1>,
    pub motion: Tensor<1>,
}

/// Weights of the terms.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossWeights {
    pub heatmap: f64,
    pub boxes: f64,
    pub motion: f64,
    /// How many times a moving agent's velocity and motion terms count (1: as any other).
    #[serde(default = "one")]
    pub moving: f64,
}

fn one() -> f64 {
    1.0
}

/// Rows `[N, channels]` of `map [B, channels, H, W]` at `(item, cell)` pairs.
fn gather_cells(map: Tensor<4>, rows: &[usize], device: &Device) -> Tensor<2> {
    let [b, c, h, w] = map.dims();
    let flat = map
        .reshape([b, c, h * w])
        .swap_dims(1, 2)
        .reshape([b * h * w, c]); // [B·H·W, C]
    let index: Vec<i64> = rows.iter().map(|&r| r as i64).collect();
    let index = Tensor::<1, Int>::from_data(TensorData::new(index, [rows.len()]), device);
    flat.select(0, index)
}

impl DetectorConfig {
    /// The loss of `outputs` against `targets`, one per batch item, in order.
    pub fn loss(
        &self,
        outputs: HeadOutputs,
        targets: &[&FrameTargets],
        weights: &LossWeights,
    ) -> DetectionLoss {
        let device = outputs.heatmap.device();
        let [b, classes, h, w] = outputs.heatmap.dims();
        let heat: Vec<f32> = targets
            .iter()
            .flat_map(|t| t.heatmap.iter().copied())
            .collect();
        let truth = Tensor::<4>::from_data(TensorData::new(heat, [b, classes, h, w]), &device);
        let agents: usize = targets.iter().map(|t| t.objects.len()).sum();
        let normaliser = agents.max(1) as f64;

        // Focal loss, in log space for the log-probabilities.
        let logits = outputs.heatmap;
        let p = sigmoid(logits.clone());
        let centre = truth.clone().equal_elem(1.0).float(); // [B, C, H, W]
        let positive = log_sigmoid(logits.clone())
            .neg()
            .mul((p.clone().neg().add_scalar(1.0)).powi_scalar(FOCAL_ALPHA))
            .mul(centre.clone());
        let negative = log_sigmoid(logits.neg())
            .neg()
            .mul(p.powi_scalar(FOCAL_ALPHA))
            .mul(truth.neg().add_scalar(1.0).powi_scalar(FOCAL_BETA))
            .mul(centre.neg().add_scalar(1.0));
        let heatmap = (positive + negative).sum().div_scalar(normaliser);

        if agents == 0 {
            let zero = heatmap.zeros_like();
            let total = heatmap.clone().mul_scalar(weights.heatmap);
            return DetectionLoss {
                total,
                heatmap,
                boxes: zero.clone(),
                motion: zero,
            };
        }
        let mut rows = Vec::with_capacity(agents);
        let mut box_truth = Vec::with_capacity(agents * BOX_CHANNELS);
        let mut box_weight = Vec::with_capacity(agents * BOX_CHANNELS);
        let (modes, steps) = (self.motion.modes, self.motion.steps);
        let mut future = Vec::with_capacity(agents * steps * 2);
        let mut known = Vec::with_capacity(agents * steps);
        let mut agent_weight = Vec::with_capacity(agents);
        for (item, frame) in targets.iter().enumerate() {
            for object in &frame.objects {
                rows.push(item * h * w + object.cell);
                box_truth.extend_from_slice(&object.boxes);
                let speed = f64::from(object.boxes[8]).hypot(f64::from(object.boxes[9]));
                let weight = if object.velocity_known && speed > MOVING_SPEED_MPS {
                    weights.moving as f32
                } else {
                    1.0
                };
                agent_weight.push(weight);
                for channel in 0..BOX_CHANNELS {
                    let velocity = channel >= 8;
                    box_weight.push(match (velocity, object.velocity_known) {
                        (true, false) => 0.0f32,
                        (true, true) => weight,
                        (false, _) => 1.0,
                    });
                }
                future.extend(object.future.iter().flatten().copied());
                known.extend(
                    object
                        .future_known
                        .iter()
                        .map(|&k| if k { 1.0f32 } else { 0.0 }),
                );
            }
        }
        let n = rows.len();
        let predicted = gather_cells(outputs.boxes, &rows, &device); // [N, 10]
        let box_truth =
            Tensor::<2>::from_data(TensorData::new(box_truth, [n, BOX_CHANNELS]), &device);
        let box_weight =
            Tensor::<2>::from_data(TensorData::new(box_weight, [n, BOX_CHANNELS]), &device);
        let boxes = (predicted - box_truth)
            .abs()
            .mul(box_weight)
            .sum()
            .div_scalar(normaliser);

        let motion = gather_cells(outputs.motion, &rows, &device); // [N, K·(2T+1)]
        let trajectories = motion
            .clone()
            .slice([0..n, 0..modes * 2 * steps])
            .reshape([n, modes, steps, 2]);
        let mode_logits = motion.slice([0..n, modes * 2 * steps..modes * (2 * steps + 1)]); // [N, K]
        let future = Tensor::<4>::from_data(TensorData::new(future, [n, 1, steps, 2]), &device);
        let known = Tensor::<3>::from_data(TensorData::new(known, [n, 1, steps]), &device);
        let counted = known.clone().sum_dim(2).clamp_min(1.0); // [N, 1, 1]
        // Displacement per step, smoothed at 0 so that its gradient is finite.
        let displacement = (trajectories - future)
            .powi_scalar(2)
            .sum_dim(3)
            .add_scalar(1e-6)
            .sqrt()
            .squeeze_dim::<3>(3); // [N, K, T]
        let per_mode = displacement
            .mul(known.clone())
            .sum_dim(2)
            .div(counted)
            .squeeze_dim::<2>(2); // [N, K]
        let agent_weight = Tensor::<2>::from_data(TensorData::new(agent_weight, [n, 1]), &device); // [N, 1]
        let has_future = known.sum_dim(2).squeeze_dim::<2>(2).clamp_max(1.0) * agent_weight; // [N, 1]
        let best = per_mode.clone().argmin(1); // [N, 1]
        let winner = per_mode.gather(1, best.clone()); // [N, 1]
        let log_probability = log_softmax(mode_logits, 1).gather(1, best); // [N, 1]
        let motion = (winner - log_probability)
            .mul(has_future)
            .sum()
            .div_scalar(normaliser);

        let total = heatmap.clone().mul_scalar(weights.heatmap)
            + boxes.clone().mul_scalar(weights.boxes)
            + motion.clone().mul_scalar(weights.motion);
        DetectionLoss {
            total,
            heatmap,
            boxes,
            motion,
        }
    }
}
