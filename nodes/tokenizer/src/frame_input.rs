//! From a sensor frame to what the tokenizer reads and renders: camera images resized to the
//! config's size, the pillars as padded tensors, the fusion's reference points projected into
//! every camera, and the rays (camera pixel blocks and real LiDAR directions) that rendering
//! casts back out.
//!
//! Everything is expressed in the BEV's ego frame: the ego at the LiDAR sweep's time (`frame.lidar.global_from_ego`), which is
//! the frame the pillars and the latent live in. Cameras fired at other instants go through the
//! global frame (see `encoder::projection`).

use bevworld_types::{PILLAR_FEATURES, PillarGrid, Pillars, Pose, SensorFrame};
use burn::prelude::*;
use glam::DVec3;
use image::imageops::FilterType;
use rayon::prelude::*;
use thiserror::Error;

use crate::config::TokenizerConfig;
use crate::encoder::projection::{FusionCamera, pillar_reference_points, project_points};
use crate::model::EncoderInput;
use crate::render::rays::{Rays, camera_rays, lidar_rays};

/// Points closer to a camera's image plane than this (metres) are treated as behind it.
const MIN_CAMERA_DEPTH: f64 = 0.1;

#[derive(Debug, Error, PartialEq)]
pub enum InputError {
    #[error(
        "frame {frame} has {found} cameras, but the tokenizer '{model}' takes {expected} (config field `cameras`)"
    )]
    Cameras {
        frame: String,
        model: String,
        found: usize,
        expected: usize,
    },
    #[error(
        "frame {frame}: the pillars are on a {found} grid, but the tokenizer '{model}' expects {expected}; set the pillarize node's `grid` to match the model config's `bev`"
    )]
    PillarGrid {
        frame: String,
        model: String,
        found: String,
        expected: String,
    },
    #[error(
        "frame {frame}: pillar {pillar} has cell ({iy}, {ix}), outside the {n} x {n} grid, or malformed pillar arrays"
    )]
    PillarData {
        frame: String,
        pillar: usize,
        iy: u32,
        ix: u32,
        n: usize,
    },
}

/// A frame's pillars as host arrays: point features, point validity, cells.
type PillarArrays = (Vec<f32>, Vec<f32>, Vec<i64>);

/// `EncoderInput` as host arrays (see `FrameInputs::encoder_arrays`).
#[derive(Clone, Debug)]
pub struct EncoderArrays {
    /// `[N_c, 3, H, W]` in [0, 1].
    pub images: Vec<f32>,
    pub image_shape: [usize; 4],
    pub pillar_slots: usize,
    pub pillar_points: Vec<f32>,
    pub pillar_valid: Vec<f32>,
    pub pillar_cells: Vec<i64>,
    pub reference: Vec<f32>,
    pub reference_valid: Vec<f32>,
    /// `[N_c, Q, K]`.
    pub reference_shape: [usize; 3],
}

impl EncoderArrays {
    pub fn to_input(&self, device: &Device) -> EncoderInput {
        let count = self.pillar_cells.len();
        let slots = self.pillar_slots;
        let [cameras, q, k] = self.reference_shape;
        EncoderInput {
            images: Tensor::from_data(
                TensorData::new(self.images.clone(), self.image_shape),
                device,
            ),
            pillar_points: Tensor::from_data(
                TensorData::new(self.pillar_points.clone(), [count, slots, PILLAR_FEATURES]),
                device,
            ),
            pillar_valid: Tensor::from_data(
                TensorData::new(self.pillar_valid.clone(), [count, slots]),
                device,
            ),
            pillar_cells: Tensor::from_data(
                TensorData::new(self.pillar_cells.clone(), [count]),
                device,
            ),
            reference: Tensor::from_data(
                TensorData::new(self.reference.clone(), [cameras, q, k, 2]),
                device,
            ),
            reference_valid: Tensor::from_data(
                TensorData::new(self.reference_valid.clone(), [cameras, q, k]),
                device,
            ),
        }
    }
}

/// Config-derived geometry, computed once and reused for every frame.
#[derive(Clone, Debug)]
pub struct FrameInputs {
    config: TokenizerConfig,
    /// The fusion's reference points, cells row-major (y, then x), `fusion_heights` per cell.
    reference_points: Vec<DVec3>,
}

/// The rays of one frame, in the BEV's ego frame.
#[derive(Clone, Debug)]
pub struct FrameRays {
    /// Every camera's block rays, camera after camera, row by row.
    pub camera: Rays,
    pub cameras: usize,
    /// The ray grid of one camera: `image_size / camera_stride`.
    pub rows: usize,
    pub columns: usize,
    /// One ray per LiDAR return off the ego vehicle's body, and the return's range (the depth
    /// a perfect render returns).
    pub lidar: Rays,
    pub lidar_ranges: Vec<f32>,
    /// Which of the sweep's points each LiDAR ray is (`PointCloud::scene_indices`).
    pub lidar_points: Vec<usize>,
}

impl FrameInputs {
    pub fn new(config: &TokenizerConfig) -> Self {
        let n = config.latent_size();
        Self {
            config: config.clone(),
            reference_points: pillar_reference_points(
                config.bev.x_range,
                config.bev.y_range,
                config.bev.z_range,
                (n, n),
                config.fusion_heights,
            ),
        }
    }

    pub fn config(&self) -> &TokenizerConfig {
        &self.config
    }

    /// The pillar grid the model's LiDAR branch expects, for the pillarize node or a
    /// `Pillarizer`.
    pub fn pillar_grid(&self) -> PillarGrid {
        let bev = &self.config.bev;
        let f = |r: [f64; 2]| [r[0] as f32, r[1] as f32];
        PillarGrid {
            x_range: f(bev.x_range),
            y_range: f(bev.y_range),
            z_range: f(bev.z_range),
            pillar_size: ((bev.x_range[1] - bev.x_range[0]) / bev.pillar_grid.max(1) as f64) as f32,
        }
    }

    fn check_cameras(&self, frame: &SensorFrame) -> Result<(), InputError> {
        if frame.cameras.len() != self.config.cameras {
            return Err(InputError::Cameras {
                frame: frame.frame_token.clone(),
                model: self.config.name.clone(),
                found: frame.cameras.len(),
                expected: self.config.cameras,
            });
        }
        Ok(())
    }

    /// The frame's camera images at the config's size, in [0, 1], planar: `[N_c, 3, H, W]`
    /// as a flat vector, cameras in the frame's order.
    pub fn camera_planes(&self, frame: &SensorFrame) -> Result<Vec<f32>, InputError> {
        self.check_cameras(frame)?;
        let [h, w] = self.config.image_size;
        // One camera per task: resizing six full-size images is the encoder's biggest host
        // cost, and the cameras are independent.
        let per_camera: Vec<Vec<f32>> = frame
            .cameras
            .par_iter()
            .map(|camera| image_planes(&camera.image, w, h))
            .collect();
        Ok(per_camera.concat())
    }

    /// Everything `Tokenizer::encode` reads for this frame.
    pub fn encoder_input(
        &self,
        frame: &SensorFrame,
        pillars: &Pillars,
        device: &Device,
    ) -> Result<EncoderInput, InputError> {
        Ok(self.encoder_arrays(frame, pillars)?.to_input(device))
    }

    /// The encoder's inputs as host arrays, to keep many frames ready for training without
    /// holding device memory.
    pub fn encoder_arrays(
        &self,
        frame: &SensorFrame,
        pillars: &Pillars,
    ) -> Result<EncoderArrays, InputError> {
        let [h, w] = self.config.image_size;
        let cameras = frame.cameras.len();
        let images = self.camera_planes(frame)?;
        let (points, valid, cells) = self.pillar_arrays(frame, pillars)?;
        let k = self.config.fusion_heights;
        let q = self.reference_points.len() / k.max(1);
        let mut reference: Vec<f32> = Vec::with_capacity(cameras * q * k * 2);
        let mut reference_valid = Vec::with_capacity(cameras * q * k);
        for fusion_camera in self.fusion_cameras(frame) {
            let hits = project_points(&self.reference_points, &fusion_camera, MIN_CAMERA_DEPTH);
            reference.extend(hits.normalized.iter().flatten());
            reference_valid.extend(hits.valid);
        }
        Ok(EncoderArrays {
            images,
            image_shape: [cameras, 3, h, w],
            pillar_slots: pillars.max_points_per_pillar.max(1),
            pillar_points: points,
            pillar_valid: valid,
            pillar_cells: cells,
            reference,
            reference_valid,
            reference_shape: [cameras, q, k],
        })
    }

    /// Each camera as the fusion sees it, at the config's image size.
    pub fn fusion_cameras(&self, frame: &SensorFrame) -> Vec<FusionCamera> {
        let [h, w] = self.config.image_size;
        frame
            .cameras
            .iter()
            .map(|camera| {
                FusionCamera::new(camera, &frame.lidar.global_from_ego, w as u32, h as u32)
            })
            .collect()
    }

    /// Padded pillar points `[P, N, 9]`, validity `[P, N]` and row-major cells `[P]`. A sweep
    /// with no pillar in range gives one all-padding pillar, which adds exactly zero.
    fn pillar_arrays(
        &self,
        frame: &SensorFrame,
        pillars: &Pillars,
    ) -> Result<PillarArrays, InputError> {
        let n = self.config.bev.pillar_grid;
        let bev = &self.config.bev;
        let grid = &pillars.grid;
        let close = |a: [f32; 2], b: [f64; 2]| {
            (f64::from(a[0]) - b[0]).abs() < 1e-3 && (f64::from(a[1]) - b[1]).abs() < 1e-3
        };
        if grid.size() != (n, n)
            || !close(grid.x_range, bev.x_range)
            || !close(grid.y_range, bev.y_range)
            || !close(grid.z_range, bev.z_range)
        {
            let (nx, ny) = grid.size();
            return Err(InputError::PillarGrid {
                frame: frame.frame_token.clone(),
                model: self.config.name.clone(),
                found: format!(
                    "{nx} x {ny} over x {:?}, y {:?}, z {:?}",
                    grid.x_range, grid.y_range, grid.z_range
                ),
                expected: format!(
                    "{n} x {n} over x {:?}, y {:?}, z {:?}",
                    bev.x_range, bev.y_range, bev.z_range
                ),
            });
        }
        let slots = pillars.max_points_per_pillar.max(1);
        let count = pillars.len();
        let malformed = |p: usize, iy: u32, ix: u32| InputError::PillarData {
            frame: frame.frame_token.clone(),
            pillar: p,
            iy,
            ix,
            n,
        };
        if pillars.coords.len() != 2 * count
            || pillars.features.len() != count * slots * PILLAR_FEATURES
        {
            return Err(malformed(0, 0, 0));
        }
        if count == 0 {
            return Ok((
                vec![0.0; slots * PILLAR_FEATURES],
                vec![0.0; slots],
                vec![0],
            ));
        }
        let mut valid = vec![0.0f32; count * slots];
        let mut cells = Vec::with_capacity(count);
        for p in 0..count {
            let (iy, ix) = (pillars.coords[2 * p], pillars.coords[2 * p + 1]);
            if iy as usize >= n || ix as usize >= n {
                return Err(malformed(p, iy, ix));
            }
            cells.push(iy as i64 * n as i64 + ix as i64);
            let points = (pillars.point_counts[p] as usize).min(slots);
            valid[p * slots..p * slots + points].fill(1.0);
        }
        Ok((pillars.features.clone(), valid, cells))
    }

    /// The rays rendering casts for this frame: every camera's 1/stride block rays, and one
    /// ray per real LiDAR return off the ego vehicle (returns off the car itself are not the
    /// scene, see `EgoBody`).
    pub fn frame_rays(&self, frame: &SensorFrame) -> Result<FrameRays, InputError> {
        self.check_cameras(frame)?;
        let [h, w] = self.config.image_size;
        let stride = self.config.render.camera_stride;
        let mut camera = Rays::default();
        for fusion_camera in self.fusion_cameras(frame) {
            let bev_ego_from_camera: Pose = fusion_camera.camera_from_bev_ego.inverse();
            let rays = camera_rays(&fusion_camera.intrinsics, &bev_ego_from_camera, stride);
            camera.origins.extend(rays.origins);
            camera.directions.extend(rays.directions);
        }
        let lidar_points = frame.lidar.scene_indices();
        let points: Vec<DVec3> = lidar_points
            .iter()
            .map(|&i| {
                let p = &frame.lidar.points[i];
                DVec3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z))
            })
            .collect();
        let (lidar, lidar_ranges) = lidar_rays(&points, &frame.lidar.ego_from_lidar);
        Ok(FrameRays {
            camera,
            cameras: frame.cameras.len(),
            rows: h / stride,
            columns: w / stride,
            lidar,
            lidar_ranges,
            lidar_points,
        })
    }
}

/// An RGB image resized (triangle filter, which averages over the footprint when shrinking)
/// to `width x height`, as `[3, H, W]` planes in [0, 1].
pub fn image_planes(image: &image::RgbImage, width: usize, height: usize) -> Vec<f32> {
    let resized;
    let image = if (image.width() as usize, image.height() as usize) == (width, height) {
        image
    } else {
        resized = image::imageops::resize(image, width as u32, height as u32, FilterType::Triangle);
        &resized
    };
    let plane = width * height;
    let mut planes = vec![0.0f32; 3 * plane];
    for (i, pixel) in image.pixels().enumerate() {
        for c in 0..3 {
            planes[c * plane + i] = f32::from(pixel.0[c]) / 255.0;
        }
    }
    planes
}

/// `[3, H, W]` planes in [0, 1] back to an 8-bit image; values outside [0, 1] are clamped.
pub fn planes_to_image(planes: &[f32], width: usize, height: usize) -> image::RgbImage {
    let plane = width * height;
    image::RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let i = y as usize * width + x as usize;
        let byte = |c: usize| {
            let value = planes.get(c * plane + i).copied().unwrap_or(0.0);
            (value.clamp(0.0, 1.0) * 255.0).round() as u8
        };
        image::Rgb([byte(0), byte(1), byte(2)])
    })
}
