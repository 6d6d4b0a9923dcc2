//! The rays the renderer casts, in the ego frame, and the fixed sample depths along them.
//!
//! - Camera rays start at the camera centre and pass through pixel centres of a grid
//!   `stride` times coarser than the image: block `(i, j)` covers pixels
//!   `[j s, (j + 1) s) x [i s, (i + 1) s)`, and its ray goes through `((j + ½) s, (i + ½) s)`.
//! - LiDAR rays start at the LiDAR origin and follow each real point's inclination and azimuth,
//!   so a rendered depth D rebuilds the point as `origin + D · (cos θ cos φ, cos θ sin φ, sin θ)`.
//!
//! Rays are plain CPU data: any subset (random batches in training, chosen views at inference)
//! is a slice of them, and only that subset is ever rendered.

use bevworld_types::{Intrinsics, Pose};
use burn::prelude::*;
use glam::DVec3;

/// Rays with unit directions, in the ego frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rays {
    pub origins: Vec<[f32; 3]>,
    pub directions: Vec<[f32; 3]>,
}

impl Rays {
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    /// The rays at `indices`, in that order.
    pub fn subset(&self, indices: &[usize]) -> Rays {
        Rays {
            origins: indices.iter().map(|&i| self.origins[i]).collect(),
            directions: indices.iter().map(|&i| self.directions[i]).collect(),
        }
    }

    /// The unit directions as a tensor.
    // -> [R, 3]
    pub fn directions_tensor(&self, device: &Device) -> Tensor<2> {
        let flat: Vec<f32> = self.directions.iter().flatten().copied().collect();
        Tensor::from_data(TensorData::new(flat, [self.len(), 3]), device)
    }

    fn push(&mut self, origin: DVec3, direction: DVec3) {
        let d = direction.normalize();
        self.origins
            .push([origin.x as f32, origin.y as f32, origin.z as f32]);
        self.directions.push([d.x as f32, d.y as f32, d.z as f32]);
    }
}

/// One ray per `stride x stride` pixel block of a camera image, row by row.
/// `intrinsics` are those of the image the rays are for (already scaled to its size).
pub fn camera_rays(intrinsics: &Intrinsics, ego_from_camera: &Pose, stride: usize) -> Rays {
    let stride = stride.max(1);
    let (columns, rows) = (
        intrinsics.width as usize / stride,
        intrinsics.height as usize / stride,
    );
    let origin = ego_from_camera.translation;
    let mut rays = Rays::default();
    for i in 0..rows {
        for j in 0..columns {
            let u = (j as f64 + 0.5) * stride as f64;
            let v = (i as f64 + 0.5) * stride as f64;
            let camera_direction = DVec3::new(
                (u - intrinsics.cx) / intrinsics.fx,
                (v - intrinsics.cy) / intrinsics.fy,
                1.0,
            );
            rays.push(origin, ego_from_camera.transform_vector3(camera_direction));
        }
    }
    rays
}

/// Unit direction from inclination θ (above the horizontal plane) and azimuth φ (from +x
/// towards +y), in the LiDAR frame.
pub fn spherical_direction(inclination: f64, azimuth: f64) -> DVec3 {
    DVec3::new(
        inclination.cos() * azimuth.cos(),
        inclination.cos() * azimuth.sin(),
        inclination.sin(),
    )
}

/// Inclination and azimuth of a LiDAR-frame point.
pub fn inclination_azimuth(point: DVec3) -> (f64, f64) {
    (
        point.z.atan2(point.x.hypot(point.y)),
        point.y.atan2(point.x),
    )
}

/// One ray per LiDAR point (LiDAR frame), expressed in the ego frame, and each point's range:
/// the depth a perfect render returns.
pub fn lidar_rays(points: &[DVec3], ego_from_lidar: &Pose) -> (Rays, Vec<f32>) {
    let origin = ego_from_lidar.translation;
    let mut rays = Rays::default();
    let mut ranges = Vec::with_capacity(points.len());
    for &point in points {
        let (inclination, azimuth) = inclination_azimuth(point);
        let direction = ego_from_lidar.transform_vector3(spherical_direction(inclination, azimuth));
        rays.push(origin, direction);
        ranges.push(point.length() as f32);
    }
    (rays, ranges)
}

/// Points `origin + depth · direction` (ego frame) from rendered depths.
pub fn points_from_depths(rays: &Rays, depths: &[f32]) -> Vec<[f32; 3]> {
    rays.origins
        .iter()
        .zip(&rays.directions)
        .zip(depths)
        .map(|((o, d), &t)| [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]])
        .collect()
}

/// `samples` fixed depths from `near` to `far` inclusive: evenly spaced in depth up to
/// `linear_until`, then evenly spaced in disparity `1/t` out to `far`. Most of what a LiDAR or
/// camera sees is within a few tens of metres, so the samples go there; far away one voxel
/// covers less of the image, and coarse steps lose little. The two parts share the samples so
/// that the step is about the same on both sides of `linear_until`. `linear_until >= far`
/// gives uniform spacing.
pub fn sample_depths_near_dense(
    near: f32,
    linear_until: f32,
    far: f32,
    samples: usize,
) -> Vec<f32> {
    if linear_until >= far || samples < 3 {
        return sample_depths(near, far, samples);
    }
    // Step of the linear part: (L - near) / n1. Step of the disparity part at L:
    // L² (1/L - 1/far) / n2 = L (1 - L / far) / n2. Equal when n1 : n2 = (L - near) : L (1 - L/far).
    let linear_extent = linear_until - near;
    let disparity_extent = linear_until * (1.0 - linear_until / far);
    let share = linear_extent / (linear_extent + disparity_extent);
    let linear = ((samples as f32 * share).round() as usize).clamp(1, samples - 2);
    let disparity = samples - linear;
    let (first, last) = (1.0 / linear_until, 1.0 / far);
    (0..linear)
        .map(|i| near + linear_extent * i as f32 / linear as f32)
        .chain((0..disparity).map(|j| {
            let fraction = j as f32 / (disparity - 1) as f32;
            1.0 / (first + (last - first) * fraction)
        }))
        .collect()
}

/// `samples` fixed depths, uniform from `near` to `far` inclusive.
pub fn sample_depths(near: f32, far: f32, samples: usize) -> Vec<f32> {
    match samples {
        0 => Vec::new(),
        1 => vec![0.5 * (near + far)],
        n => (0..n)
            .map(|i| near + (far - near) * i as f32 / (n - 1) as f32)
            .collect(),
    }
}

/// The voxel grid's placement in the ego frame: where voxel (0, 0, 0)'s lower corner is, and
/// the size of a voxel along x, y and z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoxelPlacement {
    pub min: [f32; 3],
    pub voxel_size: [f32; 3],
}

impl VoxelPlacement {
    /// An ego-frame point in voxel units (voxel `i`'s centre at `i`), as `sample_trilinear`
    /// reads it.
    pub fn to_voxel(&self, ego: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|axis| (ego[axis] - self.min[axis]) / self.voxel_size[axis] - 0.5)
    }
}

/// Sample positions along rays in voxel units, ray by ray, `depths.len()` per ray.
pub fn sample_positions(rays: &Rays, depths: &[f32], placement: &VoxelPlacement) -> Vec<[f32; 3]> {
    let mut positions = Vec::with_capacity(rays.len() * depths.len());
    for (o, d) in rays.origins.iter().zip(&rays.directions) {
        for &t in depths {
            positions.push(placement.to_voxel(std::array::from_fn(|axis| o[axis] + t * d[axis])));
        }
    }
    positions
}
