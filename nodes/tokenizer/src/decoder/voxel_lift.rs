//! Lifting the 2D latent to a 3D voxel field (the paper's decoder front):
//! linear, Swin blocks, patch expanding, more Swin blocks, then a linear layer that predicts a
//! local block of `Z · r · r` voxels of `C_v` features per cell. The head's output is the
//! field's table as it is (`render::field`), ordered (height, patch row, patch column,
//! feature); the paper's `(C_v, Z, Y, X)` grid is `VoxelField::to_grid`.
//!
//! Paper size: (4, 96, 96) -> (256, 96, 96) -> (128, 192, 192) -> (4096, 192, 192)
//! -> (16, 64, 384, 384).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::render::VoxelField;
use bevworld_blocks::linear_on_host::linear;
use bevworld_blocks::swin::patch::{PatchExpanding, patch_expanding};
use bevworld_blocks::swin::{SwinBlock, SwinBlockConfig, run_blocks};

#[derive(Config, Debug, PartialEq)]
pub struct VoxelLiftConfig {
    pub latent_channels: usize,
    /// Width after the first linear layer (256 in the paper); halved by patch expanding.
    pub dim: usize,
    /// Swin blocks before and after patch expanding.
    pub depths: [usize; 2],
    pub heads: [usize; 2],
    pub window: usize,
    /// Voxel feature channels C_v (16).
    pub voxel_channels: usize,
    /// Height cells Z (64).
    pub voxel_height: usize,
    /// Horizontal cells each expanded cell predicts along each axis, r (2).
    pub cell_split: usize,
}

impl VoxelLiftConfig {
    /// Channels the last linear layer predicts per cell: C_v * Z * r * r (4096 in the paper).
    pub fn block_channels(&self) -> usize {
        self.voxel_channels * self.voxel_height * self.cell_split * self.cell_split
    }

    /// Voxel grid `[C_v, Z, Y, X]` for a latent of `h x w` cells.
    pub fn voxel_shape(&self, h: usize, w: usize) -> [usize; 4] {
        let scale = 2 * self.cell_split;
        [self.voxel_channels, self.voxel_height, h * scale, w * scale]
    }

    pub fn init(&self, device: &Device) -> VoxelLift {
        let stack = |dim: usize, heads: usize, depth: usize| -> Vec<SwinBlock> {
            (0..depth)
                .map(|i| {
                    SwinBlockConfig::new(dim, heads, self.window)
                        .with_shifted(i % 2 == 1)
                        .init(device)
                })
                .collect()
        };
        VoxelLift {
            input: LinearConfig::new(self.latent_channels, self.dim).init(device),
            before: stack(self.dim, self.heads[0], self.depths[0]),
            expand: patch_expanding(self.dim, device),
            after: stack(self.dim / 2, self.heads[1], self.depths[1]),
            head: LinearConfig::new(self.dim / 2, self.block_channels()).init(device),
            voxel_channels: self.voxel_channels,
            voxel_height: self.voxel_height,
            cell_split: self.cell_split,
        }
    }
}

#[derive(Module, Debug)]
pub struct VoxelLift {
    input: Linear,
    before: Vec<SwinBlock>,
    expand: PatchExpanding,
    after: Vec<SwinBlock>,
    head: Linear,
    #[module(skip)]
    voxel_channels: usize,
    #[module(skip)]
    voxel_height: usize,
    #[module(skip)]
    cell_split: usize,
}

impl VoxelLift {
    /// The voxel field of one latent: `Z` heights and `2h·r × 2w·r` columns of `C_v`
    /// features.
    // [1, C', h, w] -> table [2h * 2w * Z * r * r, C_v]
    pub fn forward(&self, latent: Tensor<4>) -> VoxelField {
        let x = linear(&self.input, latent.permute([0, 2, 3, 1])); // [1, h, w, D]
        let x = run_blocks(&self.before, x);
        let x = self.expand.forward(x); // [1, 2h, 2w, D/2]
        let x = run_blocks(&self.after, x);
        let x = linear(&self.head, x); // [1, 2h, 2w, Z * r * r * C_v]
        VoxelField::from_head(x, self.voxel_channels, self.voxel_height, self.cell_split)
    }
}
