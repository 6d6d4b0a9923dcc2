//! The detector: a Swin trunk over the BEV map (`bevworld_blocks::swin`), then three
//! CenterPoint heads on its grid (Yin et al. 2021, "Center-based 3D Object Detection and
//! Tracking"), each a 3×3 convolution, ReLU and a 1×1 convolution:
//!
//! - the heatmap: one channel per class, a box's centre at the peak of its Gaussian;
//! - the box: centre offset in the cell, centre height, log size, sin and cos of the yaw,
//!   velocity (`BOX_CHANNELS`);
//! - the motion: K trajectory modes of T (x, y) offsets from the box's centre, and K logits.
//!
//! The paper's own head is query-based (500 queries matched by the Hungarian algorithm); a
//! centre heatmap reads the same BEV feature with a dense head, and trains on two CPU cores.

use burn::module::Param;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::config::{BOX_CHANNELS, DetectorConfig, InputSpec};
use bevworld_blocks::swin::SwinBackbone;

/// The heatmap logits' initial bias: every cell starts at a prior of 0.1 (CenterNet's), so
/// the empty cells' loss does not swamp the first steps.
pub const HEATMAP_PRIOR: f64 = 0.1;

/// What the heads give for a batch, on the output grid.
pub struct HeadOutputs {
    /// Heatmap logits, `[B, classes, H, W]`.
    pub heatmap: Tensor<4>,
    /// `[B, BOX_CHANNELS, H, W]`.
    pub boxes: Tensor<4>,
    /// `[B, K·(2T + 1), H, W]`: K modes of T offsets (x, y interleaved), then K logits.
    pub motion: Tensor<4>,
}

#[derive(Module, Debug)]
pub struct Head {
    hidden: Conv2d,
    out: Conv2d,
}

impl Head {
    fn new(input: usize, hidden: usize, output: usize, device: &Device) -> Self {
        Self {
            hidden: Conv2dConfig::new([input, hidden], [3, 3])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(device),
            out: Conv2dConfig::new([hidden, output], [1, 1]).init(device),
        }
    }

    // [B, C, H, W] -> [B, out, H, W]
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.out.forward(relu(self.hidden.forward(x)))
    }
}

#[derive(Module, Debug)]
pub struct Detector {
    trunk: SwinBackbone,
    heatmap: Head,
    boxes: Head,
    motion: Head,
}

impl DetectorConfig {
    /// A fresh detector for `input` (its channels times its frames, on its grid).
    pub fn init(&self, input: &InputSpec, device: &Device) -> Detector {
        let swin = self.swin(input.channels * input.frames, self.patch_for(input));
        let width = swin.out_channels();
        let mut heatmap = Head::new(width, self.head_hidden, self.classes.len(), device);
        let prior = -((1.0 - HEATMAP_PRIOR) / HEATMAP_PRIOR).ln();
        heatmap.out.bias = Some(Param::from_tensor(Tensor::full(
            [self.classes.len()],
            prior,
            device,
        )));
        Detector {
            trunk: swin.init(device),
            heatmap,
            boxes: Head::new(width, self.head_hidden, BOX_CHANNELS, device),
            motion: Head::new(width, self.head_hidden, self.motion_channels(), device),
        }
    }
}

impl Detector {
    /// `input`: standardised maps of every frame stacked on the channels, the current frame
    /// first.
    // [B, C·F, H_in, W_in] -> heads on [B, *, H, W]
    pub fn forward(&self, input: Tensor<4>) -> HeadOutputs {
        let features = self.trunk.forward(input); // [B, D, H, W]
        HeadOutputs {
            heatmap: self.heatmap.forward(features.clone()),
            boxes: self.boxes.forward(features.clone()),
            motion: self.motion.forward(features),
        }
    }
}
