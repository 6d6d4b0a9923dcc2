//! `bevworld eval` on the real KITTI scans and on bad input.

use std::path::PathBuf;
use std::process::{Command, Output};

fn bevworld(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args(args)
        .current_dir(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

fn kitti() -> Option<PathBuf> {
    bevworld_sensors::real_dataset("kitti-odometry-00")
}

fn json(output: &Output) -> serde_json::Value {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).unwrap()
}

#[test]
fn chamfer_of_a_scan_with_itself_is_zero_and_counts_follow_the_roi() {
    let Some(kitti) = kitti() else {
        return;
    };
    let scan = kitti.clone().join("velodyne/000000.bin");
    let s = scan.to_str().unwrap();
    let same = json(&bevworld(&[
        "eval", "chamfer", "--pred", s, "--gt", s, "--json",
    ]));
    assert_eq!(same["chamfer"], 0.0);
    let all = same["pred_points"].as_u64().unwrap();
    assert!(
        all > 100_000 && all < 124_669,
        "{all} points in the 4D-Occ ROI"
    );
    let vidar = json(&bevworld(&[
        "eval", "chamfer", "--pred", s, "--gt", s, "--roi", "vidar", "--json",
    ]));
    assert!(
        vidar["pred_points"].as_u64().unwrap() < all,
        "the ViDAR ROI is smaller"
    );
}

#[test]
fn chamfer_reads_ply_and_agrees_across_formats() {
    // A PLY written by hand: two points 1 m apart in x from the single ground-truth point.
    let dir = tempfile::tempdir().unwrap();
    let pred = dir.path().join("pred.ply");
    std::fs::write(&pred, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 0 0\n-1 0 0\n").unwrap();
    let gt = dir.path().join("gt.pcd.bin");
    let mut bytes = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 5.0, 0.0] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(&gt, &bytes).unwrap();
    let result = json(&bevworld(&[
        "eval",
        "chamfer",
        "--pred",
        pred.to_str().unwrap(),
        "--gt",
        gt.to_str().unwrap(),
        "--json",
    ]));
    // pred -> gt: 1 and 1, mean 1; gt -> pred: 1; CD = (1 + 1) / 2 = 1.
    assert_eq!(result["chamfer"], 1.0);
    assert_eq!(
        (result["pred_points"].as_u64(), result["gt_points"].as_u64()),
        (Some(2), Some(1))
    );
}

#[test]
fn ego_warp_beats_copy_last_on_real_kitti() {
    let Some(kitti) = kitti() else {
        return;
    };
    let rows = json(&bevworld(&[
        "eval",
        "baselines",
        "--data",
        kitti.clone().to_str().unwrap(),
        "--format",
        "kitti",
        "--horizons",
        "1,3,5",
        "--json",
    ]));
    let value = |method: &str, horizon: u64| {
        rows.as_array()
            .unwrap()
            .iter()
            .find(|r| r["method"] == method && r["horizon_frames"] == horizon)
            .unwrap()["chamfer"]
            .as_f64()
            .unwrap()
    };
    for horizon in [1, 3, 5] {
        assert!(
            value("ego_warp", horizon) < value("copy_last", horizon),
            "horizon {horizon}"
        );
    }
    // The static-world forecast degrades with the horizon.
    assert!(
        value("copy_last", 1) < value("copy_last", 3)
            && value("copy_last", 3) < value("copy_last", 5)
    );
}

#[test]
fn bad_input_is_a_clear_error() {
    let Some(kitti) = kitti() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let odd = dir.path().join("cloud.xyz");
    std::fs::write(&odd, b"1 2 3").unwrap();
    let output = bevworld(&[
        "eval",
        "chamfer",
        "--pred",
        odd.to_str().unwrap(),
        "--gt",
        odd.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&output.stderr).contains("cloud.xyz: cannot tell the format"));
    let truncated = dir.path().join("t.bin");
    std::fs::write(&truncated, [0u8; 15]).unwrap();
    let output = bevworld(&[
        "eval",
        "chamfer",
        "--pred",
        truncated.to_str().unwrap(),
        "--gt",
        truncated.to_str().unwrap(),
    ]);
    assert!(
        String::from_utf8_lossy(&output.stderr).contains("t.bin")
            && String::from_utf8_lossy(&output.stderr).contains("truncated")
    );
    let output = bevworld(&[
        "eval",
        "baselines",
        "--data",
        kitti.clone().to_str().unwrap(),
        "--format",
        "kitti",
        "--horizons",
        "0",
    ]);
    assert!(
        String::from_utf8_lossy(&output.stderr).contains("--horizons must be frame counts >= 1")
    );
    let Some(nuscenes) = bevworld_sensors::real_dataset("nuscenes-sample") else {
        return;
    };
    let output = bevworld(&[
        "eval",
        "baselines",
        "--data",
        nuscenes.to_str().unwrap(),
        "--format",
        "nuscenes",
    ]);
    assert!(
        String::from_utf8_lossy(&output.stderr).contains("has a frame 1 frames after its first")
    );
}

#[test]
fn fid_without_inception_weights_says_so_and_fails() {
    let dir = tempfile::tempdir().expect("tempdir");
    for name in ["a.png", "b.png"] {
        image::RgbImage::from_pixel(8, 8, image::Rgb([10, 20, 30]))
            .save(dir.path().join(name))
            .expect("png");
    }
    let folder = dir.path().to_str().expect("utf-8");
    let out = bevworld(&["eval", "fid", "--pred", folder, "--gt", folder]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("FID needs InceptionV3 weights"), "{stderr}");
    assert!(stderr.contains("FID was not computed"), "{stderr}");
    assert!(
        out.stdout.is_empty(),
        "no number may be printed without weights"
    );

    let missing = dir.path().join("pt_inception.pth");
    let out = bevworld(&[
        "eval",
        "fid",
        "--pred",
        folder,
        "--gt",
        folder,
        "--inception",
        missing.to_str().expect("utf-8"),
    ]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("pt_inception.pth: file not found"),
        "{stderr}"
    );
}
