//! Rays on the real nuScenes keyframe: every camera ray projects back onto its pixel centre
//! through the frame's own calibration, and LiDAR rays rebuild the real points from their ranges.

use crate::common;

use common::nuscenes_frame;

use bevworld_tokenizer::render::rays::{
    VoxelPlacement, camera_rays, inclination_azimuth, lidar_rays, points_from_depths,
    sample_depths, sample_depths_near_dense, sample_positions, spherical_direction,
};
use glam::DVec3;

#[test]
fn camera_rays_project_back_onto_their_pixel_centres() {
    let Some(frame) = nuscenes_frame() else {
        return;
    };
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
    let Some(frame) = nuscenes_frame() else {
        return;
    };
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
    for &(inclination, azimuth) in &[(0.0, 0.0), (-0.4, 3.0), (0.2, -1.7), (-0.05, 1.5)] {
        let direction = spherical_direction(inclination, azimuth);
        let (i, a) = inclination_azimuth(direction * 7.5);
        assert!((i - inclination).abs() < 1e-12 && (a - azimuth).abs() < 1e-12);
    }
}

#[test]
fn near_dense_samples_are_linear_then_even_in_disparity() {
    let close = |a: &[f32], b: &[f32]| {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
    };
    // near 1, seam 2, far 4: extents 1 and 2 (1 - 2/4) = 1 share 6 samples 3 : 3. Linear
    // 1, 4/3, 5/3; then disparity 1/2 -> 1/4 in halves: 2, 1/0.375, 4.
    let depths = sample_depths_near_dense(1.0, 2.0, 4.0, 6);
    assert!(
        close(&depths, &[1.0, 4.0 / 3.0, 5.0 / 3.0, 2.0, 8.0 / 3.0, 4.0]),
        "{depths:?}"
    );
    // The seam at `far` is uniform spacing; too few samples to split also fall back to it.
    assert_eq!(
        sample_depths_near_dense(1.0, 5.0, 5.0, 5),
        sample_depths(1.0, 5.0, 5)
    );
    assert_eq!(sample_depths_near_dense(1.0, 2.0, 5.0, 2), vec![1.0, 5.0]);
    // The tiny config's 48 samples: 27 linear ones 0.72 m apart up to 20 m, then steps that
    // start at 0.78 m and grow, strictly increasing to exactly `far`.
    let depths = sample_depths_near_dense(0.5, 20.0, 80.0, 48);
    assert_eq!(depths.len(), 48);
    assert!((depths[27] - 20.0).abs() < 1e-5 && (depths[47] - 80.0).abs() < 1e-4);
    assert!((depths[1] - depths[0] - 19.5 / 27.0).abs() < 1e-5);
    assert!((depths[28] - depths[27] - 0.779).abs() < 1e-3, "{depths:?}");
    assert!(depths.windows(2).all(|w| w[1] > w[0]));
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
    let positions = sample_positions(&rays, &[1.75, 2.0], &placement);
    assert_eq!(positions, vec![[3.0, 3.0, -0.5], [3.5, 3.0, -0.5]]);
}
