//! Where each camera sees the fusion's reference points: the geometric half of deformable
//! attention. Points are in the BEV's ego frame (the LiDAR sweep's), so a camera taken at
//! another instant goes through the global frame, as the nuScenes devkit does:
//! `camera_from_bev_ego = camera_from_ego(t_cam) * ego_from_global(t_cam) * global_from_ego(t_lidar)`.
//!
//! Pixel coordinates are continuous, with pixel `j` spanning `[j, j + 1)`, which is what
//! `Intrinsics::scaled_to` assumes; `grid_sample_2d` with `align_corners = false` reads them as
//! `x_n = 2u / W - 1`. A point behind the camera (depth below `min_depth`) or outside the image
//! is masked out, never clamped onto the border.

use bevworld_types::{CameraImage, Intrinsics, Pose};
use glam::DVec3;

/// One camera as the fusion sees it: the transform from the BEV's ego frame, and the
/// intrinsics of the image size the backbone receives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FusionCamera {
    pub camera_from_bev_ego: Pose,
    pub intrinsics: Intrinsics,
}

impl FusionCamera {
    /// For a frame's camera, with images resized to `width x height` before the backbone.
    pub fn new(camera: &CameraImage, global_from_bev_ego: &Pose, width: u32, height: u32) -> Self {
        Self {
            camera_from_bev_ego: camera.ego_from_camera.inverse()
                * camera.global_from_ego.inverse()
                * *global_from_bev_ego,
            intrinsics: camera.intrinsics.scaled_to(width, height),
        }
    }
}

/// Projections of points into one camera.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraHits {
    /// Pixel coordinates (u, v) of each point; meaningful where `valid`.
    pub pixels: Vec<[f64; 2]>,
    /// Coordinates in [-1, 1] for `grid_sample_2d` (align_corners = false); 0 where invalid.
    pub normalized: Vec<[f32; 2]>,
    /// 1 where the point is in front of the camera and inside the image, else 0.
    pub valid: Vec<f32>,
}

/// Projects BEV-ego points into a camera.
pub fn project_points(points: &[DVec3], camera: &FusionCamera, min_depth: f64) -> CameraHits {
    let k = &camera.intrinsics;
    let (width, height) = (f64::from(k.width), f64::from(k.height));
    let mut hits = CameraHits {
        pixels: Vec::with_capacity(points.len()),
        normalized: Vec::with_capacity(points.len()),
        valid: Vec::with_capacity(points.len()),
    };
    for &point in points {
        let q = camera.camera_from_bev_ego.transform_point3(point);
        if q.z <= min_depth {
            hits.pixels.push([f64::NAN, f64::NAN]);
            hits.normalized.push([0.0, 0.0]);
            hits.valid.push(0.0);
            continue;
        }
        let u = k.fx * q.x / q.z + k.cx;
        let v = k.fy * q.y / q.z + k.cy;
        hits.pixels.push([u, v]);
        if (0.0..width).contains(&u) && (0.0..height).contains(&v) {
            hits.normalized.push([
                (2.0 * u / width - 1.0) as f32,
                (2.0 * v / height - 1.0) as f32,
            ]);
            hits.valid.push(1.0);
        } else {
            hits.normalized.push([0.0, 0.0]);
            hits.valid.push(0.0);
        }
    }
    hits
}

/// The fusion's reference points: for each BEV cell centre, `heights` points evenly spaced
/// through the pillar's height range (cell-centred), cells row-major (y, then x).
pub fn pillar_reference_points(
    x_range: [f64; 2],
    y_range: [f64; 2],
    z_range: [f64; 2],
    cells: (usize, usize),
    heights: usize,
) -> Vec<DVec3> {
    let (nx, ny) = cells;
    let (sx, sy) = (
        (x_range[1] - x_range[0]) / nx as f64,
        (y_range[1] - y_range[0]) / ny as f64,
    );
    let sz = (z_range[1] - z_range[0]) / heights.max(1) as f64;
    let mut points = Vec::with_capacity(nx * ny * heights);
    for iy in 0..ny {
        for ix in 0..nx {
            for k in 0..heights {
                points.push(DVec3::new(
                    x_range[0] + (ix as f64 + 0.5) * sx,
                    y_range[0] + (iy as f64 + 0.5) * sy,
                    z_range[0] + (k as f64 + 0.5) * sz,
                ));
            }
        }
    }
    points
}
