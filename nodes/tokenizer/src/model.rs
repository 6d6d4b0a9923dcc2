//! The assembled tokenizer: six cameras and a pillarised sweep in, a 4-channel BEV latent out;
//! the latent lifted to voxels and rendered along any subset of rays.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::config::TokenizerConfig;
use crate::decoder::{Background, BackgroundConfig, RgbUpsampler, RgbUpsamplerConfig, VoxelLift};
use crate::encoder::fusion::{DeformableFusion, DeformableFusionConfig};
use crate::encoder::{PillarNet, PillarNetConfig, scatter_to_bev};
use crate::latent::{LatentCompress, LatentCompressConfig};
use crate::modality::Modality;
use crate::render::{
    AlphaHead, VoxelField, expected_depth, expected_feature, render_weights, sample_trilinear,
};
use bevworld_blocks::host::inference_values;
use bevworld_blocks::seeded_init;
use bevworld_blocks::swin::SwinBackbone;

/// What the encoder reads for one frame.
pub struct EncoderInput {
    /// Camera images in [0, 1] at the config's `image_size`: `[N_c, 3, H, W]`.
    pub images: Tensor<4>,
    /// Padded pillar points `[P, N, 9]` and their validity `[P, N]`.
    pub pillar_points: Tensor<3>,
    pub pillar_valid: Tensor<2>,
    /// Row-major pillar-grid cell of each pillar, `[P]`.
    pub pillar_cells: Tensor<1, Int>,
    /// The fusion's reference points in each camera, `[N_c, Q, K, 2]`, and their validity
    /// `[N_c, Q, K]`, with Q the latent cells (see `encoder::projection`).
    pub reference: Tensor<4>,
    pub reference_valid: Tensor<3>,
}

/// The encoder's outputs.
pub struct Encoded {
    /// `[1, C', h, w]`.
    pub latent: Tensor<4>,
    /// The fused BEV feature before compression, `[1, C, h, w]`.
    pub fused: Tensor<4>,
}

/// What rendering a batch of rays gives.
pub struct RayRender {
    /// Expected voxel feature per ray, `[R, C_v]`.
    pub features: Tensor<2>,
    /// Expected depth per ray, `[R]`.
    pub depth: Tensor<1>,
    /// Sum of the weights (1 − final transmittance) per ray, `[R]`.
    pub opacity: Tensor<1>,
    /// Render weight of every sample, `[R, S]`.
    pub weights: Tensor<2>,
}

#[derive(Module, Debug)]
pub struct Tokenizer {
    image_backbone: SwinBackbone,
    pillar_net: PillarNet,
    lidar_backbone: SwinBackbone,
    fusion: DeformableFusion,
    compress: LatentCompress,
    lift: VoxelLift,
    alpha_hidden: Linear,
    alpha_out: Linear,
    upsampler: RgbUpsampler,
    background: Option<Background>,
    #[module(skip)]
    pillar_grid: usize,
    #[module(skip)]
    pillar_channels: usize,
    /// Image backbone stages the fusion reads (`fusion_levels`).
    #[module(skip)]
    fusion_levels: usize,
    /// The encoder reads the cameras (fusion) and the sweep (pillars); an ablation model reads
    /// one of them.
    #[module(skip)]
    reads_camera: bool,
    #[module(skip)]
    reads_lidar: bool,
    /// The depth a ray's remaining transmittance adds (`render.escape_at_far`: `far`, else 0).
    #[module(skip)]
    escape_depth: f32,
}

impl TokenizerConfig {
    /// The model with weights drawn from `seed`: the same seed gives the same weights, whatever
    /// else the process does (`bevworld_blocks::seeded_init`). Check `problems()` first
    /// (`from_yaml` does).
    pub fn init_seeded(&self, seed: u64, device: &Device) -> Tokenizer {
        seeded_init(seed, device, |device| self.init(device))
    }

    /// The model's structure, its parameters drawn lazily from burn's process-wide generator at
    /// their first use: for loading weights into, which replaces them undrawn. A model that
    /// runs with its initial weights comes from `init_seeded`.
    pub fn init(&self, device: &Device) -> Tokenizer {
        let voxel_channels = self.decoder.voxel_channels;
        Tokenizer {
            image_backbone: self.image_backbone.init(device),
            pillar_net: PillarNetConfig::new(self.pillar_channels).init(device),
            lidar_backbone: self.lidar_backbone.init(device),
            fusion: DeformableFusionConfig::new(
                self.fused_channels(),
                self.image_backbone.out_channels(),
                self.cameras,
                self.fusion_heights,
            )
            .with_fine_channels(self.fusion_fine_channels())
            .init(device),
            compress: LatentCompressConfig::new(self.fused_channels(), self.latent_channels)
                .init(device),
            lift: self.decoder.init(device),
            alpha_hidden: LinearConfig::new(voxel_channels, self.render.alpha_hidden).init(device),
            alpha_out: LinearConfig::new(self.render.alpha_hidden, 1).init(device),
            upsampler: RgbUpsamplerConfig::new(
                voxel_channels,
                self.render.upsampler_hidden,
                self.render.camera_stride.trailing_zeros() as usize,
            )
            .init(device),
            background: (self.render.background_hidden > 0).then(|| {
                BackgroundConfig::new(self.render.background_hidden, voxel_channels).init(device)
            }),
            pillar_grid: self.bev.pillar_grid,
            pillar_channels: self.pillar_channels,
            fusion_levels: self.fusion_levels.max(1),
            reads_camera: self.uses(Modality::Camera),
            reads_lidar: self.uses(Modality::Lidar),
            escape_depth: if self.render.escape_at_far {
                self.render.far as f32
            } else {
                0.0
            },
        }
    }
}

impl Tokenizer {
    /// A camera-only model reads an empty pillar grid, so its BEV queries carry no LiDAR and
    /// learn everything from the images; a LiDAR-only model skips the cameras and the fusion.
    pub fn encode(&self, input: EncoderInput) -> Encoded {
        let bev = if self.reads_lidar {
            let pillars = self
                .pillar_net
                .forward(input.pillar_points, input.pillar_valid); // [P, C_p]
            scatter_to_bev(
                pillars,
                input.pillar_cells,
                self.pillar_grid,
                self.pillar_grid,
            )
        } else {
            Tensor::zeros(
                [1, self.pillar_channels, self.pillar_grid, self.pillar_grid],
                &input.images.device(),
            )
        }; // [1, C_p, G, G]
        let lidar = self.lidar_backbone.forward(bev); // [1, C, h, w]
        let fused = if self.reads_camera {
            // [N_c, C_img, h_i, w_i], and the finer stages' maps before it
            let (image_features, fine) = self
                .image_backbone
                .forward_levels(input.images, self.fusion_levels - 1);
            self.fusion.forward(
                lidar,
                image_features,
                fine,
                input.reference,
                input.reference_valid,
            )
        } else {
            lidar
        };
        Encoded {
            latent: self.compress.forward(fused.clone()),
            fused,
        }
    }

    /// The voxel field of a latent.
    // [1, C', h, w] -> table [Z * Y * X, C_v]
    pub fn voxels(&self, latent: Tensor<4>) -> VoxelField {
        self.lift.forward(latent)
    }

    /// Renders `rays` rays of `S` samples each. `positions` are the samples in voxel units, ray
    /// by ray (`render::rays::sample_positions`), `depths` the samples' distances along the
    /// ray.
    // positions: R * S points, depths [1, S] or [R, S]
    pub fn render_rays(
        &self,
        field: &VoxelField,
        positions: &[[f32; 3]],
        rays: usize,
        depths: Tensor<2>,
    ) -> RayRender {
        let [_, samples] = depths.dims();
        let features = sample_trilinear(field, positions); // [R * S, C_v]
        let [_, channels] = features.dims();
        let features = features.reshape([rays, samples, channels]);
        let logits = self.alpha_logits(features.clone()); // [R, S]
        let weights = render_weights(logits); // [R, S]
        let opacity = weights.clone().sum_dim(1).reshape([rays]); // [R]
        let depth = expected_depth(weights.clone(), depths); // [R]
        let depth = if self.escape_depth > 0.0 {
            depth
                + opacity
                    .clone()
                    .neg()
                    .add_scalar(1.0)
                    .mul_scalar(self.escape_depth)
        } else {
            depth
        };
        RayRender {
            opacity,
            depth,
            features: expected_feature(weights.clone(), features),
            weights,
        }
    }

    /// The model with its encoder (backbones, pillar net, fusion, compression) taking no
    /// gradients: a fine-tune of the decoder alone. The latent of every frame, and with it
    /// everything paired with the latent (its statistics, a world model, exported features,
    /// detectors), stays what it was; only how a latent is rendered changes.
    pub fn with_encoder_fixed(self) -> Self {
        Self {
            image_backbone: self.image_backbone.no_grad(),
            pillar_net: self.pillar_net.no_grad(),
            lidar_backbone: self.lidar_backbone.no_grad(),
            fusion: self.fusion.no_grad(),
            compress: self.compress.no_grad(),
            ..self
        }
    }

    /// This model's decoder behind `source`'s encoder. A decoder fine-tune's weight average
    /// takes the encoder from the iterate, so that the shipped encoder is bit for bit the one
    /// it started from (an average of a constant is the constant only up to rounding).
    pub fn with_encoder_of(self, source: &Tokenizer) -> Self {
        Self {
            image_backbone: source.image_backbone.clone(),
            pillar_net: source.pillar_net.clone(),
            lidar_backbone: source.lidar_backbone.clone(),
            fusion: source.fusion.clone(),
            compress: source.compress.clone(),
            ..self
        }
    }

    /// The depth a ray's remaining transmittance adds to its expected depth (`far` with
    /// `render.escape_at_far`, else 0).
    pub fn escape_depth(&self) -> f32 {
        self.escape_depth
    }

    /// The alpha head's weights on the host, for the CPU's fused renderer (`render::march`);
    /// `None` under autodiff or on another device, where rendering runs on tensors.
    pub fn alpha_head_on_host(&self) -> Option<AlphaHead> {
        let hidden = self.alpha_hidden.weight.val().dims()[1];
        let bias = |linear: &Linear, size: usize| match &linear.bias {
            Some(bias) => inference_values(&bias.val()),
            None => Some(vec![0.0; size]),
        };
        Some(AlphaHead {
            hidden_weight: inference_values(&self.alpha_hidden.weight.val())?,
            hidden_bias: bias(&self.alpha_hidden, hidden)?,
            out_weight: inference_values(&self.alpha_out.weight.val())?,
            out_bias: bias(&self.alpha_out, 1)?.first().copied().unwrap_or(0.0),
        })
    }

    /// Alpha logits `s` of voxel features (α = σ(s)): the density head every sample shares.
    // [R, S, C_v] -> [R, S]
    pub fn alpha_logits(&self, features: Tensor<3>) -> Tensor<2> {
        let [rays, samples, _] = features.dims();
        self.alpha_out
            .forward(relu(self.alpha_hidden.forward(features)))
            .reshape([rays, samples])
    }

    /// RGB images from the rendered features of every camera ray, rays row by row per camera:
    /// the background (when the model has one) seen through each ray's remaining transmittance
    /// `1 − opacity`, then the upsampler.
    // features [N_c * h_r * w_r, C_v], opacity [N_c * h_r * w_r], directions [N_c * h_r * w_r, 3]
    // -> [N_c, 3, h_r * stride, w_r * stride]
    pub fn camera_rgb(
        &self,
        features: Tensor<2>,
        opacity: Tensor<1>,
        directions: Tensor<2>,
        cameras: usize,
        rows: usize,
        columns: usize,
    ) -> Tensor<4> {
        let features = match &self.background {
            Some(background) => background.composite(features, opacity, directions),
            None => features,
        };
        let [_, channels] = features.dims();
        let grid = features
            .reshape([cameras, rows, columns, channels])
            .permute([0, 3, 1, 2]);
        self.upsampler.forward(grid)
    }
}
