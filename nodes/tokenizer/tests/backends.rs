//! The tiny tokenizer gives the same outputs on `flex` (CPU) and `wgpu` (GPU, or a software
//! adapter on GPU-less machines), from the same weights and inputs.
//!
//! Tolerance: 1e-4 absolute on values of order 1. Both backends compute in f32, in different
//! orders (tiled matmuls, fused kernels), so their round-off differs by a few ulps per
//! operation. Measured on the software adapter of a GPU-less machine: 7e-7 on the latent and
//! 1.3e-6 on the voxels, so the bound leaves room for real GPUs' other kernels. This test takes
//! about a minute there, most of it compiling shaders.

use std::path::PathBuf;

use bevworld_tokenizer::model::EncoderInput;
use bevworld_tokenizer::{TokenizerConfig, load_weights, save_weights};
use burn::prelude::*;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

fn deterministic(count: usize, scale: f32) -> Vec<f32> {
    (0..count)
        .map(|i| (((i * 7919) % 1000) as f32 / 1000.0 - 0.5) * scale)
        .collect()
}

fn run(
    config: &TokenizerConfig,
    weights: &std::path::Path,
    device: &Device,
) -> (Vec<f32>, Vec<f32>) {
    let model = load_weights(config, weights, device).expect("weights");
    let [h, w] = config.image_size;
    let n = config.latent_size();
    let (cameras, k, pillars) = (config.cameras, config.fusion_heights, 6);
    let t = |data: Vec<f32>, shape: Vec<usize>| -> TensorData { TensorData::new(data, shape) };
    let input = EncoderInput {
        images: Tensor::from_data(
            t(
                deterministic(cameras * 3 * h * w, 1.0)
                    .iter()
                    .map(|v| v + 0.5)
                    .collect(),
                vec![cameras, 3, h, w],
            ),
            device,
        ),
        pillar_points: Tensor::from_data(
            t(deterministic(pillars * 20 * 9, 4.0), vec![pillars, 20, 9]),
            device,
        ),
        pillar_valid: Tensor::ones([pillars, 20], device),
        pillar_cells: Tensor::from_data(
            TensorData::new(vec![3i64, 400, 4000, 8191, 9000, 16000], [pillars]),
            device,
        ),
        reference: Tensor::from_data(
            t(
                deterministic(cameras * n * n * k * 2, 1.8),
                vec![cameras, n * n, k, 2],
            ),
            device,
        ),
        reference_valid: Tensor::ones([cameras, n * n, k], device),
    };
    let encoded = model.encode(input);
    let latent = values(encoded.latent.clone());
    let voxels = values(model.voxels(encoded.latent).table().clone());
    (latent, voxels)
}

#[test]
fn flex_and_wgpu_agree_on_the_tiny_tokenizer() {
    let path = PathBuf::from(
        std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"),
    )
    .join("../../configs/models/tokenizer-tiny.yaml");
    let config = TokenizerConfig::from_yaml_file(&path).expect("tiny config");
    let dir = tempfile::tempdir().expect("tempdir");
    let weights = dir.path().join("tiny.bpk");
    save_weights(&config.init_seeded(0, &Device::flex()), &weights).expect("save");

    let (latent_cpu, voxels_cpu) = run(&config, &weights, &Device::flex());
    let gpu = Device::wgpu(DeviceKind::DefaultDevice);
    let (latent_gpu, voxels_gpu) = run(&config, &weights, &gpu);
    for (name, a, b) in [
        ("latent", &latent_cpu, &latent_gpu),
        ("voxels", &voxels_cpu, &voxels_gpu),
    ] {
        assert_eq!(a.len(), b.len());
        let worst = a
            .iter()
            .zip(b.iter())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        let scale = a.iter().map(|x| x.abs()).fold(0.0f32, f32::max);
        println!("{name}: max |flex - wgpu| = {worst:e} (max |value| {scale})");
        assert!(worst < 1e-4, "{name}: flex and wgpu differ by {worst}");
    }
}
