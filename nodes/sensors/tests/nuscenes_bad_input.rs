//! Bad input to the nuScenes reader: each case gets a clear error naming the file and field,
//! never a panic. Cases are made on a temporary copy of the real keyframe.

use std::path::{Path, PathBuf};

use bevworld_sensors::nuscenes::{NuScenes, NuScenesOptions};
use bevworld_sensors::{NonFinitePolicy, SensorError};

fn data() -> Option<PathBuf> {
    bevworld_sensors::real_dataset("nuscenes-sample")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
            let mut permissions = std::fs::metadata(&target).unwrap().permissions();
            #[allow(clippy::permissions_set_readonly_false)]
            permissions.set_readonly(false);
            std::fs::set_permissions(&target, permissions).unwrap();
        }
    }
}

/// A writable copy of the real sample, when it is there.
fn sample_copy() -> Option<tempfile::TempDir> {
    let data = data()?;
    let dir = tempfile::tempdir().unwrap();
    copy_dir(&data, dir.path());
    Some(dir)
}

fn table(dir: &Path, name: &str) -> PathBuf {
    dir.join("v1.0-mini").join(format!("{name}.json"))
}

fn edit_table(dir: &Path, name: &str, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = table(dir, name);
    let mut value: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    edit(&mut value);
    std::fs::write(&path, serde_json::to_vec(&value).unwrap()).unwrap();
}

fn front_camera_file(dir: &Path) -> PathBuf {
    std::fs::read_dir(dir.join("samples/CAM_FRONT"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path()
}

fn lidar_file(dir: &Path) -> PathBuf {
    let folder = dir.join("samples/LIDAR_TOP");
    std::fs::read_dir(folder)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path()
}

fn open(dir: &Path) -> Result<NuScenes, SensorError> {
    NuScenes::open(dir, NuScenesOptions::default())
}

#[test]
fn missing_table_names_the_file() {
    let Some(dir) = sample_copy() else {
        return;
    };
    std::fs::remove_file(table(dir.path(), "ego_pose")).unwrap();
    let error = open(dir.path()).err().unwrap().to_string();
    assert!(
        error.contains("ego_pose.json") && error.contains("cannot read"),
        "{error}"
    );
}

#[test]
fn missing_sensor_file_names_the_file() {
    let Some(dir) = sample_copy() else {
        return;
    };
    std::fs::remove_file(lidar_file(dir.path())).unwrap();
    let dataset = open(dir.path()).unwrap();
    let error = dataset.read(0).err().unwrap().to_string();
    assert!(
        error.contains("LIDAR_TOP") && error.contains("cannot read"),
        "{error}"
    );
}

#[test]
fn truncated_pcd_bin_is_reported_with_its_length() {
    let Some(dir) = sample_copy() else {
        return;
    };
    let path = lidar_file(dir.path());
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 7]).unwrap();
    let error = open(dir.path()).unwrap().read(0).err().unwrap().to_string();
    assert!(
        error.contains(".pcd.bin")
            && error.contains("not a multiple of 20")
            && error.contains("13 trailing"),
        "{error}"
    );
}

#[test]
fn nan_and_inf_points_are_dropped_and_counted_or_rejected() {
    let Some(dir) = sample_copy() else {
        return;
    };
    let path = lidar_file(dir.path());
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[0..4].copy_from_slice(&f32::NAN.to_le_bytes()); // point 0: x
    bytes[20 * 5 + 8..20 * 5 + 12].copy_from_slice(&f32::INFINITY.to_le_bytes()); // point 5: z
    std::fs::write(&path, &bytes).unwrap();
    let frame = open(dir.path()).unwrap().read(0).unwrap();
    assert_eq!(frame.lidar.len(), 34_688 - 2);
    assert_eq!(frame.lidar.dropped_non_finite, 2);
    let strict = NuScenes::open(
        dir.path(),
        NuScenesOptions {
            non_finite: NonFinitePolicy::Error,
            ..Default::default()
        },
    )
    .unwrap();
    let error = strict.read(0).err().unwrap().to_string();
    assert!(
        error.contains(".pcd.bin") && error.contains("point 0 has a non-finite value"),
        "{error}"
    );
}

#[test]
fn corrupt_jpeg_names_the_image() {
    let Some(dir) = sample_copy() else {
        return;
    };
    let path = front_camera_file(dir.path());
    let mut bytes = std::fs::read(&path).unwrap();
    // Garbage over the SOI marker and the first segments.
    for (i, byte) in bytes.iter_mut().take(600).enumerate() {
        *byte = (i * 37 % 251) as u8;
    }
    std::fs::write(&path, &bytes).unwrap();
    let error = open(dir.path()).unwrap().read(0).err().unwrap().to_string();
    assert!(
        error.contains("CAM_FRONT") && error.contains("corrupt image"),
        "{error}"
    );
}

#[test]
fn unknown_camera_channel_is_named() {
    let Some(dir) = sample_copy() else {
        return;
    };
    edit_table(dir.path(), "sensor", |sensors| {
        for sensor in sensors.as_array_mut().unwrap() {
            if sensor["channel"] == "CAM_BACK" {
                sensor["channel"] = "CAM_ROOF".into();
            }
        }
    });
    let error = open(dir.path()).err().unwrap().to_string();
    assert!(
        error.contains("sensor.json") && error.contains("'channel'") && error.contains("CAM_ROOF"),
        "{error}"
    );
}

#[test]
fn dangling_token_names_table_record_and_field() {
    let Some(dir) = sample_copy() else {
        return;
    };
    edit_table(dir.path(), "sample_data", |rows| {
        rows[2]["ego_pose_token"] = "0000deadbeef".into();
    });
    let error = open(dir.path()).err().unwrap().to_string();
    assert!(
        error.contains("sample_data.json")
            && error.contains("'ego_pose_token'")
            && error.contains("0000deadbeef"),
        "{error}"
    );
}

#[test]
fn non_monotonic_timestamps_are_rejected() {
    let Some(dir) = sample_copy() else {
        return;
    };
    // Add a second keyframe linked after the first but stamped before it.
    edit_table(dir.path(), "sample", |rows| {
        let mut second = rows[0].clone();
        second["token"] = "second".into();
        second["timestamp"] = (rows[0]["timestamp"].as_i64().unwrap() - 500_000).into();
        second["prev"] = rows[0]["token"].clone();
        rows[0]["next"] = "second".into();
        rows.as_array_mut().unwrap().push(second);
    });
    let error = open(dir.path()).err().unwrap().to_string();
    assert!(
        error.contains("sample.json")
            && error.contains("'timestamp'")
            && error.contains("not strictly increasing"),
        "{error}"
    );
}

#[test]
fn malformed_table_json_names_the_table() {
    let Some(dir) = sample_copy() else {
        return;
    };
    std::fs::write(table(dir.path(), "calibrated_sensor"), "[{\"token\": 3}]").unwrap();
    let error = open(dir.path()).err().unwrap().to_string();
    assert!(
        error.contains("calibrated_sensor.json") && error.contains("not valid JSON for table"),
        "{error}"
    );
}

#[test]
fn impossible_focal_lengths_are_refused_naming_the_calibration() {
    for (fx, fy) in [(0.0, 1266.0), (-1266.0, 1266.0), (1266.0, 0.0)] {
        let Some(dir) = sample_copy() else {
            return;
        };
        edit_table(dir.path(), "calibrated_sensor", |rows| {
            for row in rows.as_array_mut().unwrap() {
                if row["camera_intrinsic"]
                    .as_array()
                    .is_some_and(|m| m.len() == 3)
                {
                    row["camera_intrinsic"][0][0] = fx.into();
                    row["camera_intrinsic"][1][1] = fy.into();
                }
            }
        });
        let error = match open(dir.path()).and_then(|d| d.read(0)) {
            Ok(_) => panic!("focal lengths {fx}, {fy} were accepted"),
            Err(error) => error.to_string(),
        };
        assert!(
            error.contains("calibrated_sensor.json")
                && error.contains("camera_intrinsic")
                && error.contains("focal lengths"),
            "{error}"
        );
    }
}

#[test]
fn a_truncated_jpeg_is_an_error_not_a_grey_image() {
    let Some(dir) = sample_copy() else {
        return;
    };
    let path = front_camera_file(dir.path());
    let bytes = std::fs::read(&path).unwrap();
    // Cut to a third, as an interrupted copy leaves it.
    std::fs::write(&path, &bytes[..bytes.len() / 3]).unwrap();
    let error = open(dir.path()).unwrap().read(0).err().unwrap().to_string();
    assert!(
        error.contains("CAM_FRONT") && error.contains("truncated JPEG"),
        "{error}"
    );
}

#[test]
fn a_jpeg_with_scrambled_bytes_is_an_error_not_a_grey_image() {
    let Some(dir) = sample_copy() else {
        return;
    };
    let path = front_camera_file(dir.path());
    let bytes = std::fs::read(&path).unwrap();
    // Whole, it decodes.
    assert!(bevworld_sensors::image_file::decode_rgb(&bytes).is_ok());
    // Scrambled in the entropy-coded middle (a bad sector, a broken copy), with its header
    // and end-of-image marker intact.
    let mut scrambled = bytes.clone();
    let (start, end) = (scrambled.len() / 3, scrambled.len() / 3 + 4096);
    let mut state = 0x9e37_79b9_u32;
    for byte in &mut scrambled[start..end] {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        *byte = state as u8;
    }
    std::fs::write(&path, &scrambled).unwrap();
    let error = open(dir.path()).unwrap().read(0).err().unwrap().to_string();
    assert!(
        error.contains("CAM_FRONT") && error.contains("corrupt JPEG"),
        "{error}"
    );
}

#[test]
fn non_unit_quaternions_are_normalised_and_counted() {
    let Some(dir) = sample_copy() else {
        return;
    };
    assert_eq!(open(dir.path()).unwrap().non_unit_quaternions(), 0);
    edit_table(dir.path(), "ego_pose", |rows| {
        let rotation = &mut rows[0]["rotation"];
        for k in 0..4 {
            let v = rotation[k].as_f64().unwrap();
            rotation[k] = (2.0 * v).into();
        }
    });
    let scaled = open(dir.path()).unwrap();
    assert_eq!(scaled.non_unit_quaternions(), 1);
    // Normalised where it is used: the frame's pose is a rotation still.
    let frame = scaled.read(0).unwrap();
    let rotation = glam::DMat3::from_mat4(glam::DMat4::from(frame.global_from_ego));
    let should_be_identity = rotation.transpose() * rotation;
    assert!(
        should_be_identity.abs_diff_eq(glam::DMat3::IDENTITY, 1e-9),
        "{should_be_identity:?}"
    );
}
