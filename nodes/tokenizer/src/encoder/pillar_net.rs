//! The PointPillars pillar feature net and its scatter into the dense BEV grid.
//!
//! Each point's 9 features go through a shared linear layer, a normalisation and a ReLU; a
//! pillar is the max over its points. PointPillars normalises with batch norm; we use a layer
//! norm over each point's channels. Batch statistics pooled over every slot would include the
//! padding, they differ between training (the batch's) and inference (running averages), and
//! their running averages are a state that threads of a data-parallel step update in whatever
//! order they finish, so a run would not repeat. A layer norm treats each point alone, the
//! same way in training and inference. The linear layer has a bias, so that the norm does not
//! make a point and its scaled copy alike. Padded point slots are masked to 0 after the ReLU, where every
//! real value is already >= 0, so they never win the max. Only non-empty pillars are computed;
//! the scatter writes them into a zero BEV map.

use bevworld_blocks::linear_on_host::linear;
use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Features per point, as the pillarize node writes them.
pub const POINT_FEATURES: usize = 9;

#[derive(Config, Debug)]
pub struct PillarNetConfig {
    /// Channels of a pillar feature (64 in PointPillars).
    pub channels: usize,
}

#[derive(Module, Debug)]
pub struct PillarNet {
    linear: Linear,
    norm: LayerNorm,
}

impl PillarNetConfig {
    pub fn init(&self, device: &Device) -> PillarNet {
        PillarNet {
            linear: LinearConfig::new(POINT_FEATURES, self.channels).init(device),
            norm: LayerNormConfig::new(self.channels)
                .with_epsilon(1e-3)
                .init(device),
        }
    }
}

impl PillarNet {
    /// `points`: padded per-pillar points; `valid`: 1 for a real point, 0 for padding.
    // points [P, N, 9], valid [P, N] -> [P, C]
    pub fn forward(&self, points: Tensor<3>, valid: Tensor<2>) -> Tensor<2> {
        let [pillars, slots, _] = points.dims();
        let h = self.norm.forward(linear(&self.linear, points)); // [P, N, C]
        let h = relu(h) * valid.reshape([pillars, slots, 1]);
        let [_, _, channels] = h.dims();
        h.max_dim(1).reshape([pillars, channels])
    }
}

/// Writes pillar features into a zero BEV map at their cells.
/// `cells`: row-major cell index `iy * width + ix` of each pillar, all distinct.
// features [P, C], cells [P] -> [1, C, H, W]
pub fn scatter_to_bev(
    features: Tensor<2>,
    cells: Tensor<1, Int>,
    height: usize,
    width: usize,
) -> Tensor<4> {
    let [_, channels] = features.dims();
    let device = features.device();
    Tensor::<2>::zeros([height * width, channels], &device)
        .select_assign(0, cells, features, burn::tensor::IndexingUpdateOp::Add)
        .swap_dims(0, 1)
        .reshape([1, channels, height, width])
}
