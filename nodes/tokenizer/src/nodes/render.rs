//! `render`: a BEV latent back to six camera images and one LiDAR sweep, casting the rays of
//! the frame it stands for (its cameras' calibration, its real LiDAR beam directions).
//!
//! Outputs: `images` (the reconstructions, named by camera), `lidar` (the rendered sweep in
//! the LiDAR frame, one point per input return off the ego vehicle, with that return's ring),
//! and `side_by_side`
//! (input | reconstruction per camera, at the model's image size).
//!
//! A forecast is rendered the same way: a `FutureView` on `future` carries its latent and the
//! frame whose rays it is cast along (the logged future frame, or the rig at the predicted
//! pose), and comes out on `future` as a `RenderedFuture`, with only the `sensors` asked for.
//! Connect either `latent` and `frame`, or `future`.

use std::sync::Arc;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, Outputs, ParamError, Port, Registry, Task,
};
use bevworld_types::{
    BevFeatures, FutureView, ImageSet, LidarPoint, NamedImage, PointCloud, RenderedFuture,
    SensorFrame,
};
use burn::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::frame_input::{FrameInputs, FrameRays, image_planes, planes_to_image};
use crate::modality::Modality;
use crate::nodes::loaded_model::{LoadedModel, ModelParams};
use crate::render::rays::Rays;
use crate::render::{OccupancyGrid, RenderedRays, SkipOptions, VoxelScene, camera_images};

// The node's ports, each named once (`bevworld_graph::Port`).
const FRAME: Port<SensorFrame> = Port::new("frame");
const FUTURE_IN: Port<FutureView> = Port::new("future");
const LATENT: Port<BevFeatures> = Port::new("latent");
const FUTURE_OUT: Port<RenderedFuture> = Port::new("future");
const IMAGES: Port<ImageSet> = Port::new("images");
const LIDAR: Port<PointCloud> = Port::new("lidar");
const SIDE_BY_SIDE: Port<ImageSet> = Port::new("side_by_side");

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
    /// What a `future` view is rendered into: `cameras`, `lidar`, or both.
    #[serde(default = "default_sensors")]
    pub sensors: Vec<String>,
}

fn default_sensors() -> Vec<String> {
    vec!["cameras".into(), "lidar".into()]
}

fn default_chunk() -> usize {
    4096
}

pub struct RenderNode {
    loaded: Arc<LoadedModel>,
    inputs: FrameInputs,
    skipping: Option<SkipOptions>,
    chunk: usize,
    samples_evaluated: u64,
    samples_dense: u64,
    warned_hash: bool,
    /// Which sensors a `future` view is rendered into.
    future_cameras: bool,
    future_lidar: bool,
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
        let images = out.is_connected(&IMAGES) || out.is_connected(&SIDE_BY_SIDE);
        let lidar = out.is_connected(&LIDAR);
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
        let images = self.images(frame, camera, rays)?;
        let [h, w] = self.loaded.config.image_size;
        if out.is_connected(&SIDE_BY_SIDE) {
            let mut side_by_side = ImageSet::default();
            for (input, reconstruction) in frame.cameras.iter().zip(&images.images) {
                let original = planes_to_image(&image_planes(&input.image, w, h), w, h);
                let mut pair = image::RgbImage::new(2 * w as u32, h as u32);
                image::imageops::replace(&mut pair, &original, 0, 0);
                image::imageops::replace(&mut pair, reconstruction.image.as_ref(), w as i64, 0);
                side_by_side.images.push(NamedImage {
                    name: reconstruction.name.clone(),
                    image: Arc::new(pair),
                });
            }
            out.send(&SIDE_BY_SIDE, side_by_side)?;
        }
        out.send(&IMAGES, images)
    }
}

/// The rendered depths along the sweep's rays as points in the LiDAR frame, each with the ring
/// of the return its ray came from. The tokenizer does not model reflectance: a point's
/// intensity is its ray's opacity `1 − T` in [0, 1], how surely the ray met a surface.
fn rendered_sweep(frame: &SensorFrame, lidar: &RenderedRays, rays: &FrameRays) -> PointCloud {
    let cloud = &frame.lidar;
    let lidar_from_ego = cloud.ego_from_lidar.inverse();
    let points = rays
        .lidar
        .directions
        .iter()
        .zip(&lidar.depth)
        .zip(&lidar.opacity)
        .zip(&rays.lidar_points)
        .map(|(((d, &depth), &opacity), &index)| {
            let direction =
                lidar_from_ego.transform_vector3(DVec3::new(d[0].into(), d[1].into(), d[2].into()));
            let p = direction * f64::from(depth);
            LidarPoint {
                x: p.x as f32,
                y: p.y as f32,
                z: p.z as f32,
                intensity: opacity.clamp(0.0, 1.0),
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

impl RenderNode {
    /// Casts `frame`'s rays into `latent`: the camera renders and the sweep, each only when
    /// asked for.
    fn render(
        &mut self,
        latent: &BevFeatures,
        frame: &SensorFrame,
        want_images: bool,
        want_lidar: bool,
    ) -> Result<(Option<RenderedRays>, Option<RenderedRays>, FrameRays), NodeError> {
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
        Ok((camera, lidar, rays))
    }

    /// The camera renders as named images.
    fn images(
        &self,
        frame: &SensorFrame,
        camera: &RenderedRays,
        rays: &FrameRays,
    ) -> Result<ImageSet, NodeError> {
        let rgb = camera_images(&self.loaded.model, camera, rays, &self.loaded.device);
        let [h, w] = self.loaded.config.image_size;
        let planes = rgb
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|error| NodeError::item(format!("reading the images back: {error:?}")))?;
        Ok(ImageSet {
            images: frame
                .cameras
                .iter()
                .enumerate()
                .map(|(c, input)| NamedImage {
                    name: input.channel.name().to_string(),
                    image: Arc::new(planes_to_image(
                        &planes[c * 3 * h * w..(c + 1) * 3 * h * w],
                        w,
                        h,
                    )),
                })
                .collect(),
        })
    }

    fn render_future(&mut self, view: Arc<FutureView>, out: &mut Outputs) -> Result<(), NodeError> {
        let (want_images, want_lidar) = (self.future_cameras, self.future_lidar);
        for (wanted, modality) in [
            (want_images, Modality::Camera),
            (want_lidar, Modality::Lidar),
        ] {
            if wanted && !self.loaded.config.uses(modality) {
                return Err(NodeError::fatal(format!(
                    "render: `sensors` asks for the {}, but model '{}' was trained without them; set `sensors` to what it renders",
                    modality.plural(),
                    self.loaded.config.name
                )));
            }
        }
        let started = std::time::Instant::now();
        let (camera, lidar, rays) =
            self.render(&view.latent, &view.rays, want_images, want_lidar)?;
        let images = camera
            .map(|camera| self.images(&view.rays, &camera, &rays))
            .transpose()?;
        let lidar = lidar.map(|lidar| rendered_sweep(&view.rays, &lidar, &rays));
        let render_ms = started.elapsed().as_secs_f64() * 1e3;
        if let Some(images) = &images
            && out.is_connected(&IMAGES)
        {
            out.send(&IMAGES, images.clone())?;
        }
        if let Some(lidar) = &lidar
            && out.is_connected(&LIDAR)
        {
            out.send(&LIDAR, lidar.clone())?;
        }
        out.send(
            &FUTURE_OUT,
            RenderedFuture {
                view,
                images,
                lidar,
                render_ms,
            },
        )
    }
}

impl Task for RenderNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        if inputs.message(FUTURE_IN.name).is_some() {
            let view = inputs.shared(&FUTURE_IN)?;
            return self.render_future(view, out);
        }
        let (want_images, want_lidar) = self.wanted(out)?;
        let (Some(_), Some(_)) = (inputs.message(LATENT.name), inputs.message(FRAME.name)) else {
            return Err(NodeError::fatal(
                "render: connect both `latent` and `frame` (a reconstruction), or `future` (a forecast)",
            ));
        };
        let latent = inputs.get(&LATENT)?;
        let frame = inputs.get(&FRAME)?;
        let (camera, lidar, rays) = self.render(latent, frame, want_images, want_lidar)?;
        if let Some(camera) = camera {
            self.send_images(frame, &camera, &rays, out)?;
        }
        if let Some(lidar) = lidar {
            out.send(&LIDAR, rendered_sweep(frame, &lidar, &rays))?;
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

/// Which sensors `sensors` names: (cameras, lidar).
fn sensors(names: &[String]) -> Result<(bool, bool), ParamError> {
    let mut wanted = (false, false);
    for name in names {
        match name.as_str() {
            "cameras" => wanted.0 = true,
            "lidar" => wanted.1 = true,
            other => {
                return Err(
                    ParamError::field("sensors", format!("unknown sensor '{other}'"))
                        .with_accepted("cameras, lidar"),
                );
            }
        }
    }
    if wanted == (false, false) {
        return Err(ParamError::field("sensors", "is empty").with_accepted("cameras, lidar"));
    }
    Ok(wanted)
}

pub fn register(registry: &mut Registry) {
    registry.register_with_models(
        KindSpec::task(
            "render",
            "the BEV tokenizer's decoder: a latent to voxels, ray-cast into the frame's six cameras and LiDAR beams",
        )
        .input(LATENT.optional())
        .input(FRAME.optional())
        .input(FUTURE_IN.optional())
        .output(IMAGES.spec())
        .output(LIDAR.spec())
        .output(SIDE_BY_SIDE.spec())
        .output(FUTURE_OUT.spec()),
        |params: &RenderParams, models: &bevworld_graph::Models| {
            if let Some(options) = &params.skipping {
                let problems = options.problems();
                if let Some(first) = problems.first() {
                    return Err(ParamError::field("skipping", first.clone()));
                }
            }
            sensors(&params.sensors)?;
            if params.chunk == 0 {
                return Err(ParamError::field("chunk", "must be at least 1").with_accepted("an integer >= 1"));
            }
            params.model.check(models)
        },
        |params: RenderParams, models: &bevworld_graph::Models| {
            let (future_cameras, future_lidar) = sensors(&params.sensors)?;
            let loaded = params.model.load_shared(models)?;
            Ok(Node::Task(Box::new(RenderNode {
                future_cameras,
                future_lidar,
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
