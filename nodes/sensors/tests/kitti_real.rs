//! The KITTI reader on the 6 real scans in ../shared/data/kitti-odometry-00.

use std::path::{Path, PathBuf};

use bevworld_sensors::kitti::Kitti;
use bevworld_sensors::{Dataset, DatasetOptions, NonFinitePolicy};
use glam::DVec3;

fn data() -> Option<PathBuf> {
    bevworld_sensors::real_dataset("kitti-odometry-00")
}

#[test]
fn reads_scans_poses_and_times() {
    let Some(data) = data() else {
        return;
    };
    let kitti = Kitti::open(&data, NonFinitePolicy::Drop).unwrap();
    assert_eq!(kitti.len(), 6);
    // 000000.bin is 1,994,688 bytes of float32 x 4.
    let frame0 = kitti.decode(kitti.fetch(0).unwrap()).unwrap();
    assert_eq!(
        frame0.lidar.len() + frame0.lidar.dropped_non_finite,
        1_994_688 / 16
    );
    assert_eq!(frame0.time_of_validity_us, 0);
    // Frame 0's pose is the identity (up to the file's rounding).
    assert!(frame0.global_from_ego.translation.length() < 1e-6); // P_0 is stored to 7 digits
    let frame1 = kitti.decode(kitti.fetch(1).unwrap()).unwrap();
    assert_eq!(frame1.time_of_validity_us, 103_736); // 1.037359e-01 s
    // Camera 0 moved +0.8587 m along its z (forward) axis; the velodyne's x is forward,
    // so the velodyne pose moves ~0.86 m along +x: Tr^-1 * P_1 * Tr.
    let t = frame1.global_from_ego.translation;
    assert!(
        (t.x - 0.858).abs() < 0.01 && t.y.abs() < 0.1 && t.z.abs() < 0.05,
        "{t}"
    );
    let action = frame0.action.unwrap();
    assert!(
        (action.speed_mps - t.x / 0.103736).abs() < 0.2,
        "{action:?}"
    );
}

#[test]
fn velodyne_pose_is_tr_inverse_p_tr() {
    let Some(data) = data() else {
        return;
    };
    // By hand: Tr and P_1 from the files; the conjugation must agree with the reader's pose.
    let read = |name: &str| std::fs::read_to_string(data.clone().join(name)).unwrap();
    let parse = |line: &str| -> glam::DAffine3 {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        glam::DAffine3 {
            matrix3: glam::DMat3::from_cols(
                DVec3::new(v[0], v[4], v[8]),
                DVec3::new(v[1], v[5], v[9]),
                DVec3::new(v[2], v[6], v[10]),
            ),
            translation: DVec3::new(v[3], v[7], v[11]),
        }
    };
    let calib = read("calib.txt");
    let tr = parse(calib.trim_start_matches("Tr:"));
    let poses = read("poses.txt");
    let p1 = parse(poses.lines().nth(1).unwrap());
    let expected = tr.inverse() * p1 * tr;
    let kitti = Kitti::open(&data, NonFinitePolicy::Drop).unwrap();
    let got = kitti.pose(1).unwrap();
    assert!((got.translation - expected.translation).length() < 1e-12);
    assert!((got.matrix3 - expected.matrix3).abs_diff_eq(glam::DMat3::ZERO, 1e-12));
}

/// Copies the first two scans of the real sequence to `to`; false when it is not there.
fn copy_sequence(to: &Path) -> bool {
    let Some(data) = data() else {
        return false;
    };
    std::fs::create_dir_all(to.join("velodyne")).unwrap();
    for name in ["calib.txt", "poses.txt", "times.txt"] {
        std::fs::copy(data.join(name), to.join(name)).unwrap();
    }
    for k in 0..2 {
        let name = format!("velodyne/{k:06}.bin");
        std::fs::copy(data.join(&name), to.join(&name)).unwrap();
    }
    true
}

#[test]
fn auto_format_recognises_kitti() {
    let Some(data) = data() else {
        return;
    };
    let dataset = Dataset::open(&data, &DatasetOptions::default()).unwrap();
    assert_eq!(dataset.len(), 6);
}

#[test]
fn malformed_calib_poses_and_times_name_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    if !copy_sequence(dir.path()) {
        return;
    }
    std::fs::write(dir.path().join("calib.txt"), "Tr: 1 2 3\n").unwrap();
    let error = Kitti::open(dir.path(), NonFinitePolicy::Drop)
        .err()
        .unwrap()
        .to_string();
    assert!(
        error.contains("calib.txt") && error.contains("'Tr'") && error.contains("needs 12"),
        "{error}"
    );

    if !copy_sequence(dir.path()) {
        return;
    }
    std::fs::write(dir.path().join("calib.txt"), "P0: 1 2\n").unwrap();
    let error = Kitti::open(dir.path(), NonFinitePolicy::Drop)
        .err()
        .unwrap()
        .to_string();
    assert!(
        error.contains("calib.txt") && error.contains("missing"),
        "{error}"
    );

    if !copy_sequence(dir.path()) {
        return;
    }
    std::fs::write(
        dir.path().join("poses.txt"),
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 x 0 1 0 0 0 0 1 0\n",
    )
    .unwrap();
    let error = Kitti::open(dir.path(), NonFinitePolicy::Drop)
        .err()
        .unwrap()
        .to_string();
    assert!(
        error.contains("poses.txt") && error.contains("line 2") && error.contains("'x'"),
        "{error}"
    );

    if !copy_sequence(dir.path()) {
        return;
    }
    std::fs::write(dir.path().join("times.txt"), "0.0\n0.2\n0.1\n").unwrap();
    let error = Kitti::open(dir.path(), NonFinitePolicy::Drop)
        .err()
        .unwrap()
        .to_string();
    assert!(
        error.contains("times.txt") && error.contains("line 3") && error.contains("non-monotonic"),
        "{error}"
    );
}

#[test]
fn truncated_scan_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    if !copy_sequence(dir.path()) {
        return;
    }
    let path = dir.path().join("velodyne/000001.bin");
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
    let kitti = Kitti::open(dir.path(), NonFinitePolicy::Drop).unwrap();
    let error = kitti
        .decode(kitti.fetch(1).unwrap())
        .err()
        .unwrap()
        .to_string();
    assert!(
        error.contains("000001.bin") && error.contains("truncated"),
        "{error}"
    );
}

#[test]
fn an_empty_scan_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    if !copy_sequence(dir.path()) {
        return;
    }
    let path = dir.path().join("velodyne/000002.bin");
    std::fs::write(&path, b"").unwrap();
    let kitti = Kitti::open(dir.path(), NonFinitePolicy::Drop).unwrap();
    let error = kitti
        .decode(kitti.fetch(2).unwrap())
        .err()
        .unwrap()
        .to_string();
    assert!(
        error.contains("000002.bin") && error.contains("empty"),
        "{error}"
    );
}

#[test]
fn a_kitti_folder_without_poses_is_named_as_such_under_auto() {
    let dir = tempfile::tempdir().unwrap();
    if !copy_sequence(dir.path()) {
        return;
    }
    std::fs::remove_file(dir.path().join("poses.txt")).unwrap();
    let error = match Dataset::open(dir.path(), &DatasetOptions::default()) {
        Ok(_) => panic!("a sequence without poses was opened"),
        Err(error) => error.to_string(),
    };
    assert!(
        error.contains("no poses.txt") && error.contains("KITTI odometry"),
        "{error}"
    );
}
