//! InceptionV3 as FID uses it: the network of pytorch-fid's `FIDInceptionA/C/E_1/E_2`, whose
//! weights (`pt_inception-2015-12-05-6726825d.pth`) are the TensorFlow FID graph ported to
//! PyTorch. It differs from torchvision's InceptionV3 in two places, both kept here:
//! - the average pools of the A, C and E_1 blocks exclude padding from the mean;
//! - the last block (E_2) pools its side branch with a max, not an average.
//!
//! Field names follow the PyTorch state dict in snake case (`Mixed_5b` is `mixed_5b`), so a
//! weights file maps onto the modules by one key rewrite (see `fid.rs`). Only the pool3 trunk
//! is built: FID reads the 2048-d pooled features, not the classifier.

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{AvgPool2d, AvgPool2dConfig, MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, Initializer, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Input side FID resizes every image to.
pub const INCEPTION_SIZE: usize = 299;
/// Smallest side the network accepts: the last reductions leave a 1 x 1 grid.
pub const MIN_INPUT_SIZE: usize = 75;
/// Width of the pool3 features.
pub const POOL3_FEATURES: usize = 2048;

/// Convolution without bias, batch norm (eps 1e-3, as TensorFlow's), ReLU.
#[derive(Module, Debug)]
pub struct BasicConv2d {
    conv: Conv2d,
    bn: BatchNorm,
}

/// Kernel `[kh, kw]`, stride and symmetric padding `[ph, pw]` of one `BasicConv2d`.
#[derive(Clone, Copy, Debug)]
struct ConvShape {
    kernel: [usize; 2],
    stride: usize,
    padding: [usize; 2],
}

const fn k(kh: usize, kw: usize, ph: usize, pw: usize) -> ConvShape {
    ConvShape {
        kernel: [kh, kw],
        stride: 1,
        padding: [ph, pw],
    }
}

const fn k_stride2(kh: usize, kw: usize) -> ConvShape {
    ConvShape {
        kernel: [kh, kw],
        stride: 2,
        padding: [0, 0],
    }
}

fn basic(input: usize, output: usize, shape: ConvShape, device: &Device) -> BasicConv2d {
    let [ph, pw] = shape.padding;
    BasicConv2d {
        conv: Conv2dConfig::new([input, output], shape.kernel)
            .with_stride([shape.stride, shape.stride])
            .with_padding(PaddingConfig2d::Explicit(ph, pw, ph, pw))
            .with_bias(false)
            // He initialisation keeps a random network's activations alive through all 94
            // layers, so that its features are usable in tests; real weights replace it.
            .with_initializer(Initializer::KaimingNormal {
                gain: std::f64::consts::SQRT_2,
                fan_out_only: false,
            })
            .init(device),
        bn: BatchNormConfig::new(output).with_epsilon(1e-3).init(device),
    }
}

impl BasicConv2d {
    // [B, C_in, H, W] -> [B, C_out, H', W']
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        relu(self.bn.forward(self.conv.forward(x)))
    }
}

/// 3x3 stride-1 average pool over the padded input, dividing by the cells inside the image.
fn avg_pool_3x3_exclude_pad() -> AvgPool2d {
    AvgPool2dConfig::new([3, 3])
        .with_strides([1, 1])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .with_count_include_pad(false)
        .init()
}

fn max_pool_3x3_stride2() -> MaxPool2d {
    MaxPool2dConfig::new([3, 3]).with_strides([2, 2]).init()
}

/// Mixed_5b/c/d: 1x1, 5x5, double 3x3 and pooled branches.
#[derive(Module, Debug)]
pub struct InceptionA {
    branch1x1: BasicConv2d,
    branch5x5_1: BasicConv2d,
    branch5x5_2: BasicConv2d,
    branch3x3dbl_1: BasicConv2d,
    branch3x3dbl_2: BasicConv2d,
    branch3x3dbl_3: BasicConv2d,
    branch_pool: BasicConv2d,
    pool: AvgPool2d,
}

impl InceptionA {
    fn new(input: usize, pool_features: usize, device: &Device) -> Self {
        Self {
            branch1x1: basic(input, 64, k(1, 1, 0, 0), device),
            branch5x5_1: basic(input, 48, k(1, 1, 0, 0), device),
            branch5x5_2: basic(48, 64, k(5, 5, 2, 2), device),
            branch3x3dbl_1: basic(input, 64, k(1, 1, 0, 0), device),
            branch3x3dbl_2: basic(64, 96, k(3, 3, 1, 1), device),
            branch3x3dbl_3: basic(96, 96, k(3, 3, 1, 1), device),
            branch_pool: basic(input, pool_features, k(1, 1, 0, 0), device),
            pool: avg_pool_3x3_exclude_pad(),
        }
    }

    // [B, C_in, H, W] -> [B, 224 + pool_features, H, W]
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let b1 = self.branch1x1.forward(x.clone());
        let b5 = self
            .branch5x5_2
            .forward(self.branch5x5_1.forward(x.clone()));
        let b3 = self.branch3x3dbl_3.forward(
            self.branch3x3dbl_2
                .forward(self.branch3x3dbl_1.forward(x.clone())),
        );
        let pooled = self.pool.forward(x);
        Tensor::cat(vec![b1, b5, b3, self.branch_pool.forward(pooled)], 1)
    }
}

/// Mixed_6a: the first grid reduction, 35x35 -> 17x17: a strided 3x3, a strided double 3x3,
/// and the input max-pooled, concatenated.
#[derive(Module, Debug)]
pub struct InceptionB {
    branch3x3: BasicConv2d,
    branch3x3dbl_1: BasicConv2d,
    branch3x3dbl_2: BasicConv2d,
    branch3x3dbl_3: BasicConv2d,
    pool: MaxPool2d,
}

impl InceptionB {
    fn new(input: usize, device: &Device) -> Self {
        Self {
            branch3x3: basic(input, 384, k_stride2(3, 3), device),
            branch3x3dbl_1: basic(input, 64, k(1, 1, 0, 0), device),
            branch3x3dbl_2: basic(64, 96, k(3, 3, 1, 1), device),
            branch3x3dbl_3: basic(96, 96, k_stride2(3, 3), device),
            pool: max_pool_3x3_stride2(),
        }
    }

    // [B, C_in, H, W] -> [B, 480 + C_in, (H - 3) / 2 + 1, (W - 3) / 2 + 1]
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let b3 = self.branch3x3.forward(x.clone());
        let bd = self.branch3x3dbl_3.forward(
            self.branch3x3dbl_2
                .forward(self.branch3x3dbl_1.forward(x.clone())),
        );
        let bp = self.pool.forward(x);
        Tensor::cat(vec![b3, bd, bp], 1)
    }
}

/// Mixed_6b..e: factorised 7x7 convolutions (1x7 then 7x1).
#[derive(Module, Debug)]
pub struct InceptionC {
    branch1x1: BasicConv2d,
    branch7x7_1: BasicConv2d,
    branch7x7_2: BasicConv2d,
    branch7x7_3: BasicConv2d,
    branch7x7dbl_1: BasicConv2d,
    branch7x7dbl_2: BasicConv2d,
    branch7x7dbl_3: BasicConv2d,
    branch7x7dbl_4: BasicConv2d,
    branch7x7dbl_5: BasicConv2d,
    branch_pool: BasicConv2d,
    pool: AvgPool2d,
}

impl InceptionC {
    fn new(input: usize, c7: usize, device: &Device) -> Self {
        let row = k(1, 7, 0, 3);
        let column = k(7, 1, 3, 0);
        Self {
            branch1x1: basic(input, 192, k(1, 1, 0, 0), device),
            branch7x7_1: basic(input, c7, k(1, 1, 0, 0), device),
            branch7x7_2: basic(c7, c7, row, device),
            branch7x7_3: basic(c7, 192, column, device),
            branch7x7dbl_1: basic(input, c7, k(1, 1, 0, 0), device),
            branch7x7dbl_2: basic(c7, c7, column, device),
            branch7x7dbl_3: basic(c7, c7, row, device),
            branch7x7dbl_4: basic(c7, c7, column, device),
            branch7x7dbl_5: basic(c7, 192, row, device),
            branch_pool: basic(input, 192, k(1, 1, 0, 0), device),
            pool: avg_pool_3x3_exclude_pad(),
        }
    }

    // [B, 768, H, W] -> [B, 768, H, W]
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let b1 = self.branch1x1.forward(x.clone());
        let b7 = self.branch7x7_3.forward(
            self.branch7x7_2
                .forward(self.branch7x7_1.forward(x.clone())),
        );
        let mut bd = self.branch7x7dbl_1.forward(x.clone());
        bd = self.branch7x7dbl_2.forward(bd);
        bd = self.branch7x7dbl_3.forward(bd);
        bd = self.branch7x7dbl_4.forward(bd);
        bd = self.branch7x7dbl_5.forward(bd);
        let bp = self.branch_pool.forward(self.pool.forward(x));
        Tensor::cat(vec![b1, b7, bd, bp], 1)
    }
}

/// Mixed_7a: the second grid reduction, 17x17 -> 8x8.
#[derive(Module, Debug)]
pub struct InceptionD {
    branch3x3_1: BasicConv2d,
    branch3x3_2: BasicConv2d,
    /// 1x1, 1x7 and 7x1, then the strided 3x3.
    branch7x7x3_1: BasicConv2d,
    branch7x7x3_2: BasicConv2d,
    branch7x7x3_3: BasicConv2d,
    branch7x7x3_4: BasicConv2d,
    pool: MaxPool2d,
}

impl InceptionD {
    fn new(input: usize, device: &Device) -> Self {
        Self {
            branch3x3_1: basic(input, 192, k(1, 1, 0, 0), device),
            branch3x3_2: basic(192, 320, k_stride2(3, 3), device),
            branch7x7x3_1: basic(input, 192, k(1, 1, 0, 0), device),
            branch7x7x3_2: basic(192, 192, k(1, 7, 0, 3), device),
            branch7x7x3_3: basic(192, 192, k(7, 1, 3, 0), device),
            branch7x7x3_4: basic(192, 192, k_stride2(3, 3), device),
            pool: max_pool_3x3_stride2(),
        }
    }

    // [B, 768, H, W] -> [B, 1280, (H - 3) / 2 + 1, (W - 3) / 2 + 1]
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let b3 = self
            .branch3x3_2
            .forward(self.branch3x3_1.forward(x.clone()));
        let mut b7 = self.branch7x7x3_1.forward(x.clone());
        b7 = self.branch7x7x3_2.forward(b7);
        b7 = self.branch7x7x3_3.forward(b7);
        b7 = self.branch7x7x3_4.forward(b7);
        let bp = self.pool.forward(x);
        Tensor::cat(vec![b3, b7, bp], 1)
    }
}

/// How an E block pools its side branch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SidePool {
    /// Mixed_7b: a 3x3 average that excludes padding.
    AverageExcludingPad,
    /// Mixed_7c: a 3x3 max (the TensorFlow FID graph's quirk).
    Max,
}

/// Mixed_7b/c: expanded filter banks (1x3 and 3x1 side by side).
#[derive(Module, Debug)]
pub struct InceptionE {
    branch1x1: BasicConv2d,
    branch3x3_1: BasicConv2d,
    branch3x3_2a: BasicConv2d,
    branch3x3_2b: BasicConv2d,
    branch3x3dbl_1: BasicConv2d,
    branch3x3dbl_2: BasicConv2d,
    branch3x3dbl_3a: BasicConv2d,
    branch3x3dbl_3b: BasicConv2d,
    branch_pool: BasicConv2d,
    average: AvgPool2d,
    max: MaxPool2d,
    #[module(skip)]
    max_pool_side: bool,
}

impl InceptionE {
    fn new(input: usize, side_pool: SidePool, device: &Device) -> Self {
        Self {
            branch1x1: basic(input, 320, k(1, 1, 0, 0), device),
            branch3x3_1: basic(input, 384, k(1, 1, 0, 0), device),
            branch3x3_2a: basic(384, 384, k(1, 3, 0, 1), device),
            branch3x3_2b: basic(384, 384, k(3, 1, 1, 0), device),
            branch3x3dbl_1: basic(input, 448, k(1, 1, 0, 0), device),
            branch3x3dbl_2: basic(448, 384, k(3, 3, 1, 1), device),
            branch3x3dbl_3a: basic(384, 384, k(1, 3, 0, 1), device),
            branch3x3dbl_3b: basic(384, 384, k(3, 1, 1, 0), device),
            branch_pool: basic(input, 192, k(1, 1, 0, 0), device),
            average: avg_pool_3x3_exclude_pad(),
            max: MaxPool2dConfig::new([3, 3])
                .with_strides([1, 1])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(),
            max_pool_side: side_pool == SidePool::Max,
        }
    }

    // [B, C_in, H, W] -> [B, 2048, H, W]
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let b1 = self.branch1x1.forward(x.clone());
        let b3 = self.branch3x3_1.forward(x.clone());
        let b3 = Tensor::cat(
            vec![
                self.branch3x3_2a.forward(b3.clone()),
                self.branch3x3_2b.forward(b3),
            ],
            1,
        );
        let bd = self
            .branch3x3dbl_2
            .forward(self.branch3x3dbl_1.forward(x.clone()));
        let bd = Tensor::cat(
            vec![
                self.branch3x3dbl_3a.forward(bd.clone()),
                self.branch3x3dbl_3b.forward(bd),
            ],
            1,
        );
        let pooled = if self.max_pool_side {
            self.max.forward(x)
        } else {
            self.average.forward(x)
        };
        let bp = self.branch_pool.forward(pooled);
        Tensor::cat(vec![b1, b3, bd, bp], 1)
    }
}

/// The FID InceptionV3 trunk, up to the 2048-d average-pooled features.
#[derive(Module, Debug)]
pub struct InceptionV3 {
    conv2d_1a_3x3: BasicConv2d,
    conv2d_2a_3x3: BasicConv2d,
    conv2d_2b_3x3: BasicConv2d,
    conv2d_3b_1x1: BasicConv2d,
    conv2d_4a_3x3: BasicConv2d,
    mixed_5b: InceptionA,
    mixed_5c: InceptionA,
    mixed_5d: InceptionA,
    mixed_6a: InceptionB,
    mixed_6b: InceptionC,
    mixed_6c: InceptionC,
    mixed_6d: InceptionC,
    mixed_6e: InceptionC,
    mixed_7a: InceptionD,
    mixed_7b: InceptionE,
    mixed_7c: InceptionE,
    pool: MaxPool2d,
}

impl InceptionV3 {
    /// Randomly initialised; load real weights with `fid::load_inception`.
    pub fn init(device: &Device) -> Self {
        Self {
            conv2d_1a_3x3: basic(3, 32, k_stride2(3, 3), device),
            conv2d_2a_3x3: basic(32, 32, k(3, 3, 0, 0), device),
            conv2d_2b_3x3: basic(32, 64, k(3, 3, 1, 1), device),
            conv2d_3b_1x1: basic(64, 80, k(1, 1, 0, 0), device),
            conv2d_4a_3x3: basic(80, 192, k(3, 3, 0, 0), device),
            mixed_5b: InceptionA::new(192, 32, device),
            mixed_5c: InceptionA::new(256, 64, device),
            mixed_5d: InceptionA::new(288, 64, device),
            mixed_6a: InceptionB::new(288, device),
            mixed_6b: InceptionC::new(768, 128, device),
            mixed_6c: InceptionC::new(768, 160, device),
            mixed_6d: InceptionC::new(768, 160, device),
            mixed_6e: InceptionC::new(768, 192, device),
            mixed_7a: InceptionD::new(768, device),
            mixed_7b: InceptionE::new(1280, SidePool::AverageExcludingPad, device),
            mixed_7c: InceptionE::new(2048, SidePool::Max, device),
            pool: max_pool_3x3_stride2(),
        }
    }

    /// Pool3 features of images already scaled to [-1, 1].
    // [B, 3, 299, 299] -> [B, 2048]
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        let x = self.conv2d_1a_3x3.forward(x); // [B, 32, 149, 149]
        let x = self.conv2d_2a_3x3.forward(x); // [B, 32, 147, 147]
        let x = self.conv2d_2b_3x3.forward(x); // [B, 64, 147, 147]
        let x = self.pool.forward(x); // [B, 64, 73, 73]
        let x = self.conv2d_3b_1x1.forward(x); // [B, 80, 73, 73]
        let x = self.conv2d_4a_3x3.forward(x); // [B, 192, 71, 71]
        let x = self.pool.forward(x); // [B, 192, 35, 35]
        let x = self.mixed_5b.forward(x); // [B, 256, 35, 35]
        let x = self.mixed_5c.forward(x); // [B, 288, 35, 35]
        let x = self.mixed_5d.forward(x); // [B, 288, 35, 35]
        let x = self.mixed_6a.forward(x); // [B, 768, 17, 17]
        let x = self.mixed_6b.forward(x);
        let x = self.mixed_6c.forward(x);
        let x = self.mixed_6d.forward(x);
        let x = self.mixed_6e.forward(x); // [B, 768, 17, 17]
        let x = self.mixed_7a.forward(x); // [B, 1280, 8, 8]
        let x = self.mixed_7b.forward(x); // [B, 2048, 8, 8]
        let x = self.mixed_7c.forward(x); // [B, 2048, 8, 8]
        let [batch, channels, _, _] = x.dims();
        x.mean_dim(3).mean_dim(2).reshape([batch, channels]) // [B, 2048]
    }
}
