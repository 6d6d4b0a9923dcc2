//! The assembled tiny tokenizer runs end to end: encode, lift, render rays, upsample to RGB,
//! with the shapes the config promises and depths inside the sampled range.

use std::path::PathBuf;

use bevworld_blocks::init::{random_normal, random_tensor};
use bevworld_tokenizer::TokenizerConfig;
use bevworld_tokenizer::model::EncoderInput;
use bevworld_tokenizer::render::rays::{Rays, sample_positions};
use burn::prelude::*;

#[test]
fn tiny_tokenizer_runs_end_to_end() {
    let device = Device::flex();
    let path = PathBuf::from(
        std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"),
    )
    .join("../../configs/models/tokenizer-tiny.yaml");
    let config = TokenizerConfig::from_yaml_file(&path).expect("tiny config");
    let model = config.init_seeded(0, &device);
    let [h, w] = config.image_size;
    let n = config.latent_size();
    let (cameras, k) = (config.cameras, config.fusion_heights);

    let pillars = 5;
    let input = EncoderInput {
        images: random_tensor(1, [cameras, 3, h, w], 0.0, 1.0, &device),
        pillar_points: random_normal(2, [pillars, 20, 9], 0.0, 1.0, &device),
        pillar_valid: Tensor::ones([pillars, 20], &device),
        pillar_cells: Tensor::from_data(
            TensorData::new(vec![0i64, 77, 500, 9000, 16383], [pillars]),
            &device,
        ),
        reference: random_tensor(3, [cameras, n * n, k, 2], -1.0, 1.0, &device),
        reference_valid: Tensor::ones([cameras, n * n, k], &device),
    };
    let encoded = model.encode(input);
    assert_eq!(encoded.latent.dims(), [1, config.latent_channels, n, n]);
    assert_eq!(encoded.fused.dims(), [1, config.fused_channels(), n, n]);

    let voxels = model.voxels(encoded.latent);
    let [cv, z, y, x] = config.voxel_shape();
    assert_eq!(voxels.shape.voxels(), [z, y, x]);
    assert_eq!(voxels.table().dims(), [z * y * x, cv]);

    // A handful of rays from near the ego origin, in arbitrary directions.
    let rays = Rays {
        origins: vec![[0.0, 0.0, 1.5]; 4],
        directions: vec![
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.6, 0.8, 0.0],
            [0.0, 0.6, -0.8],
        ],
    };
    let depths = config.render.sample_depths();
    let positions = sample_positions(&rays, &depths, &config.voxel_placement());
    let depth_row =
        Tensor::<2>::from_data(TensorData::new(depths.clone(), [1, depths.len()]), &device);
    let rendered = model.render_rays(&voxels, &positions, rays.len(), depth_row);
    assert_eq!(rendered.features.dims(), [4, cv]);
    let depth = rendered.depth.into_data().try_to_vec::<f32>().unwrap();
    let opacity = rendered.opacity.into_data().try_to_vec::<f32>().unwrap();
    for (d, o) in depth.iter().zip(&opacity) {
        assert!((0.0..=1.0 + 1e-5).contains(o), "opacity {o}");
        // D = Σ w t with Σ w = opacity ≤ 1, so D ≤ opacity · far.
        assert!(
            *d >= 0.0 && *d <= o * config.render.far as f32 + 1e-3,
            "depth {d}"
        );
    }

    let stride = config.render.camera_stride;
    let (rows, columns) = (h / stride, w / stride);
    let features = random_normal(4, [cameras * rows * columns, cv], 0.0, 1.0, &device);
    let opacity = random_tensor(5, [cameras * rows * columns], 0.0, 1.0, &device);
    let directions = random_normal(6, [cameras * rows * columns, 3], 0.0, 1.0, &device);
    let rgb = model.camera_rgb(features, opacity, directions, cameras, rows, columns);
    assert_eq!(rgb.dims(), [cameras, 3, h, w]);
}
