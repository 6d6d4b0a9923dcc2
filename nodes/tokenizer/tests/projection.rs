//! The fusion's projection on the real nuScenes keyframe lands where `bevworld inspect` (the
//! devkit's `map_pointcloud_to_image`) puts each LiDAR point, and masks what no camera sees.

use bevworld_sensors::inspect::project_cloud;
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_tokenizer::encoder::projection::{
    FusionCamera, pillar_reference_points, project_points,
};
use glam::DVec3;

#[test]
fn fusion_projection_matches_inspect_on_the_real_sample() {
    let Some(root) = bevworld_sensors::real_dataset("nuscenes-sample") else {
        return;
    };
    let frame = Dataset::open(&root, &DatasetOptions::default())
        .expect("nuScenes sample")
        .read(0)
        .expect("frame 0");
    let cloud = &frame.lidar;
    // The BEV lives in the ego frame at the LiDAR's timestamp.
    let ego_points: Vec<DVec3> = cloud
        .points
        .iter()
        .map(|p| {
            cloud
                .ego_from_lidar
                .transform_point3(DVec3::new(p.x.into(), p.y.into(), p.z.into()))
        })
        .collect();
    let mut compared = 0;
    for camera in &frame.cameras {
        let reference = project_cloud(cloud, camera);
        assert!(!reference.is_empty());
        let full = FusionCamera::new(
            camera,
            &cloud.global_from_ego,
            camera.intrinsics.width,
            camera.intrinsics.height,
        );
        let hits = project_points(&ego_points, &full, 1.0);
        // The backbone's resized input: the same points, scaled.
        let resized = FusionCamera::new(camera, &cloud.global_from_ego, 704, 256);
        let small = project_points(&ego_points, &resized, 1.0);
        let (sx, sy) = (
            704.0 / f64::from(camera.intrinsics.width),
            256.0 / f64::from(camera.intrinsics.height),
        );
        for p in &reference {
            let [u, v] = hits.pixels[p.index];
            assert!(
                (u - p.u).abs() < 1e-6 && (v - p.v).abs() < 1e-6,
                "{:?} point {}: ({u}, {v}) vs inspect ({}, {})",
                camera.channel,
                p.index,
                p.u,
                p.v
            );
            assert_eq!(hits.valid[p.index], 1.0);
            let [us, vs] = small.pixels[p.index];
            assert!((us - p.u * sx).abs() < 1e-6 && (vs - p.v * sy).abs() < 1e-6);
            let [xn, yn] = small.normalized[p.index];
            assert!((xn as f64 - (2.0 * us / 704.0 - 1.0)).abs() < 1e-6);
            assert!((yn as f64 - (2.0 * vs / 256.0 - 1.0)).abs() < 1e-6);
            compared += 1;
        }
        // What inspect rejects for depth is masked here too, never clamped to the border.
        for (index, point) in ego_points.iter().enumerate() {
            let in_camera = full.camera_from_bev_ego.transform_point3(*point);
            if in_camera.z <= 1.0 {
                assert_eq!(hits.valid[index], 0.0);
                assert_eq!(hits.normalized[index], [0.0, 0.0]);
            }
        }
        assert!(hits.valid.contains(&0.0));
    }
    assert!(compared > 10_000, "only {compared} points compared");
}

#[test]
fn reference_points_sit_at_cell_centres_through_the_pillar() {
    let points = pillar_reference_points([-80.0, 80.0], [-80.0, 80.0], [-4.5, 4.5], (4, 2), 4);
    assert_eq!(points.len(), 4 * 2 * 4);
    // Cell (iy 0, ix 1): x centre -80 + 1.5 * 40 = -20, y centre -80 + 0.5 * 80 = -40.
    let cell = &points[4..8];
    for (k, p) in cell.iter().enumerate() {
        assert_eq!((p.x, p.y), (-20.0, -40.0));
        assert!((p.z - (-4.5 + (k as f64 + 0.5) * 2.25)).abs() < 1e-12);
    }
}
