//! Inference rendering of any number of rays in bounded memory: rays go through the model in
//! chunks, and the per-ray results come back to the host. Training renders its small random
//! ray batches with `Tokenizer::render_rays` directly, keeping the graph for backprop.

use burn::prelude::*;

use crate::config::TokenizerConfig;
use crate::frame_input::FrameRays;
use crate::model::Tokenizer;
use crate::render::field::VoxelField;
use crate::render::march::{AlphaHead, March};
use crate::render::occupancy::Skipping;
use crate::render::rays::{Rays, VoxelPlacement, sample_positions};
use crate::render::rendered::{RenderedRays, host_vec};

/// The camera images of rendered camera rays cast as `rays.camera` is: the background through
/// each ray's transmittance, then the RGB upsampler.
// -> [N_c, 3, H, W] in [0, 1]
pub fn camera_images(
    model: &Tokenizer,
    camera: &RenderedRays,
    rays: &FrameRays,
    device: &Device,
) -> Tensor<4> {
    model.camera_rgb(
        camera.features_tensor(0, camera.rays(), device),
        camera.opacity_tensor(device),
        rays.camera.directions_tensor(device),
        rays.cameras,
        rays.rows,
        rays.columns,
    )
}

/// A voxel field ready to render: the model whose alpha head reads it, the voxels, the fixed
/// sample depths and where the grid sits in the ego frame.
pub struct VoxelScene<'a> {
    pub model: &'a Tokenizer,
    pub voxels: VoxelField,
    pub depths: Vec<f32>,
    pub placement: VoxelPlacement,
    /// Rays per pass through the model, which bounds memory.
    pub chunk: usize,
}

impl<'a> VoxelScene<'a> {
    /// The scene of `voxels` with the sampling the model's config prescribes.
    pub fn new(model: &'a Tokenizer, config: &TokenizerConfig, voxels: VoxelField) -> Self {
        Self {
            model,
            voxels,
            depths: config.render.sample_depths(),
            placement: config.voxel_placement(),
            chunk: 4096,
        }
    }

    pub fn channels(&self) -> usize {
        self.voxels.shape.channels
    }

    /// The RGB upsampler's images of rendered camera rays cast as `rays.camera` is: flat
    /// `[N_c, 3, H, W]` planes in [0, 1], cameras in the frame's order.
    pub fn camera_planes(&self, camera: &RenderedRays, rays: &FrameRays) -> Vec<f32> {
        host_vec(camera_images(
            self.model,
            camera,
            rays,
            &self.voxels.device(),
        ))
    }

    /// The fused CPU renderer of this scene (`render::march`), when the field and the model
    /// are CPU inference tensors.
    pub(crate) fn march<'s>(
        &'s self,
        head: &'s AlphaHead,
        skipping: Option<Skipping<'s>>,
    ) -> Option<March<'s>> {
        Some(March {
            shape: self.voxels.shape,
            table: self.voxels.host_table()?,
            head,
            depths: &self.depths,
            placement: self.placement,
            escape_depth: self.model.escape_depth(),
            skipping,
        })
    }

    /// Renders every ray densely, all samples: on the CPU as one fused host kernel
    /// (`render::march`), elsewhere through the model `chunk` rays at a time.
    pub fn render_dense(&self, rays: &Rays) -> RenderedRays {
        if let Some(head) = self.model.alpha_head_on_host()
            && let Some(march) = self.march(&head, None)
        {
            return march.render(rays);
        }
        let device = self.voxels.device();
        let depths = &self.depths;
        let depth_row =
            Tensor::<2>::from_data(TensorData::new(depths.clone(), [1, depths.len()]), &device);
        let mut out = RenderedRays {
            channels: self.channels(),
            samples_dense: (rays.len() * depths.len()) as u64,
            ..RenderedRays::default()
        };
        let chunk = self.chunk.max(1);
        for start in (0..rays.len()).step_by(chunk) {
            let indices: Vec<usize> = (start..(start + chunk).min(rays.len())).collect();
            let part = rays.subset(&indices);
            let positions = sample_positions(&part, depths, &self.placement);
            let rendered =
                self.model
                    .render_rays(&self.voxels, &positions, part.len(), depth_row.clone());
            out.features.extend(host_vec(rendered.features));
            out.depth.extend(host_vec(rendered.depth));
            out.opacity.extend(host_vec(rendered.opacity));
            out.samples_evaluated += (part.len() * depths.len()) as u64;
        }
        out
    }
}
