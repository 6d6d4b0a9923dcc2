//! Deformable cross-attention from the LiDAR BEV into the cameras (the paper's fusion).
//!
//! Each BEV cell is a query. Its K reference points along the pillar's height are projected into
//! every camera (`projection.rs`); around each projection the query predicts a learned offset
//! (zero at initialisation, so sampling starts at the geometric point) and an attention weight.
//! Image features are read bilinearly with zero padding (`bilinear::sample_bilinear`, with
//! `grid_sample_2d`'s conventions). With several feature levels (the backbone's stages, as in
//! multi-scale deformable attention), every level is read at the same point through its own
//! value projection and the values are summed: the finer stage keeps the colours and edges
//! that the last one has averaged over 8 x 8 pixels. The weights are a softmax over the
//! (camera, point) pairs that are valid, times their validity: a point behind a camera or
//! outside its image gets weight exactly 0, and a query that no camera sees gets nothing from
//! the images, only its residual.

use bevworld_blocks::linear_on_host::linear;
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;

use crate::encoder::bilinear::sample_bilinear;
use bevworld_blocks::MASKED;
use bevworld_blocks::activation::softmax_last;

#[derive(Config, Debug, PartialEq)]
pub struct DeformableFusionConfig {
    /// Channels of the BEV queries and of the output.
    pub dim: usize,
    /// Channels of the image features: the coarsest level's.
    pub image_channels: usize,
    /// Channels of each finer level the fusion also reads, finest first (empty: one level).
    #[config(default = "Vec::new()")]
    pub fine_channels: Vec<usize>,
    pub cameras: usize,
    /// Reference points per query along the pillar's height (K = 4 in the paper).
    pub heights: usize,
}

#[derive(Module, Debug)]
pub struct DeformableFusion {
    value: Linear,
    /// Value projections of the finer levels, in `fine_channels` order.
    fine_values: Vec<Linear>,
    offsets: Linear,
    weights: Linear,
    output: Linear,
    #[module(skip)]
    cameras: usize,
    #[module(skip)]
    heights: usize,
}

impl DeformableFusionConfig {
    pub fn init(&self, device: &Device) -> DeformableFusion {
        DeformableFusion {
            value: LinearConfig::new(self.image_channels, self.dim).init(device),
            fine_values: self
                .fine_channels
                .iter()
                .map(|&channels| LinearConfig::new(channels, self.dim).init(device))
                .collect(),
            offsets: LinearConfig::new(self.dim, self.cameras * self.heights * 2)
                .with_initializer(Initializer::Zeros)
                .init(device),
            weights: LinearConfig::new(self.dim, self.cameras * self.heights).init(device),
            output: LinearConfig::new(self.dim, self.dim).init(device),
            cameras: self.cameras,
            heights: self.heights,
        }
    }
}

impl DeformableFusion {
    /// `reference`: where each query's points land in each camera, in `grid_sample_2d`'s
    /// [-1, 1] coordinates; `valid`: 1 where that projection is in front of the camera and
    /// inside its image. `fine` are the finer feature levels, one per `fine_channels` entry.
    // bev [1, C, H, W], images [N_c, C_img, h, w], fine [N_c, C_l, h_l, w_l] each,
    // reference [N_c, Q, K, 2], valid [N_c, Q, K] -> [1, C, H, W], with Q = H * W
    pub fn forward(
        &self,
        bev: Tensor<4>,
        images: Tensor<4>,
        fine: Vec<Tensor<4>>,
        reference: Tensor<4>,
        valid: Tensor<3>,
    ) -> Tensor<4> {
        let [_, dim, height, width] = bev.dims();
        let [cameras, _, feature_h, feature_w] = images.dims();
        let (queries, k) = (height * width, self.heights);
        let query = bev.reshape([dim, queries]).swap_dims(0, 1); // [Q, C]

        let value = linear(&self.value, images.permute([0, 2, 3, 1])); // [N_c, h, w, C]
        // Offsets in feature-map cells, turned into [-1, 1] units.
        let scale = Tensor::<1>::from_data(
            TensorData::new(vec![2.0 / feature_w as f32, 2.0 / feature_h as f32], [2]),
            &query.device(),
        )
        .reshape([1, 1, 1, 2]);
        let offsets = linear(&self.offsets, query.clone())
            .reshape([queries, cameras, k, 2])
            .swap_dims(0, 1)
            * scale; // [N_c, Q, K, 2]
        let grid = reference + offsets;

        let valid_qck = valid.swap_dims(0, 1).reshape([queries, cameras * k]); // [Q, N_c*K]
        let logits = linear(&self.weights, query.clone()) // [Q, N_c*K]
            + (valid_qck.clone().neg().add_scalar(1.0)).mul_scalar(MASKED);
        let attention = (softmax_last(logits) * valid_qck)
            .reshape([queries, cameras, k])
            .swap_dims(0, 1); // [N_c, Q, K]

        let grid = grid.reshape([cameras, queries * k, 2]);
        let mut sampled = sample_bilinear(value, grid.clone()); // [N_c, Q * K, C]
        for (projection, level) in self.fine_values.iter().zip(fine) {
            let value = linear(projection, level.permute([0, 2, 3, 1])); // [N_c, h_l, w_l, C]
            sampled = sampled + sample_bilinear(value, grid.clone());
        }
        let sampled = sampled.reshape([cameras, queries, k, dim]); // [N_c, Q, K, C]
        let fused = (sampled * attention.reshape([cameras, queries, k, 1]))
            .sum_dim(2)
            .sum_dim(0)
            .reshape([queries, dim]); // [Q, C]
        let out = query + linear(&self.output, fused); // [Q, C]
        out.swap_dims(0, 1).reshape([1, dim, height, width])
    }
}
