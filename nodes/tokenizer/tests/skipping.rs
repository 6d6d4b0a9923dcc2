//! Empty-space skipping against the dense render, on a scene with a known answer: a field of
//! "empty" voxel features (α ≈ 0 under the model's alpha head) holding one solid box of
//! "occupied" features (α ≈ 1). Rays that hit the box must stop at its face; the skipping
//! renderer must agree with the dense one while evaluating far fewer samples.

use crate::common;

use common::tiny;

use bevworld_blocks::init::{random_normal, random_values};
use bevworld_tokenizer::render::rays::Rays;
use bevworld_tokenizer::render::{OccupancyGrid, SkipOptions, VoxelField, VoxelScene};
use bevworld_tokenizer::{Tokenizer, TokenizerConfig};
use burn::module::Module;
use burn::prelude::*;

/// Two feature vectors whose alpha logits under this model are below −20 and above +20,
/// found among scaled random candidates (the head is piecewise linear, so large inputs
/// saturate α one way or the other).
fn empty_and_occupied(model: &Tokenizer, channels: usize, device: &Device) -> (Vec<f32>, Vec<f32>) {
    let candidates = 512;
    // Read the random draw back once and rebuild the tensor from it, so that the logits and
    // the returned vectors come from the very same values.
    let values: Vec<f32> = random_values(7, candidates * channels, 0.0, 1.0, true)
        .into_iter()
        .map(|v| v * 50.0)
        .collect();
    let features = Tensor::<3>::from_data(
        TensorData::new(values.clone(), [1, candidates, channels]),
        device,
    );
    let logits = model
        .alpha_logits(features)
        .into_data()
        .try_to_vec::<f32>()
        .expect("logits");
    let argmin = (0..candidates)
        .min_by(|&a, &b| logits[a].total_cmp(&logits[b]))
        .expect("candidates");
    let argmax = (0..candidates)
        .max_by(|&a, &b| logits[a].total_cmp(&logits[b]))
        .expect("candidates");
    // The head is piecewise linear: far along a direction the logit grows linearly, so
    // doubling a candidate drives α to 0 or 1 as far as needed.
    let logit_of = |v: &[f32]| -> f32 {
        let t = Tensor::<3>::from_data(TensorData::new(v.to_vec(), [1, 1, channels]), device);
        model
            .alpha_logits(t)
            .into_data()
            .try_to_vec::<f32>()
            .expect("logit")[0]
    };
    let push = |mut v: Vec<f32>, goal: fn(f32) -> bool| -> Vec<f32> {
        for _ in 0..12 {
            if goal(logit_of(&v)) {
                return v;
            }
            v.iter_mut().for_each(|x| *x *= 2.0);
        }
        panic!("no candidate reaches the goal: logit {}", logit_of(&v));
    };
    let row = |i: usize| values[i * channels..(i + 1) * channels].to_vec();
    (
        push(row(argmin), |s| s < -20.0),
        push(row(argmax), |s| s > 20.0),
    )
}

/// The tiny grid (8 x 16 x 128 x 128 over x, y in [-80, 80), z in [-4.5, 4.5]) filled with
/// `empty`, with voxels x in 70..80, y in 60..68, all z (ego x in [7.5, 20), y in [-5, 5)) set
/// to `occupied`.
fn box_scene(
    config: &TokenizerConfig,
    empty: &[f32],
    occupied: &[f32],
    device: &Device,
) -> Tensor<5> {
    let [c, z, y, x] = config.voxel_shape();
    let mut data = vec![0.0f32; c * z * y * x];
    for ch in 0..c {
        for iz in 0..z {
            for iy in 0..y {
                for ix in 0..x {
                    let inside = (70..80).contains(&ix) && (60..68).contains(&iy);
                    let value = if inside { occupied[ch] } else { empty[ch] };
                    data[((ch * z + iz) * y + iy) * x + ix] = value;
                }
            }
        }
    }
    Tensor::from_data(TensorData::new(data, [1, c, z, y, x]), device)
}

/// Horizontal rays from the ego origin at 0.5 m height, fanned over 360°.
fn fan(count: usize) -> Rays {
    Rays {
        origins: vec![[0.0, 0.0, 0.5]; count],
        directions: (0..count)
            .map(|i| {
                let a = i as f32 / count as f32 * std::f32::consts::TAU;
                [a.cos(), a.sin(), 0.0]
            })
            .collect(),
    }
}

#[test]
fn skipping_matches_dense_on_a_box_and_skips_most_samples() {
    let device = Device::flex();
    let config = tiny();
    let model = config.init_seeded(7, &device);
    let channels = config.decoder.voxel_channels;
    let (empty, occupied) = empty_and_occupied(&model, channels, &device);
    let voxels = box_scene(&config, &empty, &occupied, &device);
    let scene = VoxelScene::new(&model, &config, VoxelField::from_grid(voxels));
    let rays = fan(360);

    let dense = scene.render_dense(&rays);
    // A threshold well below the default 1e-3: samples that mix empty and occupied features at
    // the box's faces can have α just under a threshold, and each skipped one shifts the depth
    // by up to α·t. At 1e-5 that stays under a millimetre per sample.
    let options = SkipOptions {
        alpha_threshold: 1e-5,
        ..SkipOptions::default()
    };
    let grid = OccupancyGrid::build(&scene, &options);
    assert!(
        grid.occupied_fraction > 0.0 && grid.occupied_fraction < 0.01,
        "occupied fraction {}",
        grid.occupied_fraction
    );
    let skipped = scene.render_skipping(&grid, &rays, &options);

    // The box spans azimuths atan2(±5, 7.5..20): rays at 0° hit its near face at x = 7.5 m.
    let hit = 0;
    assert!(dense.opacity[hit] > 0.999, "opacity {}", dense.opacity[hit]);
    // Samples lie every (80 − 0.5) / 47 ≈ 1.69 m: at 7.27 m (30% into the face voxel by
    // interpolation) and at 8.96 m (inside). The depth must lie between them.
    let spacing = (80.0 - 0.5) / 47.0;
    let (before, after) = (0.5 + 4.0 * spacing, 0.5 + 5.0 * spacing);
    assert!(
        (before..=after + 1e-3).contains(&dense.depth[hit]),
        "dense depth at 0°: {} (face at 7.5 m)",
        dense.depth[hit]
    );
    // Early stop drops at most T < 1e-4 of a ray's weight (≤ 8 mm at 80 m); skipping drops
    // samples of α ≤ ~1e-5.
    for r in 0..rays.len() {
        assert!(
            (dense.depth[r] - skipped.depth[r]).abs() < 0.01,
            "ray {r}: dense depth {} vs skipping {}",
            dense.depth[r],
            skipped.depth[r]
        );
        assert!((dense.opacity[r] - skipped.opacity[r]).abs() < 1e-3);
        for c in 0..channels {
            let (a, b) = (
                dense.features[r * channels + c],
                skipped.features[r * channels + c],
            );
            assert!(
                (a - b).abs() < 1e-2 * (1.0 + a.abs()),
                "ray {r} channel {c}: {a} vs {b}"
            );
        }
    }
    assert_eq!(dense.samples_evaluated, dense.samples_dense);
    assert!(
        skipped.samples_evaluated * 4 < dense.samples_evaluated,
        "skipping evaluated {} of {} samples",
        skipped.samples_evaluated,
        dense.samples_evaluated
    );
}

#[test]
fn with_escape_at_far_a_ray_that_misses_everything_ends_at_the_far_plane() {
    let device = Device::flex();
    let plain_config = tiny();
    let escape_config = TokenizerConfig {
        render: bevworld_tokenizer::config::RenderConfig {
            escape_at_far: true,
            ..plain_config.render.clone()
        },
        ..plain_config.clone()
    };
    // Both models hold the same parameters; only the escape differs.
    let plain = plain_config.init_seeded(7, &device);
    let escaping = escape_config
        .init(&device)
        .load_record(plain.clone().into_record());
    let far = plain_config.render.far as f32;
    assert_eq!((plain.escape_depth(), escaping.escape_depth()), (0.0, far));
    let channels = plain_config.decoder.voxel_channels;
    let (empty, occupied) = empty_and_occupied(&plain, channels, &device);
    let voxels = box_scene(&plain_config, &empty, &occupied, &device);
    let rays = fan(360);
    let options = SkipOptions {
        alpha_threshold: 1e-5,
        ..SkipOptions::default()
    };
    let render = |model: &Tokenizer, config: &TokenizerConfig| {
        let scene = VoxelScene::new(model, config, VoxelField::from_grid(voxels.clone()));
        let grid = OccupancyGrid::build(&scene, &options);
        (
            scene.render_dense(&rays),
            scene.render_skipping(&grid, &rays, &options),
        )
    };
    let (plain_dense, _) = render(&plain, &plain_config);
    let (dense, skipped) = render(&escaping, &escape_config);
    // The ray at 0° stops in the box: nothing escapes, and the depth is the plain one.
    assert!(dense.opacity[0] > 0.999, "opacity {}", dense.opacity[0]);
    assert!(
        (dense.depth[0] - plain_dense.depth[0]).abs() < 1e-3 * far,
        "{} {} {}",
        dense.depth[0],
        plain_dense.depth[0],
        plain_dense.opacity[0]
    );
    // The ray at 225° crosses only empty voxels out to the far plane (at 80 m it is at
    // x = y = −56.6 m, inside the ±80 m grid; along an axis the last samples would reach the
    // grid's edge, where the field is not `empty`): α is below e^-20 at every sample. Plainly
    // it ends at the sensor; escaping, at the far plane, as 4D-Occ's renderer ends it at the
    // grid's exit. Dense and skipping renders agree on every ray.
    let miss = 225;
    assert!(
        dense.opacity[miss] < 1e-6,
        "opacity {}",
        dense.opacity[miss]
    );
    assert!(
        plain_dense.depth[miss] < 1e-3,
        "{}",
        plain_dense.depth[miss]
    );
    assert!(
        (dense.depth[miss] - far).abs() < 1e-3,
        "{}",
        dense.depth[miss]
    );
    for r in 0..rays.len() {
        let expected = plain_dense.depth[r] + (1.0 - plain_dense.opacity[r]) * far;
        assert!(
            (dense.depth[r] - expected).abs() < 1e-3 * far,
            "ray {r}: {} against {expected}",
            dense.depth[r]
        );
        assert!(
            (dense.depth[r] - skipped.depth[r]).abs() < 0.01,
            "ray {r}: dense depth {} vs skipping {}",
            dense.depth[r],
            skipped.depth[r]
        );
    }
}

#[test]
fn skipping_nothing_reproduces_the_dense_render() {
    let device = Device::flex();
    let config = tiny();
    let model = config.init_seeded(0, &device);
    let [c, z, y, x] = config.voxel_shape();
    let voxels = random_normal(8, [1, c, z, y, x], 0.0, 1.0, &device);
    let scene = VoxelScene::new(&model, &config, VoxelField::from_grid(voxels));
    let rays = fan(64);
    let keep_all = SkipOptions {
        alpha_threshold: -1.0,
        stop_transmittance: 0.0,
        segment: 7, // not a divisor of 48: the last segment is padded
        ..SkipOptions::default()
    };
    let grid = OccupancyGrid::build(&scene, &keep_all);
    let dense = scene.render_dense(&rays);
    let skipped = scene.render_skipping(&grid, &rays, &keep_all);
    assert_eq!(skipped.samples_evaluated, dense.samples_dense);
    for r in 0..rays.len() {
        assert!((dense.depth[r] - skipped.depth[r]).abs() < 1e-3 * (1.0 + dense.depth[r]));
        assert!((dense.opacity[r] - skipped.opacity[r]).abs() < 1e-5);
    }
    for (a, b) in dense.features.iter().zip(&skipped.features) {
        assert!((a - b).abs() < 1e-4 * (1.0 + a.abs()), "{a} vs {b}");
    }
}

#[test]
fn skip_options_name_every_bad_field() {
    let bad = SkipOptions {
        alpha_threshold: f32::NAN,
        cell: 0,
        stop_transmittance: 1.5,
        segment: 0,
        dilate: true,
    };
    let problems = bad.problems().join("\n");
    for field in ["alpha_threshold", "cell", "stop_transmittance", "segment"] {
        assert!(problems.contains(field), "{problems}");
    }
    assert!(SkipOptions::default().problems().is_empty());
}

/// On the CPU outside autodiff, rendering runs as one fused host kernel (`render::march`);
/// under autodiff it runs burn's ops. The same scene must render the same, dense and skipping.
#[test]
fn the_fused_cpu_march_equals_the_tensor_path() {
    let host = Device::flex();
    let config = tiny();
    let model = config.init_seeded(3, &host);
    let [c, z, y, x] = config.voxel_shape();
    let voxels = random_normal(9, [1, c, z, y, x], 0.0, 1.0, &host);
    let rays = fan(96);
    // The tensor path checks its early stop every `segment` samples, the march every 16.
    let options = SkipOptions {
        alpha_threshold: 0.3,
        stop_transmittance: 1e-2,
        segment: 16,
        ..SkipOptions::default()
    };
    let render = |device: &Device| {
        let model = model.clone().to_device(device);
        let field = VoxelField::from_grid(Tensor::from_data(voxels.clone().into_data(), device));
        let scene = VoxelScene::new(&model, &config, field);
        let grid = OccupancyGrid::build(&scene, &options);
        (
            scene.render_dense(&rays),
            scene.render_skipping(&grid, &rays, &options),
        )
    };
    let (march_dense, march_skipping) = render(&host);
    let (tensor_dense, tensor_skipping) = render(&host.clone().autodiff());
    for (march, tensors) in [
        (&march_dense, &tensor_dense),
        (&march_skipping, &tensor_skipping),
    ] {
        assert_eq!(march.samples_evaluated, tensors.samples_evaluated);
        for r in 0..rays.len() {
            assert!(
                (march.depth[r] - tensors.depth[r]).abs() < 1e-4 * (1.0 + tensors.depth[r]),
                "ray {r}: depth {} vs {}",
                march.depth[r],
                tensors.depth[r]
            );
            assert!((march.opacity[r] - tensors.opacity[r]).abs() < 1e-5);
        }
        for (a, b) in march.features.iter().zip(&tensors.features) {
            assert!((a - b).abs() < 1e-4 * (1.0 + b.abs()), "{a} vs {b}");
        }
    }
    assert!(
        march_skipping.samples_evaluated < march_dense.samples_evaluated,
        "the skipping march skipped nothing: {} of {}",
        march_skipping.samples_evaluated,
        march_dense.samples_evaluated
    );
}
