//! A loss that counts what moves (issue 51). The residual model predicts the future minus the
//! current latent moved by the ego (`residual_over_ego_warp`); wherever the world stands
//! still that residual is near zero, and those cells are most of a scene, so the plain L1
//! barely counts the few cells where another car moves. Here a cell counts `1 + extra` times
//! where the true residual exceeds `threshold` (standardised units) in any channel:
//!
//!   L = Σ w·|ŷ − y| / (C · Σ w),   w = 1 + extra · [max_c |r_c| > threshold]
//!
//! the weighted mean of the per-element L1 over `[B, N, C, H, W]`, equal to the plain mean
//! when `extra` is 0. The weight comes from the data, not the network: no gradient flows
//! through it.

use burn::prelude::*;
use serde::{Deserialize, Serialize};

use bevworld_training::ConfigProblem;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MovingWeight {
    /// How much more a moving cell counts: its weight is `1 + extra`.
    pub extra: f64,
    /// The true residual's magnitude, standardised, past which a cell moves.
    pub threshold: f64,
}

impl MovingWeight {
    pub fn problems(&self, field: &str) -> Vec<ConfigProblem> {
        let mut problems = Vec::new();
        if !(self.extra.is_finite() && self.extra >= 0.0) {
            problems.push(ConfigProblem::new(
                format!("{field}.extra"),
                format!("{} (accepted: a finite number ≥ 0)", self.extra),
            ));
        }
        if !(self.threshold.is_finite() && self.threshold > 0.0) {
            problems.push(ConfigProblem::new(
                format!("{field}.threshold"),
                format!(
                    "{} (accepted: a finite number > 0, standardised units)",
                    self.threshold
                ),
            ));
        }
        problems
    }

    /// Which cells move: 1 where the true residual passes the threshold in any channel.
    // [B, N, C, H, W] -> [B, N, 1, H, W]
    pub fn moving_cells(&self, residual: Tensor<5>) -> Tensor<5> {
        residual
            .abs()
            .max_dim(2)
            .greater_elem(self.threshold)
            .float()
    }

    /// Each cell's weight, from the true residual of the diffused frames.
    // [B, N, C, H, W] -> [B, N, 1, H, W]
    pub fn cell_weights(&self, residual: Tensor<5>) -> Tensor<5> {
        self.moving_cells(residual)
            .mul_scalar(self.extra)
            .add_scalar(1.0)
    }

    /// The weighted mean of `error` (per element, `[B, N, C, H, W]`) under the cells'
    /// weights of `residual`.
    pub fn loss(&self, error: Tensor<5>, residual: Tensor<5>) -> Tensor<1> {
        let weights = self.cell_weights(residual);
        let norm = weights.clone().mean();
        let dims = error.dims();
        (error * weights.expand(dims)).mean() / norm
    }
}

#[cfg(test)]
mod tests {
    use super::MovingWeight;
    use burn::prelude::*;

    fn tensor(values: Vec<f32>, dims: [usize; 5]) -> Tensor<5> {
        Tensor::from_data(TensorData::new(values, dims), &Device::flex())
    }

    #[test]
    fn a_cell_moves_when_any_channel_of_its_residual_passes_the_threshold() {
        let weight = MovingWeight {
            extra: 3.0,
            threshold: 0.25,
        };
        // [1, 1, 2, 1, 3]: cell 0 still, cell 1 moves in channel 1, cell 2 in channel 0
        // (negative), and 0.25 itself does not pass.
        let residual = tensor(vec![0.1, 0.0, -0.5, 0.25, 0.3, 0.0], [1, 1, 2, 1, 3]);
        let weights: Vec<f32> = weight
            .cell_weights(residual)
            .into_data()
            .try_to_vec::<f32>()
            .expect("f32");
        assert_eq!(weights, vec![1.0, 4.0, 4.0]);
    }

    #[test]
    fn the_loss_is_the_weighted_mean_by_hand_and_the_plain_mean_without_extra() {
        let residual = tensor(vec![0.0, 1.0, 0.0, 0.0], [1, 1, 2, 1, 2]);
        // Errors: cell 0 {1, 3}, cell 1 {2, 6}. Weights 1 and 5:
        // (1·1 + 1·3 + 5·2 + 5·6) / (2 · 6) = 44 / 12.
        let error = tensor(vec![1.0, 2.0, 3.0, 6.0], [1, 1, 2, 1, 2]);
        let moving = MovingWeight {
            extra: 4.0,
            threshold: 0.5,
        };
        let loss: f32 = moving.loss(error.clone(), residual.clone()).into_scalar();
        assert!((loss - 44.0 / 12.0).abs() < 1e-6, "{loss}");
        let plain = MovingWeight {
            extra: 0.0,
            threshold: 0.5,
        };
        let loss: f32 = plain.loss(error, residual).into_scalar();
        assert!((loss - 3.0).abs() < 1e-6, "the mean of 1, 2, 3, 6: {loss}");
    }

    #[test]
    fn a_negative_extra_or_a_threshold_not_above_zero_is_refused_by_name() {
        let bad = MovingWeight {
            extra: -1.0,
            threshold: 0.0,
        };
        let fields: Vec<String> = bad
            .problems("moving_weight")
            .iter()
            .map(ToString::to_string)
            .collect();
        assert_eq!(fields.len(), 2, "{fields:?}");
        assert!(fields[0].contains("moving_weight.extra"), "{fields:?}");
        assert!(fields[1].contains("moving_weight.threshold"), "{fields:?}");
        let good = MovingWeight {
            extra: 4.0,
            threshold: 0.25,
        };
        assert!(good.problems("moving_weight").is_empty());
    }
}
