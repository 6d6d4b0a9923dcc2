//! The nuScenes reader on the real keyframe in ../shared/data/nuscenes-sample, checked against
//! values read by hand from its JSON tables and its sweep file.

use std::path::PathBuf;

use bevworld_sensors::nuscenes::{NuScenes, NuScenesOptions};
use bevworld_types::CameraChannel;
use glam::DVec3;

fn data() -> Option<PathBuf> {
    bevworld_sensors::real_dataset("nuscenes-sample")
}

#[test]
fn reads_the_keyframe_with_its_calibration() {
    let Some(data) = data() else {
        return;
    };
    let dataset = NuScenes::open(&data, NuScenesOptions::default()).unwrap();
    assert_eq!(dataset.version(), "v1.0-mini");
    assert_eq!(dataset.len(), 1);
    let frame = dataset.read(0).unwrap();
    assert_eq!(frame.sample_token, "ca9a282c9e77460f8360f564131a8af5");
    assert_eq!(frame.scene_name, "scene-0061");
    assert_eq!(frame.time_of_validity_us, 1_532_402_927_647_951);
    assert!(
        frame.action.is_none(),
        "a one-frame scene has no next frame"
    );

    // LIDAR_TOP: 34,688 points; first and last point as stored in the file.
    let lidar = &frame.lidar;
    assert_eq!(lidar.len(), 34_688);
    assert_eq!(lidar.dropped_non_finite, 0);
    let first = lidar.points[0];
    assert_eq!(
        (first.x, first.y, first.z, first.intensity),
        (-3.124_373_4, -0.434_153_68, -1.867_192, 4.0)
    );
    // A quarter of the sweep hits the car itself: 8,526 returns inside 4D-Occ's ego box
    // (counted with numpy on the file), which evaluation and rendering leave out.
    assert_eq!(lidar.scene_indices().len(), 34_688 - 8_526);
    let last = lidar.points[34_687];
    assert_eq!((last.x, last.intensity, last.ring), (-14.113_669, 40.0, 31));
    assert_eq!(first.ring, 0);
    // ego_from_lidar translation [0.943713, 0.0, 1.84023]; ego pose translation [411.3039, 1180.8904, 0].
    assert!(
        (lidar.ego_from_lidar.translation - DVec3::new(0.943713, 0.0, 1.84023)).length() < 1e-12
    );
    assert!(
        (frame.global_from_ego.translation
            - DVec3::new(411.3039349319818, 1180.8903791765097, 0.0))
        .length()
            < 1e-9
    );
    // The LiDAR's rotation is about -90 deg yaw: its +x axis points along ego -y.
    let lidar_x_in_ego = lidar.ego_from_lidar.transform_vector3(DVec3::X);
    assert!(
        (lidar_x_in_ego - DVec3::new(0.0, -1.0, 0.0)).length() < 0.03,
        "{lidar_x_in_ego}"
    );

    // Six cameras in canonical order, each with its own timestamp and ego pose.
    let channels: Vec<CameraChannel> = frame.cameras.iter().map(|c| c.channel).collect();
    assert_eq!(channels, CameraChannel::ALL.to_vec());
    let front = frame.camera(CameraChannel::Front).unwrap();
    assert_eq!(front.timestamp_us, 1_532_402_927_612_460);
    assert_eq!((front.image.width(), front.image.height()), (1600, 900));
    assert!((front.intrinsics.fx - 1266.417203046554).abs() < 1e-9);
    assert!((front.intrinsics.cx - 816.2670197447984).abs() < 1e-9);
    assert!(
        (front.global_from_ego.translation - DVec3::new(411.4199861830012, 1181.197175631848, 0.0))
            .length()
            < 1e-9
    );
    assert!(
        (front.ego_from_camera.translation
            - DVec3::new(1.70079118954, 0.0159456324149, 1.51095763913))
        .length()
            < 1e-12
    );
    // The front camera looks along ego +x (its optical axis is camera +z).
    let optical_axis = front.ego_from_camera.transform_vector3(DVec3::Z);
    assert!(optical_axis.x > 0.99, "{optical_axis}");
    let back = frame.camera(CameraChannel::Back).unwrap();
    assert!(back.ego_from_camera.transform_vector3(DVec3::Z).x < -0.99);
}

#[test]
fn unknown_scene_is_named() {
    let Some(data) = data() else {
        return;
    };
    let error = NuScenes::open(
        &data,
        NuScenesOptions {
            scenes: vec!["scene-9999".into()],
            ..Default::default()
        },
    )
    .err()
    .unwrap();
    let text = error.to_string();
    assert!(
        text.contains("scene.json") && text.contains("scene-9999") && text.contains("scene-0061"),
        "{text}"
    );
}
