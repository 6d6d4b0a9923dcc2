//! LiDAR-to-camera projection exactly as the nuScenes devkit's `map_pointcloud_to_image`:
//! lidar -> ego at the LiDAR's timestamp -> global -> ego at the camera's timestamp -> camera;
//! depth is the camera-frame z; keep depth > 1 m and 1 < u < W-1, 1 < v < H-1. In f64, as the
//! devkit's numpy code computes.

use bevworld_types::{CameraImage, PointCloud};
use glam::DVec3;
use image::{Rgb, RgbImage};

/// One projected point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected {
    pub u: f64,
    pub v: f64,
    pub depth: f64,
    /// Index of the point in the cloud.
    pub index: usize,
}

pub const MIN_DEPTH: f64 = 1.0;

pub fn project_cloud(cloud: &PointCloud, camera: &CameraImage) -> Vec<Projected> {
    let camera_from_lidar = camera.ego_from_camera.inverse()
        * camera.global_from_ego.inverse()
        * cloud.global_from_ego
        * cloud.ego_from_lidar;
    let k = &camera.intrinsics;
    let (width, height) = (f64::from(k.width), f64::from(k.height));
    cloud
        .points
        .iter()
        .enumerate()
        .filter_map(|(index, p)| {
            let q = camera_from_lidar.transform_point3(DVec3::new(
                f64::from(p.x),
                f64::from(p.y),
                f64::from(p.z),
            ));
            let depth = q.z;
            if depth <= MIN_DEPTH {
                return None;
            }
            let u = (k.fx * q.x + k.cx * q.z) / q.z;
            let v = (k.fy * q.y + k.cy * q.z) / q.z;
            (u > 1.0 && u < width - 1.0 && v > 1.0 && v < height - 1.0).then_some(Projected {
                u,
                v,
                depth,
                index,
            })
        })
        .collect()
}

/// A perceptually ordered colour for a depth (near = warm, far = cool), turbo-like.
pub fn depth_colour(depth: f64, max_depth: f64) -> Rgb<u8> {
    let t = (depth / max_depth).clamp(0.0, 1.0);
    let r = (1.0 - t).powf(0.8) * 255.0;
    let g = (1.0 - (2.0 * t - 1.0).abs()).powf(0.7) * 235.0 + 20.0 * (1.0 - t);
    let b = t.powf(0.8) * 255.0;
    Rgb([r as u8, g.clamp(0.0, 255.0) as u8, b as u8])
}

/// The camera image with points drawn as small discs coloured by depth.
pub fn draw_points(image: &RgbImage, points: &[Projected], max_depth: f64) -> RgbImage {
    let mut canvas = image.clone();
    let radius = ((image.width() as f64 / 800.0).round() as i64).max(1);
    for p in points {
        let colour = depth_colour(p.depth, max_depth);
        let (cu, cv) = (p.u.floor() as i64, p.v.floor() as i64);
        for dv in -radius..=radius {
            for du in -radius..=radius {
                if du * du + dv * dv > radius * radius {
                    continue;
                }
                let (x, y) = (cu + du, cv + dv);
                if x >= 0 && y >= 0 && (x as u32) < canvas.width() && (y as u32) < canvas.height() {
                    canvas.put_pixel(x as u32, y as u32, colour);
                }
            }
        }
    }
    canvas
}

/// `u,v,depth` rows with a header.
pub fn to_csv(points: &[Projected]) -> String {
    let mut out = String::with_capacity(points.len() * 32 + 16);
    out.push_str("u,v,depth\n");
    for p in points {
        out.push_str(&format!("{:.6},{:.6},{:.6}\n", p.u, p.v, p.depth));
    }
    out
}
