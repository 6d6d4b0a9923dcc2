//! A Swin Transformer backbone: patch embedding, then stages of (regular, shifted) block pairs
//! with patch merging between stages. Shared by all six cameras, and run again on the LiDAR BEV.

use bevworld_types::ConfigProblem;
use burn::prelude::*;

use super::block::{SwinBlock, SwinBlockConfig};
use super::patch::{PatchEmbed, PatchEmbedConfig, PatchMerging, patch_merging};

/// Sizes of a Swin backbone, as the model YAML gives them.
#[derive(Config, Debug, PartialEq)]
pub struct SwinConfig {
    pub in_channels: usize,
    /// Patch side of the embedding.
    pub patch: usize,
    pub embed_dim: usize,
    /// Blocks per stage; the channels double and the resolution halves after each stage but
    /// the last.
    pub depths: Vec<usize>,
    /// Attention heads per stage.
    pub heads: Vec<usize>,
    pub window: usize,
}

impl SwinConfig {
    /// Channels of the last stage.
    pub fn out_channels(&self) -> usize {
        self.embed_dim << self.depths.len().saturating_sub(1)
    }

    /// Input pixels per output cell, along each axis.
    pub fn stride(&self) -> usize {
        self.patch << self.depths.len().saturating_sub(1)
    }

    /// Problems with the sizes, one line each.
    pub fn problems(&self, name: &str) -> Vec<ConfigProblem> {
        let mut problems = Vec::new();
        if self.depths.is_empty() {
            problems.push(ConfigProblem::new(
                format!("{name}.depths"),
                "needs at least one stage",
            ));
        }
        if self.depths.len() != self.heads.len() {
            problems.push(ConfigProblem::new(
                format!("{name}.heads"),
                format!(
                    "{} entries for {} stages",
                    self.heads.len(),
                    self.depths.len()
                ),
            ));
        }
        for (stage, &heads) in self.heads.iter().enumerate() {
            let dim = self.embed_dim << stage;
            if heads == 0 || !dim.is_multiple_of(heads) {
                problems.push(ConfigProblem::new(
                    format!("{name}.heads[{stage}]"),
                    format!("{heads} heads do not divide {dim} channels"),
                ));
            }
        }
        if self.patch == 0 || self.window == 0 || self.embed_dim == 0 || self.in_channels == 0 {
            problems.push(ConfigProblem::new(
                name,
                "patch, window, embed_dim and in_channels must be positive",
            ));
        }
        problems
    }

    pub fn init(&self, device: &Device) -> SwinBackbone {
        let stages = self
            .depths
            .iter()
            .zip(&self.heads)
            .enumerate()
            .map(|(stage, (&depth, &heads))| {
                let dim = self.embed_dim << stage;
                SwinStage {
                    blocks: (0..depth)
                        .map(|i| {
                            SwinBlockConfig::new(dim, heads, self.window)
                                .with_shifted(i % 2 == 1)
                                .init(device)
                        })
                        .collect(),
                    merge: (stage + 1 < self.depths.len()).then(|| patch_merging(dim, device)),
                }
            })
            .collect();
        SwinBackbone {
            embed: PatchEmbedConfig::new(self.in_channels, self.embed_dim, self.patch).init(device),
            stages,
        }
    }
}

#[derive(Module, Debug)]
pub struct SwinStage {
    blocks: Vec<SwinBlock>,
    merge: Option<PatchMerging>,
}

impl SwinStage {
    // [B, H, W, C] -> [B, H, W, C], or [B, H / 2, W / 2, 2C] with merging
    pub fn forward(&self, mut x: Tensor<4>) -> Tensor<4> {
        for block in &self.blocks {
            x = block.forward(x);
        }
        match &self.merge {
            Some(merge) => merge.forward(x),
            None => x,
        }
    }
}

/// Runs a list of Swin blocks over a channels-last map (the decoder's stacks).
pub fn run_blocks(blocks: &[SwinBlock], mut x: Tensor<4>) -> Tensor<4> {
    for block in blocks {
        x = block.forward(x);
    }
    x
}

#[derive(Module, Debug)]
pub struct SwinBackbone {
    embed: PatchEmbed,
    stages: Vec<SwinStage>,
}

impl SwinBackbone {
    /// Channels-first in and out, so that convolutions can follow.
    // [B, C_in, H, W] -> [B, C_out, H / stride, W / stride]
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut h = self.embed.forward(x); // [B, H/p, W/p, C]
        for stage in &self.stages {
            h = stage.forward(h);
        }
        h.permute([0, 3, 1, 2])
    }

    /// `forward`'s output, and the outputs of the `finer` stages before the last, finest
    /// first, channels-first: stage `s` gives `[B, C·2^s, H / (patch·2^s), W / (patch·2^s)]`,
    /// taken after its blocks and before its patch merging.
    pub fn forward_levels(&self, x: Tensor<4>, finer: usize) -> (Tensor<4>, Vec<Tensor<4>>) {
        let mut h = self.embed.forward(x); // [B, H/p, W/p, C]
        let first_kept = self.stages.len().saturating_sub(finer + 1);
        let mut levels = Vec::with_capacity(finer);
        for (index, stage) in self.stages.iter().enumerate() {
            for block in &stage.blocks {
                h = block.forward(h);
            }
            if let Some(merge) = &stage.merge {
                if index >= first_kept {
                    levels.push(h.clone().permute([0, 3, 1, 2]));
                }
                h = merge.forward(h);
            }
        }
        (h.permute([0, 3, 1, 2]), levels)
    }
}
