//! `render`: a BEV latent back to six camera images and one LiDAR sweep, casting the rays of
//! the frame it stands for (its cameras' calibration, its real LiDAR beam directions).
//!
//! Outputs: `images` (the reconstructions, named by camera), `lidar` (the rendered sweep in
//! the LiDAR frame, one point per input return off the ego vehicle, with that return's ring),
//! and `side_by_side`
//! (input | reconstruction per camera, at the model's image size).

use std::sync::Arc;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, Outputs, ParamError, PortSpec, Registry, Task,
};
use bevworld_types::{BevFeatures, ImageSet, LidarPoint, NamedImage, PointCloud, SensorFrame};
use burn::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::frame_input::{FrameInputs, FrameRays, image_planes, planes_to_image};
use crate::modality::Modality;
use crate::nodes::loaded_model::{LoadedModel, ModelParams};
use crate::render::rays::Rays;
use crate::render::{OccupancyGrid, RenderedRays, SkipOptions, VoxelScene, camera_images};

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RenderParams {
    #[serde(flatten)]
    pub model: ModelParams,
    /// Empty-space skipping and early ray stop; absent renders every sample.
    #[serde(default)]
    pub skipping: Option<SkipOptions>,
    /// Rays per pass through the model (bounds memory).
    #[serde(default = "default_chunk")]
    pub chunk: usize,
}

fn default_chunk() -> usize {
    4096
}

pub struct RenderNode {
    loaded: LoadedModel,
    inputs: FrameInputs,
    skipping: Option<SkipOptions>,
    chunk: usize,
    samples_evaluated: u64,
    samples_dense: u64,
    warned_hash: bool,
}

impl RenderNode {
    fn latent_tensor(&mut self, latent: &BevFeatures) -> Result<Tensor<4>, NodeError> {
        let config = &self.loaded.config;
        let (c, n) = (config.latent_channels, config.latent_size());
        if latent.model != config.name {
            return Err(NodeError::item(format!(
                "the latent of frame {} comes from model '{}', but this node renders with '{}': give both the same `model`",
                latent.meta.frame_token, latent.model, config.name
            )));
        }
        if latent.channels.len() != c
            || (latent.grid.height, latent.grid.width) != (n, n)
            || latent.data.len() != c * n * n
        {
            return Err(NodeError::item(format!(
                "the latent of frame {} is {} x {} x {} with {} values; '{}' renders {c} x {n} x {n}",
                latent.meta.frame_token,
                latent.channels.len(),
                latent.grid.height,
                latent.grid.width,
                latent.data.len(),
                config.name
            )));
        }
        if latent.weights_hash != self.loaded.weights_hash && !self.warned_hash {
            self.warned_hash = true;
            tracing::warn!(
                latent = %latent.weights_hash,
                renderer = %self.loaded.weights_hash,
                "the latent was encoded with other weights than this renderer's"
            );
        }
        Ok(Tensor::from_data(
            TensorData::new(latent.data.clone(), [1, c, n, n]),
            &self.loaded.device,
        ))
    }
}

/// Renders `rays` with skipping when it is configured, densely otherwise.
fn render_rays(
    scene: &VoxelScene,
    skipping: Option<(&OccupancyGrid, &SkipOptions)>,
    rays: &Rays,
) -> RenderedRays {
    match skipping {
        Some((grid, options)) => scene.render_skipping(grid, rays, options),
        None => scene.render_dense(rays),
    }
}

impl RenderNode {
    /// Which of the model's two renders anything listens to. Asking a single-modality
    /// (ablation) model for the other one is an error: that half of its decoder never trained.
    fn wanted(&self, out: &Outputs) -> Result<(bool, bool), NodeError> {
        let config = &self.loaded.config;
        let images = out.is_connected("images") || out.is_connected("side_by_side");
        let lidar = out.is_connected("lidar");
        for (wanted, modality, ports) in [
            (images, Modality::Camera, "`images`/`side_by_side`"),
            (lidar, Modality::Lidar, "`lidar`"),
        ] {
            if wanted && !config.uses(modality) {
                return Err(NodeError::fatal(format!(
                    "render: {ports} is connected, but model '{}' was trained without the {} (modalities: {}), so it cannot render them; disconnect the port or use a model that renders both",
                    config.name,
                    modality.plural(),
                    config
                        .modalities
                        .iter()
                        .map(|m| m.name())
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
        }
        Ok((images, lidar))
    }

    /// The camera renders through the upsampler, as `images` and, when connected, as
    /// `side_by_side` pairs.
    fn send_images(
        &self,
        frame: &SensorFrame,
        camera: &RenderedRays,
        rays: &FrameRays,
        out: &mut Outputs,
    ) -> Result<(), NodeError> {
        let rgb = camera_images(&self.loaded.model, camera, rays, &self.loaded.device);
        let [h, w] = self.loaded.config.image_size;
        let planes = rgb
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|error| NodeError::item(format!("reading the images back: {error:?}")))?;
        let mut images = ImageSet::default();
        let mut side_by_side = ImageSet::default();
        for (c, input) in frame.cameras.iter().enumerate() {
            let name = input.channel.name().to_string();
            let reconstruction = planes_to_image(&planes[c * 3 * h * w..(c + 1) * 3 * h * w], w, h);
            if out.is_connected("side_by_side") {
                let original = planes_to_image(&image_planes(&input.image, w, h), w, h);
                let mut pair = image::RgbImage::new(2 * w as u32, h as u32);
                image::imageops::replace(&mut pair, &original, 0, 0);
                image::imageops::replace(&mut pair, &reconstruction, w as i64, 0);
                side_by_side.images.push(NamedImage {
                    name: name.clone(),
                    image: Arc::new(pair),
                });
            }
            images.images.push(NamedImage {
                name,
                image: Arc::new(reconstruction),
            });
        }

        if out.is_connected("side_by_side") {
            out.send("side_by_side", side_by_side)?;
        }
        out.send("images", images)
    }
}

/// The rendered depths along the sweep's rays as points in the LiDAR frame, each with the ring
/// of the return its ray came from.
fn rendered_sweep(frame: &SensorFrame, lidar: &RenderedRays, rays: &FrameRays) -> PointCloud {
    let cloud = &frame.lidar;
    let lidar_from_ego = cloud.ego_from_lidar.inverse();
    let points = rays
        .lidar
        .directions
        .iter()
        .zip(&lidar.depth)
        .zip(&rays.lidar_points)
        .map(|((d, &depth), &index)| {
            let direction =
                lidar_from_ego.transform_vector3(DVec3::new(d[0].into(), d[1].into(), d[2].into()));
            let p = direction * f64::from(depth);
            LidarPoint {
                x: p.x as f32,
                y: p.y as f32,
                z: p.z as f32,
                intensity: 0.0,
                ring: cloud.points.get(index).map_or(0, |p| p.ring),
            }
        })
        .collect();
    PointCloud {
        points,
        ego_from_lidar: cloud.ego_from_lidar,
        timestamp_us: cloud.timestamp_us,
        global_from_ego: cloud.global_from_ego,
        dropped_non_finite: 0,
        source_file: format!("rendered:{}", cloud.source_file),
    }
}

impl Task for RenderNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let (want_images, want_lidar) = self.wanted(out)?;
        let latent = inputs.get::<BevFeatures>("latent")?;
        let frame = inputs.get::<SensorFrame>("frame")?;
        let latent_tensor = self.latent_tensor(latent)?;
        let rays = self
            .inputs
            .frame_rays(frame)
            .map_err(|error| NodeError::item(error.to_string()))?;
        let voxels = self.loaded.model.voxels(latent_tensor);
        let mut scene = VoxelScene::new(&self.loaded.model, &self.loaded.config, voxels);
        scene.chunk = self.chunk;
        let grid = self
            .skipping
            .as_ref()
            .map(|options| OccupancyGrid::build(&scene, options));
        let skipping = grid.as_ref().zip(self.skipping.as_ref());
        // Only what something consumes is cast.
        let camera = want_images.then(|| render_rays(&scene, skipping, &rays.camera));
        let lidar = want_lidar.then(|| render_rays(&scene, skipping, &rays.lidar));
        drop(scene);
        for part in camera.iter().chain(&lidar) {
            self.samples_evaluated += part.samples_evaluated;
            self.samples_dense += part.samples_dense;
        }
        if let Some(camera) = camera {
            self.send_images(frame, &camera, &rays, out)?;
        }
        if let Some(lidar) = lidar {
            out.send("lidar", rendered_sweep(frame, &lidar, &rays))?;
        }
        Ok(())
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        if self.samples_dense > 0 {
            figures.insert(
                "samples_evaluated_fraction".into(),
                self.samples_evaluated as f64 / self.samples_dense as f64,
            );
        }
        figures
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::task(
            "render",
            "the BEV tokenizer's decoder: a latent to voxels, ray-cast into the frame's six cameras and LiDAR beams",
        )
        .input(PortSpec::new::<BevFeatures>("latent"))
        .input(PortSpec::new::<SensorFrame>("frame"))
        .output(PortSpec::new::<ImageSet>("images"))
        .output(PortSpec::new::<PointCloud>("lidar"))
        .output(PortSpec::new::<ImageSet>("side_by_side")),
        |params: &RenderParams| {
            if let Some(options) = &params.skipping {
                let problems = options.problems();
                if let Some(first) = problems.first() {
                    return Err(ParamError::field("skipping", first.clone()));
                }
            }
            if params.chunk == 0 {
                return Err(ParamError::field("chunk", "must be at least 1").with_accepted("an integer >= 1"));
            }
            params.model.check()
        },
        |params: RenderParams| {
            let loaded = params.model.load()?;
            Ok(Node::Task(Box::new(RenderNode {
                inputs: FrameInputs::new(&loaded.config),
                loaded,
                skipping: params.skipping,
                chunk: params.chunk,
                samples_evaluated: 0,
                samples_dense: 0,
                warned_hash: false,
            })))
        },
    );
}
