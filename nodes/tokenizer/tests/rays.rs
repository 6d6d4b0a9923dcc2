//! Rays on the real nuScenes keyframe: every camera ray projects back onto its pixel centre
//! through the frame's own calibration, and LiDAR rays rebuild the real points from their ranges.

mod common;

use common::nuscenes_frame;

use bevworld_tokenizer::render::rays::{
    VoxelPlacement, camera_rays, inclination_azimuth, lidar_rays, points_from_depths,
    sample_depths, sample_positions, spherical_direction,
};
use burn::prelude::*;
use glam::DVec3;

#[test]
fn camera_rays_project_back_onto_their_pixel_centres() {
    let frame = nuscenes_frame();
    assert_eq!(frame.cameras.len(), 6);
    for camera in &frame.cameras {
        // The network sees resized images: the rays are for that size, at 1/8 resolution.
        let intrinsics = camera.intrinsics.scaled_to(704, 256);
        let stride = 8;
        let rays = camera_rays(&intrinsics, &camera.ego_from_camera, stride);
        assert_eq!(rays.len(), (704 / 8) * (256 / 8));
        let camera_from_ego = camera.ego_from_camera.inverse();
        for (k, (o, d)) in rays.origins.iter().zip(&rays.directions).enumerate() {
            let (i, j) = (k / 88, k % 88);
            let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            assert!((norm - 1.0).abs() < 1e-5);
            let at = DVec3::new(
                (o[0] + 12.0 * d[0]) as f64,
                (o[1] + 12.0 * d[1]) as f64,
                (o[2] + 12.0 * d[2]) as f64,
            );
            let pixel = intrinsics
                .project(camera_from_ego.transform_point3(at))
                .expect("in front of the camera");
            let expected = ((j as f64 + 0.5) * 8.0, (i as f64 + 0.5) * 8.0);
            assert!(
                (pixel.x - expected.0).abs() < 2e-3 && (pixel.y - expected.1).abs() < 2e-3,
                "{:?} ray {k}: {pixel:?} vs {expected:?}",
                camera.channel
            );
        }
    }
}

#[test]
fn lidar_rays_rebuild_the_real_sweep_from_its_ranges() {
    let frame = nuscenes_frame();
    let cloud = &frame.lidar;
    let points: Vec<DVec3> = cloud
        .points
        .iter()
        .map(|p| DVec3::new(p.x.into(), p.y.into(), p.z.into()))
        .collect();
    assert_eq!(points.len(), 34_688);
    let (rays, ranges) = lidar_rays(&points, &cloud.ego_from_lidar);
    let rebuilt = points_from_depths(&rays, &ranges);
    let mut worst = 0.0f64;
    for (p, r) in points.iter().zip(&rebuilt) {
        let ego = cloud.ego_from_lidar.transform_point3(*p);
        let error = (ego - DVec3::new(r[0].into(), r[1].into(), r[2].into())).length();
        worst = worst.max(error);
    }
    assert!(worst < 2e-3, "worst rebuild error {worst} m");
}

#[test]
fn spherical_angles_round_trip() {
    for &(inclination, azimuth) in &[(0.0, 0.0), (-0.4, 3.0), (0.2, -1.7), (-0.05, 1.5707)] {
        let direction = spherical_direction(inclination, azimuth);
        let (i, a) = inclination_azimuth(direction * 7.5);
        assert!((i - inclination).abs() < 1e-12 && (a - azimuth).abs() < 1e-12);
    }
}

#[test]
fn sample_depths_and_positions_are_where_they_should_be() {
    assert_eq!(sample_depths(1.0, 5.0, 5), vec![1.0, 2.0, 3.0, 4.0, 5.0]);
    assert_eq!(sample_depths(1.0, 5.0, 1), vec![3.0]);
    assert!(sample_depths(1.0, 5.0, 0).is_empty());
    // A grid from -4 m with 0.5 m voxels: the point at x = -4 + 0.5 * (3 + ½) is voxel 3's centre.
    let placement = VoxelPlacement {
        min: [-4.0, -4.0, -2.0],
        voxel_size: [0.5, 0.5, 0.25],
    };
    let rays = bevworld_tokenizer::render::rays::Rays {
        origins: vec![[-4.0, -2.25, -2.0]],
        directions: vec![[1.0, 0.0, 0.0]],
    };
    let positions = sample_positions(&rays, &[1.75, 2.0], &placement, &Device::flex());
    assert_eq!(positions.dims(), [1, 2, 3]);
    let v = positions.into_data().try_to_vec::<f32>().expect("f32");
    assert_eq!(v, vec![3.0, 3.0, -0.5, 3.5, 3.0, -0.5]);
}
