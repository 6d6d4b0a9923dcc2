//! Tokenizer latency at the tiny size on the device `BURN_DEVICE` selects (flex by default):
//! encoder, voxel lift, and the rendering of one full frame (all camera rays of six cameras and
//! one LiDAR sweep's worth of rays), with parameter counts and the machine's matmul rate in the
//! same run. The weights are untrained: latency does not depend on their values.
//!
//!   cargo run --release -p bevworld-bench --bin tokenizer

use std::path::PathBuf;
use std::time::Instant;

use bevworld_bench::{markdown_table, percentile, write_results};
use bevworld_tokenizer::TokenizerConfig;
use bevworld_tokenizer::model::EncoderInput;
use bevworld_tokenizer::render::rays::{Rays, sample_depths, sample_positions};
use burn::module::Module;
use burn::prelude::*;
use burn::tensor::Distribution;

/// Median and p99 milliseconds of `runs` calls after one warm-up; `f` must finish its work
/// (read back a value) so that asynchronous backends are timed fully.
fn time(runs: usize, mut f: impl FnMut()) -> (f64, f64) {
    f();
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let started = Instant::now();
            f();
            started.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    (percentile(&times, 0.5), percentile(&times, 0.99))
}

fn main() {
    let (kind, device) = bevworld_device::from_env().expect("BURN_DEVICE");
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/models/tokenizer-tiny.yaml");
    let config = TokenizerConfig::from_yaml_file(&path).expect("tiny config");
    let model = config.init(&device);
    let [h, w] = config.image_size;
    let n = config.latent_size();
    let (cameras, k) = (config.cameras, config.fusion_heights);
    let pillars = 3000; // a nuScenes sweep on the tiny 128 x 128 grid fills about this many
    let cells: Vec<i64> = (0..pillars as i64).map(|i| i * 5 % (128 * 128)).collect();
    let input = || EncoderInput {
        images: Tensor::random([cameras, 3, h, w], Distribution::Uniform(0.0, 1.0), &device),
        pillar_points: Tensor::random([pillars, 20, 9], Distribution::Normal(0.0, 1.0), &device),
        pillar_valid: Tensor::ones([pillars, 20], &device),
        pillar_cells: Tensor::from_data(TensorData::new(cells.clone(), [pillars]), &device),
        reference: Tensor::random(
            [cameras, n * n, k, 2],
            Distribution::Uniform(-1.0, 1.0),
            &device,
        ),
        reference_valid: Tensor::ones([cameras, n * n, k], &device),
    };
    let read = |t: Tensor<1>| {
        t.into_data()
            .try_to_vec::<f32>()
            .map(|v| v[0])
            .unwrap_or(0.0)
    };

    let runs = 10;
    let encoder = time(runs, || {
        let encoded = model.encode(input());
        std::hint::black_box(read(encoded.latent.sum().reshape([1])));
    });
    let latent = model.encode(input()).latent;
    let lift = time(runs, || {
        std::hint::black_box(read(model.voxels(latent.clone()).sum().reshape([1])));
    });
    let voxels = model.voxels(latent);

    // One frame: every 1/8-grid camera ray of six cameras, plus 34,688 LiDAR rays.
    let stride = config.render.camera_stride;
    let camera_rays = cameras * (h / stride) * (w / stride);
    let lidar_rays = 34_688;
    let total_rays = camera_rays + lidar_rays;
    let rays = Rays {
        origins: vec![[0.0, 0.0, 1.8]; total_rays],
        directions: (0..total_rays)
            .map(|i| {
                let a = i as f32 * 0.001;
                [a.cos() * 0.99, a.sin() * 0.99, -0.14]
            })
            .collect(),
    };
    let depths = sample_depths(
        config.render.near as f32,
        config.render.far as f32,
        config.render.samples,
    );
    let placement = config.voxel_placement();
    let render = time(3, || {
        let positions = sample_positions(&rays, &depths, &placement, &device);
        let depth_row =
            Tensor::<2>::from_data(TensorData::new(depths.clone(), [1, depths.len()]), &device);
        let out = model.render_rays(voxels.clone(), positions, total_rays, depth_row);
        let rgb = model.camera_rgb(
            out.features.narrow(0, 0, camera_rays),
            cameras,
            h / stride,
            w / stride,
        );
        std::hint::black_box(read(rgb.sum().reshape([1])));
    });
    let rays_per_s = total_rays as f64 / (render.0 * 1e-3);
    let matmul = bevworld_device::matmul_gflops(&device, 512, 5).unwrap_or(f64::NAN);

    let rows = vec![
        vec![
            "encoder (6 cameras + 3,000 pillars -> 4 x 32 x 32)".into(),
            format!("{:.1} / {:.1}", encoder.0, encoder.1),
        ],
        vec![
            "voxel lift (latent -> 8 x 16 x 128 x 128)".into(),
            format!("{:.1} / {:.1}", lift.0, lift.1),
        ],
        vec![
            format!(
                "render one frame ({camera_rays} camera + {lidar_rays} LiDAR rays x {} samples, RGB upsampling)",
                config.render.samples
            ),
            format!("{:.1} / {:.1}", render.0, render.1),
        ],
    ];
    let table = markdown_table(&["stage (tiny config)", "ms p50 / p99"], &rows);
    print!("{table}");
    let parameters = model.num_params();
    let notes = format!(
        "Backend: {} ({device:?}). Parameters: {parameters} ({:.2} M). Rendering: {:.2} M rays/s \
         without empty-space skipping (not built yet). Matmul rate in the same run: {matmul:.1} \
         GFLOP/s (512 x 512). Untrained weights; timings do not depend on their values.\n",
        kind.name(),
        parameters as f64 / 1e6,
        rays_per_s / 1e6,
    );
    print!("{notes}");
    write_results(
        "tokenizer",
        "Tokenizer latency, tiny config",
        "cargo run --release -p bevworld-bench --bin tokenizer",
        &table,
        &notes,
        &serde_json::json!({
            "backend": kind.name(),
            "parameters": parameters,
            "encoder_ms_p50": encoder.0,
            "lift_ms_p50": lift.0,
            "render_frame_ms_p50": render.0,
            "rays": total_rays,
            "samples_per_ray": config.render.samples,
            "rays_per_s": rays_per_s,
            "matmul_gflops": matmul,
        }),
    );
}
