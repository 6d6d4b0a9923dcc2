//! Floating-point operations of the tokenizer, counted analytically from its config: a
//! multiply-add is 2 FLOPs; normalisations, activations and softmax are left out (they are a
//! few percent of the matmuls at these widths). The benchmark divides these counts by measured
//! times to report the achieved GFLOP/s against the machine's matmul rate.

use crate::config::TokenizerConfig;
use bevworld_blocks::swin::SwinConfig;

/// Swin blocks' MLP expansion (`SwinBlockConfig::mlp_ratio`'s default).
const MLP_RATIO: f64 = 4.0;

/// FLOPs of one Swin block over an `h x w` map of `dim` channels: the map is padded to whole
/// windows, and every token attends to the `window²` tokens of its window.
pub fn swin_block(dim: usize, window: usize, h: usize, w: usize) -> f64 {
    let padded = (h.div_ceil(window) * window * w.div_ceil(window) * window) as f64;
    let (c, m) = (dim as f64, (window * window) as f64);
    let qkv = 2.0 * padded * c * 3.0 * c;
    let attention = 2.0 * 2.0 * padded * m * c; // Q Kᵀ and A V
    let projection = 2.0 * padded * c * c;
    let mlp = 2.0 * 2.0 * padded * c * MLP_RATIO * c;
    qkv + attention + projection + mlp
}

/// FLOPs of a Swin backbone on `batch` maps of `h x w`.
pub fn swin_backbone(config: &SwinConfig, batch: usize, h: usize, w: usize) -> f64 {
    let (mut h, mut w) = (h / config.patch, w / config.patch);
    let p2 = (config.patch * config.patch) as f64;
    let mut total = 2.0 * (h * w) as f64 * p2 * config.in_channels as f64 * config.embed_dim as f64;
    for (stage, &depth) in config.depths.iter().enumerate() {
        let dim = config.embed_dim << stage;
        total += depth as f64 * swin_block(dim, config.window, h, w);
        if stage + 1 < config.depths.len() {
            (h, w) = (h / 2, w / 2);
            total += 2.0 * (h * w) as f64 * (4 * dim) as f64 * (2 * dim) as f64;
        }
    }
    batch as f64 * total
}

/// FLOPs of a 3x3 convolution, `input -> output` channels, over `h x w`.
fn conv3x3(input: usize, output: usize, h: usize, w: usize) -> f64 {
    2.0 * 9.0 * (input * output * h * w) as f64
}

/// The tokenizer's FLOPs by stage.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TokenizerFlops {
    pub image_backbone: f64,
    pub pillar_net: f64,
    pub lidar_backbone: f64,
    pub fusion: f64,
    pub compress: f64,
    /// Latent to voxels.
    pub lift: f64,
    /// One ray sample: trilinear gather of 8 corners, the alpha head, and compositing.
    pub per_sample: f64,
    /// The RGB upsampler for one camera.
    pub upsampler_per_camera: f64,
}

impl TokenizerFlops {
    /// Counts for a frame of `pillars` non-empty pillars of `points_per_pillar` slots.
    pub fn of(config: &TokenizerConfig, pillars: usize, points_per_pillar: usize) -> Self {
        let [h, w] = config.image_size;
        let n = config.latent_size();
        let q = (n * n) as f64;
        let c = config.fused_channels() as f64;
        let cameras = config.cameras as f64;
        let k = config.fusion_heights as f64;
        let [fh, fw] = config.image_feature_size();
        let c_img = config.image_backbone.out_channels() as f64;
        let grid = config.bev.pillar_grid;
        let decoder = &config.decoder;
        let dim = decoder.dim;
        let c_v = decoder.voxel_channels as f64;
        let hidden = config.render.alpha_hidden as f64;
        let stride = config.render.camera_stride;
        let (rows, columns) = (h / stride, w / stride);
        let u = config.render.upsampler_hidden;

        let fusion = 2.0 * cameras * (fh * fw) as f64 * c_img * c // value projection
            + 2.0 * q * c * cameras * k * 3.0 // offsets (2) and attention weights (1)
            + 2.0 * cameras * q * k * c * 4.0 // bilinear sampling of 4 texels
            + 2.0 * q * c * c // output projection
            + config
                .fusion_fine_channels()
                .iter()
                .enumerate()
                .map(|(level, &c_l)| {
                    // the finer levels, finest first: each twice the size of the next
                    let finer = 1usize << (config.fusion_fine_channels().len() - level);
                    2.0 * cameras * (fh * fw * finer * finer) as f64 * c_l as f64 * c
                        + 2.0 * cameras * q * k * c * 4.0
                })
                .sum::<f64>();
        let lift = 2.0 * q * config.latent_channels as f64 * dim as f64
            + decoder.depths[0] as f64 * swin_block(dim, decoder.window, n, n)
            + 2.0 * q * (dim * 2 * dim) as f64 // patch expanding
            + decoder.depths[1] as f64 * swin_block(dim / 2, decoder.window, 2 * n, 2 * n)
            + 2.0 * 4.0 * q * (dim / 2) as f64 * decoder.block_channels() as f64;
        let mut upsampler = conv3x3(decoder.voxel_channels, u, rows, columns);
        let (mut r, mut cl) = (rows, columns);
        for _ in 0..stride.trailing_zeros() {
            (r, cl) = (2 * r, 2 * cl);
            upsampler += conv3x3(u, u, r, cl);
        }
        upsampler += conv3x3(u, 3, r, cl);
        Self {
            image_backbone: swin_backbone(&config.image_backbone, config.cameras, h, w),
            pillar_net: 2.0
                * (pillars * points_per_pillar) as f64
                * 9.0
                * config.pillar_channels as f64,
            lidar_backbone: swin_backbone(&config.lidar_backbone, 1, grid, grid),
            fusion,
            compress: 2.0 * q * c * config.latent_channels as f64,
            lift,
            per_sample: 2.0 * 8.0 * c_v + 2.0 * (c_v * hidden + hidden) + 2.0 * (c_v + 1.0),
            upsampler_per_camera: upsampler,
        }
    }

    pub fn encoder(&self) -> f64 {
        self.image_backbone + self.pillar_net + self.lidar_backbone + self.fusion + self.compress
    }

    /// Rendering `samples` samples (summed over rays) and `cameras` upsampled images.
    pub fn render(&self, samples: u64, cameras: usize) -> f64 {
        samples as f64 * self.per_sample + cameras as f64 * self.upsampler_per_camera
    }
}
