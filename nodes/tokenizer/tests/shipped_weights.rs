//! The committed tiny tokenizer (`nodes/tokenizer/weights/tokenizer-tiny.bpk`, with
//! `configs/models/tokenizer-tiny.yaml`) reproduces the reconstruction stored in
//! `tests/fixtures/` of a fixed input: the first keyframe of the held-out synthetic scene 9000.
//!
//! After retraining,
//! `BEVWORLD_BLESS=1 cargo test --release -p bevworld-tokenizer --test tokenizer shipped_weights`
//! rewrites the stored reconstruction (and says so); without it, any drift beyond the
//! tolerances below fails.

use crate::common;

use std::path::{Path, PathBuf};

use bevworld_metrics::{Planes, Roi, chamfer_in_roi, psnr};
use bevworld_pillarize::{Limits, Pillarizer};
use bevworld_sensors::synth::{SynthConfig, generate};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_tokenizer::render::VoxelScene;
use bevworld_tokenizer::render::rays::points_from_depths;
use bevworld_tokenizer::{FrameInputs, load_weights, weights_digest};
use bevworld_types::{LatentStatsFile, stats_path_for};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

/// Every `LIDAR_STRIDE`-th in-range LiDAR ray's depth is stored.
const LIDAR_STRIDE: usize = 97;

fn weights() -> PathBuf {
    common::crate_dir().join("weights/tokenizer-tiny.bpk")
}

fn fixtures() -> PathBuf {
    common::crate_dir().join("tests/fixtures")
}

/// What the stored reconstruction holds besides the front camera's PNG.
#[derive(Debug, Serialize, Deserialize)]
struct Reference {
    weights_digest: String,
    frame_token: String,
    /// Per latent channel.
    latent_mean: Vec<f64>,
    latent_std: Vec<f64>,
    /// Rendered depth of every `LIDAR_STRIDE`-th LiDAR ray, metres.
    lidar_depths: Vec<f32>,
    /// Of all six cameras against the input, and of the whole sweep (4D-Occ ROI).
    psnr_db: f64,
    chamfer_m2: f64,
}

/// Everything the shipped model makes of the fixed frame.
struct Reconstruction {
    reference: Reference,
    /// `[6, 3, H, W]` in [0, 1].
    rgb: Vec<f32>,
    height: usize,
    width: usize,
}

fn reconstruct(data: &Path) -> Reconstruction {
    let config = common::tiny();
    let device = Device::flex();
    let model = load_weights(&config, &weights(), &device).expect("the shipped weights load");
    let frame = Dataset::open(data, &DatasetOptions::default())
        .expect("dataset")
        .read(0)
        .expect("frame 0");
    let inputs = FrameInputs::new(&config);
    let mut points = Vec::new();
    bevworld_pillarize::ego_points_into(&frame.lidar, &mut points);
    let pillars = Pillarizer::new(inputs.pillar_grid(), Limits::default()).run(&points);
    let arrays = inputs
        .encoder_arrays(&frame, &pillars)
        .expect("encoder input");
    let latent = model.encode(arrays.to_input(&device)).latent;
    let values = latent
        .clone()
        .into_data()
        .try_to_vec::<f32>()
        .expect("latent");
    let cells = config.latent_size() * config.latent_size();
    let (mut latent_mean, mut latent_std) = (Vec::new(), Vec::new());
    for plane in values.chunks(cells) {
        let n = plane.len() as f64;
        let mean = plane.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = plane
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n;
        latent_mean.push(mean);
        latent_std.push(var.sqrt());
    }

    let scene = VoxelScene::new(&model, &config, model.voxels(latent));
    let rays = inputs.frame_rays(&frame).expect("rays");
    let rgb = scene.camera_planes(&scene.render_dense(&rays.camera), &rays);
    let [height, width] = config.image_size;
    let planes = |data| Planes {
        data,
        channels: 3,
        height: rays.cameras * height,
        width,
    };
    let psnr_db = psnr(&planes(&rgb), &planes(&arrays.images), 1.0).expect("psnr");

    let lidar = scene.render_dense(&rays.lidar);
    let to_f64 = |p: &[f32; 3]| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
    let predicted: Vec<[f64; 3]> = points_from_depths(&rays.lidar, &lidar.depth)
        .iter()
        .map(to_f64)
        .collect();
    let truth: Vec<[f64; 3]> = points_from_depths(&rays.lidar, &rays.lidar_ranges)
        .iter()
        .map(to_f64)
        .collect();
    let chamfer_m2 = chamfer_in_roi(&predicted, &truth, &Roi::FOUR_D_OCC).chamfer;

    Reconstruction {
        reference: Reference {
            weights_digest: weights_digest(&weights()).expect("digest"),
            frame_token: frame.frame_token.clone(),
            latent_mean,
            latent_std,
            lidar_depths: lidar.depth.iter().step_by(LIDAR_STRIDE).copied().collect(),
            psnr_db,
            chamfer_m2,
        },
        rgb,
        height,
        width,
    }
}

/// The front camera (the first) as 8-bit RGB.
fn front_camera_png(r: &Reconstruction) -> image::RgbImage {
    let plane = r.height * r.width;
    image::RgbImage::from_fn(r.width as u32, r.height as u32, |x, y| {
        let at = y as usize * r.width + x as usize;
        image::Rgb(std::array::from_fn(|c| {
            (r.rgb[c * plane + at].clamp(0.0, 1.0) * 255.0).round() as u8
        }))
    })
}

#[test]
fn the_shipped_weights_reproduce_the_stored_reconstruction() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("synth");
    let held_out = SynthConfig {
        seed: 9000,
        scenes: 1,
        seconds: 0.5,
        camera_width: 224,
        camera_height: 126,
        ..Default::default()
    };
    generate(&data, &held_out, |_, _| {}).expect("synthetic scene");
    let now = reconstruct(&data);
    let (json, png) = (
        fixtures().join("tokenizer-tiny-reconstruction.json"),
        fixtures().join("tokenizer-tiny-reconstruction-CAM_FRONT.png"),
    );
    if std::env::var_os("BEVWORLD_BLESS").is_some() {
        std::fs::create_dir_all(fixtures()).expect("fixtures folder");
        let text = serde_json::to_string_pretty(&now.reference).expect("json");
        std::fs::write(&json, text + "\n").expect("write reference");
        front_camera_png(&now).save(&png).expect("write png");
        eprintln!(
            "BEVWORLD_BLESS: rewrote {} and {}",
            json.display(),
            png.display()
        );
        return;
    }

    let stored: Reference =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("stored reference"))
            .expect("reference parses");
    let r = &now.reference;
    assert_eq!(
        r.weights_digest, stored.weights_digest,
        "the shipped weights changed: rerun with BEVWORLD_BLESS=1 to store their reconstruction"
    );
    assert_eq!(
        r.frame_token, stored.frame_token,
        "the synthetic frame changed"
    );
    for c in 0..stored.latent_mean.len() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-4 * (1.0 + b.abs());
        assert!(
            close(r.latent_mean[c], stored.latent_mean[c])
                && close(r.latent_std[c], stored.latent_std[c]),
            "latent channel {c}: mean {} std {}, stored {} {}",
            r.latent_mean[c],
            r.latent_std[c],
            stored.latent_mean[c],
            stored.latent_std[c]
        );
    }
    assert_eq!(r.lidar_depths.len(), stored.lidar_depths.len());
    let worst = r
        .lidar_depths
        .iter()
        .zip(&stored.lidar_depths)
        .map(|(a, b)| (a - b).abs() / (1.0 + b.abs()))
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-3, "LiDAR depth drifted by {worst} (relative)");
    assert!(
        (r.psnr_db - stored.psnr_db).abs() < 0.02,
        "PSNR {} dB, stored {}",
        r.psnr_db,
        stored.psnr_db
    );
    assert!(
        (r.chamfer_m2 - stored.chamfer_m2).abs() < 1e-3 * (1.0 + stored.chamfer_m2),
        "Chamfer {} m², stored {}",
        r.chamfer_m2,
        stored.chamfer_m2
    );
    let stored_png = image::open(&png).expect("stored png").to_rgb8();
    let now_png = front_camera_png(&now);
    assert_eq!(stored_png.dimensions(), now_png.dimensions());
    let worst = stored_png
        .as_raw()
        .iter()
        .zip(now_png.as_raw())
        .map(|(a, b)| a.abs_diff(*b))
        .max()
        .unwrap_or(0);
    assert!(
        worst <= 2,
        "the front camera differs by {worst}/255 in a pixel"
    );

    // The stored figures are a trained model's, not a random one's.
    assert!(
        stored.psnr_db > 18.0 && stored.chamfer_m2 < 3.0,
        "{stored:?}"
    );
    // Its normalisation statistics ship with it and belong to these weights.
    let stats = LatentStatsFile::load(&stats_path_for(&weights())).expect("shipped stats");
    assert_eq!(stats.weights_hash, r.weights_digest);
    assert_eq!(stats.model, "tokenizer-tiny");
}
