//! Tokenizer latency, FLOPs and rendering speed against error, on the device `BURN_DEVICE`
//! selects (flex by default), at the tiny size, on the real nuScenes keyframe:
//!
//! - encoder and voxel lift: ms, analytic GFLOP, achieved GFLOP/s and its fraction of the
//!   machine's matmul rate measured in the same run;
//! - one full frame rendered (every 1/8-grid camera ray of six cameras and one ray per LiDAR
//!   point), densely and with empty-space skipping + early stop, with the skipping's error
//!   against the dense render (LiDAR depth, camera colour).
//!
//! - the render's parts: the marches of the camera and of the LiDAR rays, dense and skipping,
//!   the RGB upsampler and the occupancy grid. The upsampler runs the same in both renders and
//!   the grid is skipping's own cost, so `dense / (upsampler + grid)` bounds skipping's
//!   speed-up however empty the field.
//!
//! `TOKENIZER_WEIGHTS=FILE` loads trained weights; without it the model is untrained, which
//! leaves latency unchanged but makes the skipping figures unrepresentative (α ≈ 0.5 everywhere).
//! `TOKENIZER_RESULTS=NAME` writes `bench/results/NAME.{md,json}` instead of `tokenizer.*`, for
//! weights other than the shipped ones.
//!
//!   cargo run --release -p bevworld-bench --bin tokenizer
//!   TOKENIZER_WEIGHTS=nodes/tokenizer/weights/tokenizer-tiny.bpk cargo run --release -p bevworld-bench --bin tokenizer

use std::path::PathBuf;

use bevworld_bench::{markdown_table, nuscenes_keyframe, psnr, time_runs, write_results};
use bevworld_pillarize::Limits;
use bevworld_tokenizer::flops::TokenizerFlops;
use bevworld_tokenizer::render::{OccupancyGrid, RenderedRays, SkipOptions, VoxelScene};
use bevworld_tokenizer::{TokenizerConfig, load_weights};
use burn::module::Module;
use burn::prelude::*;

/// Runs per render timing: their median. Three left the dense/skipping ratio moving by a
/// fifth between runs on a 2-core VM.
const RENDER_RUNS: usize = 9;

fn main() {
    bevworld_device::keep_freed_memory();
    let (kind, device) = bevworld_device::from_env().expect("BURN_DEVICE");
    let root = bevworld_bench::manifest_dir().join("..");
    let config = TokenizerConfig::from_yaml_file(&root.join("configs/models/tokenizer-tiny.yaml"))
        .expect("tiny config");
    let weights = std::env::var_os("TOKENIZER_WEIGHTS").map(PathBuf::from);
    let model = match &weights {
        Some(path) => load_weights(&config, path, &device).expect("TOKENIZER_WEIGHTS"),
        None => config.init_seeded(0, &device),
    };
    let (frame, pillars, inputs) = nuscenes_keyframe(&config);
    let limits = Limits::default();
    let flops = TokenizerFlops::of(&config, pillars.len(), limits.max_points_per_pillar);
    let read = |t: Tensor<1>| {
        t.into_data()
            .try_to_vec::<f32>()
            .map(|v| v[0])
            .unwrap_or(0.0)
    };

    let runs = 10;
    let encoder = time_runs(runs, || {
        let input = inputs
            .encoder_input(&frame, &pillars, &device)
            .expect("encoder input");
        let encoded = model.encode(input);
        std::hint::black_box(read(encoded.latent.clone().sum().reshape([1])));
        encoded.latent
    });
    let latent = encoder.2.clone();
    let lift = time_runs(runs, || {
        let voxels = model.voxels(latent.clone());
        std::hint::black_box(read(voxels.table().clone().sum().reshape([1])));
        voxels
    });
    let voxels = lift.2.clone();

    let rays = inputs.frame_rays(&frame).expect("rays");
    let camera_rays = rays.camera.len();
    let lidar_rays = rays.lidar.len();
    let total_rays = camera_rays + lidar_rays;
    let scene = VoxelScene::new(&model, &config, voxels);
    let rgb_of = |camera: &RenderedRays| -> Vec<f32> { scene.camera_planes(camera, &rays) };
    let dense = time_runs(RENDER_RUNS, || {
        let camera = scene.render_dense(&rays.camera);
        let lidar = scene.render_dense(&rays.lidar);
        (rgb_of(&camera), camera, lidar)
    });
    // Skipping at the default segment and at longer ones: a longer segment means fewer
    // passes through the model (less overhead per sample) but later early stops. On the CPU
    // the fused renderer (`render::march`) evaluates 16 samples at a time whatever the
    // segment, so one run says it all.
    let defaults = SkipOptions::default();
    let fused = kind.name() == "flex";
    let segments = if fused {
        vec![defaults.segment]
    } else {
        vec![defaults.segment, 24, 48]
    };
    // Then a tighter grid: one-voxel cells, undilated (`sparse-field.md` measures its error).
    let tight = SkipOptions {
        cell: 1,
        dilate: false,
        ..defaults
    };
    let skip_runs: Vec<_> = segments
        .into_iter()
        .map(|segment| SkipOptions {
            segment,
            ..defaults
        })
        .chain([tight])
        .map(|options| {
            let run = time_runs(RENDER_RUNS, || {
                let grid = OccupancyGrid::build(&scene, &options);
                let camera = scene.render_skipping(&grid, &rays.camera, &options);
                let lidar = scene.render_skipping(&grid, &rays.lidar, &options);
                (rgb_of(&camera), camera, lidar, grid.occupied_fraction)
            });
            (options, run)
        })
        .collect();
    // The render's parts, timed alone.
    let grid = OccupancyGrid::build(&scene, &defaults);
    let part = |f: &dyn Fn() -> RenderedRays| {
        time_runs(RENDER_RUNS, || std::hint::black_box(f().depth.len())).0
    };
    let parts = serde_json::json!({
        "dense_camera_march_ms_p50": part(&|| scene.render_dense(&rays.camera)),
        "dense_lidar_march_ms_p50": part(&|| scene.render_dense(&rays.lidar)),
        "skipping_camera_march_ms_p50": part(&|| scene.render_skipping(&grid, &rays.camera, &defaults)),
        "skipping_lidar_march_ms_p50": part(&|| scene.render_skipping(&grid, &rays.lidar, &defaults)),
        "rgb_upsampler_ms_p50": time_runs(RENDER_RUNS, || rgb_of(&dense.2.1).len()).0,
        "occupancy_grid_ms_p50": time_runs(RENDER_RUNS, || {
            OccupancyGrid::build(&scene, &defaults).occupied_fraction
        })
        .0,
    });
    let ms = |key: &str| parts[key].as_f64().unwrap_or(f64::NAN);
    // Where the occupancy grid keeps the LiDAR rays' samples, against each ray's return: air
    // the ray crosses before it (what a sparse field should leave out), the metre either side
    // of it, and what lies behind it (which early stop leaves out once the surface is opaque).
    // Before the return, also the samples whose nearest voxel is itself above the threshold,
    // without the grid's dilation and pooling: the field's own share of what is kept.
    let field_occupied: Option<Vec<bool>> = {
        let threshold = (defaults.alpha_threshold / (1.0 - defaults.alpha_threshold)).ln();
        let channels = scene.voxels.shape.channels;
        model
            .alpha_head_on_host()
            .zip(scene.voxels.host_table())
            .map(|(head, table)| {
                let logits = head.table_logits(table, channels);
                logits.into_iter().map(|s| s > threshold).collect()
            })
    };
    let shape = scene.voxels.shape;
    let ([x_terms, y_terms, z_terms], [nz, ny, nx]) = (shape.row_terms(), shape.voxels());
    let nearest = |v: f32, n: usize| {
        let r = (v + 0.5).floor();
        (r >= 0.0 && r < n as f32).then_some(r as usize)
    };
    let lidar_kept = {
        let (depths, placement) = (config.render.sample_depths(), config.voxel_placement());
        let (mut kept, mut before, mut before_in_field) = ([0u64; 3], 0u64, 0u64);
        let lidar = &rays.lidar;
        for ((o, d), &range) in lidar
            .origins
            .iter()
            .zip(&lidar.directions)
            .zip(&rays.lidar_ranges)
        {
            for &t in &depths {
                before += u64::from(t < range - 1.0);
                let p = placement.to_voxel(std::array::from_fn(|axis| o[axis] + t * d[axis]));
                let voxel = nearest(p[0], nx)
                    .zip(nearest(p[1], ny))
                    .zip(nearest(p[2], nz))
                    .map(|((ix, iy), iz)| (x_terms[ix] + y_terms[iy] + z_terms[iz]) as usize);
                if t < range - 1.0
                    && let (Some(row), Some(occupied)) = (voxel, &field_occupied)
                    && occupied[row]
                {
                    before_in_field += 1;
                }
                if grid.keeps(p) {
                    let slot = match t {
                        t if t < range - 1.0 => 0,
                        t if t <= range + 1.0 => 1,
                        _ => 2,
                    };
                    kept[slot] += 1;
                }
            }
        }
        let total = (lidar.len() * depths.len()).max(1) as f64;
        serde_json::json!({
            "before_return": kept[0] as f64 / total,
            "within_1m_of_return": kept[1] as f64 / total,
            "behind_return": kept[2] as f64 / total,
            "all_before_return": before as f64 / total,
            "before_return_in_an_occupied_voxel": field_occupied
                .as_ref()
                .map(|_| before_in_field as f64 / total),
        })
    };
    let share = |key: &str| 100.0 * lidar_kept[key].as_f64().unwrap_or(f64::NAN);
    let (upsampler_ms, grid_ms) = (ms("rgb_upsampler_ms_p50"), ms("occupancy_grid_ms_p50"));
    let matmul = bevworld_device::matmul_gflops(&device, 512, 5).unwrap_or(f64::NAN);

    let (dense_rgb, dense_camera, dense_lidar) = &dense.2;
    let dense_samples = dense_camera.samples_dense + dense_lidar.samples_dense;
    let occupied = skip_runs.first().map_or(f64::NAN, |(_, run)| run.2.3);
    let options = defaults;
    let gflops = |flop: f64, ms: f64| flop / (ms * 1e-3) / 1e9;
    let encoder_flop = flops.encoder();
    let lift_flop = flops.lift;
    let dense_flop = flops.render(dense_samples, rays.cameras);
    let row = |stage: String, t: (f64, f64), flop: f64, extra: String| {
        let rate = gflops(flop, t.0);
        vec![
            stage,
            format!("{:.1} / {:.1}", t.0, t.1),
            format!("{:.3}", flop / 1e9),
            format!("{rate:.1} ({:.0}%)", 100.0 * rate / matmul),
            extra,
        ]
    };
    let n = config.latent_size();
    let [voxel_c, voxel_z, voxel_y, voxel_x] = config.decoder.voxel_shape(n, n);
    let rows = vec![
        row(
            format!(
                "encoder ({} cameras + {} pillars -> {} x {n} x {n})",
                config.cameras,
                pillars.len(),
                config.latent_channels
            ),
            (encoder.0, encoder.1),
            encoder_flop,
            String::new(),
        ),
        row(
            format!("voxel lift (latent -> {voxel_c} x {voxel_z} x {voxel_y} x {voxel_x})"),
            (lift.0, lift.1),
            lift_flop,
            String::new(),
        ),
        row(
            format!(
                "render, dense ({camera_rays} camera + {lidar_rays} LiDAR rays x {} samples, RGB)",
                config.render.samples
            ),
            (dense.0, dense.1),
            dense_flop,
            format!("{:.3} M rays/s", total_rays as f64 / (dense.0 * 1e-3) / 1e6),
        ),
    ];
    let mut rows = rows;
    let mut skip_json = Vec::new();
    for (options, skipping) in &skip_runs {
        let (skip_rgb, skip_camera, skip_lidar, _) = &skipping.2;
        let depth_mae = dense_lidar
            .depth
            .iter()
            .zip(&skip_lidar.depth)
            .map(|(a, b)| f64::from((a - b).abs()))
            .sum::<f64>()
            / lidar_rays.max(1) as f64;
        let colour_psnr = psnr(dense_rgb, skip_rgb);
        let evaluated = skip_camera.samples_evaluated + skip_lidar.samples_evaluated;
        let fraction = evaluated as f64 / dense_samples as f64;
        skip_json.push(serde_json::json!({
            "segment": options.segment,
            "cell": options.cell,
            "dilate": options.dilate,
            "ms_p50": skipping.0,
            "gflop": flops.render(evaluated, rays.cameras) / 1e9,
            "sample_fraction": fraction,
            "depth_mae_m": depth_mae,
            "colour_psnr_db": colour_psnr,
        }));
        rows.push(row(
            format!(
                "render, skipping (α ≤ {}, {}³ cells{}, stop at T < {}, {})",
                options.alpha_threshold,
                options.cell,
                if options.dilate { "" } else { ", undilated" },
                options.stop_transmittance,
                if fused {
                    "16 samples at a time, fused CPU renderer".to_string()
                } else {
                    format!("segments of {}", options.segment)
                }
            ),
            (skipping.0, skipping.1),
            flops.render(evaluated, rays.cameras),
            format!(
                "{:.3} M rays/s, {:.2}x dense; {:.1}% of samples; depth MAE {depth_mae:.4} m; colour PSNR vs dense {colour_psnr:.1} dB",
                total_rays as f64 / (skipping.0 * 1e-3) / 1e6,
                dense.0 / skipping.0,
                100.0 * fraction
            ),
        ));
    }
    let table = markdown_table(
        &[
            "stage (tiny config)",
            "ms p50 / p99",
            "GFLOP",
            "GFLOP/s (of matmul)",
            "notes",
        ],
        &rows,
    );
    print!("{table}");
    let parameters = model.num_params();
    let weights_note = match &weights {
        Some(path) => format!("trained weights {}", path.display()),
        None => "untrained weights (α ≈ 0.5 everywhere, so skipping gains come from early stop \
                 alone; latency does not depend on the weights)"
            .into(),
    };
    let notes = format!(
        "Backend: {} ({device:?}). Input: the real nuScenes keyframe. Parameters: {parameters} \
         ({:.2} M). {weights_note}. Occupied voxels (α > {}): {:.1}%. Matmul rate in the same run: \
         {matmul:.1} GFLOP/s (512 x 512). FLOPs are analytic (`nodes/tokenizer/src/flops.rs`), \
         2 per multiply-add.\n\nThe render's parts (ms p50): marches dense {:.1} (camera) + {:.1} \
         (LiDAR), skipping {:.1} + {:.1}; the RGB upsampler {upsampler_ms:.1}, run by both; the \
         occupancy grid {grid_ms:.1}, skipping's own. However empty the field, skipping cannot \
         beat dense by more than {:.2}x (dense / (upsampler + grid)). Of the LiDAR rays' samples \
         the occupancy grid keeps {:.1}% before the return (of {:.1}% that lie there; {:.1}% lie \
         in a voxel itself above the threshold), {:.1}% within a metre of it and {:.1}% behind \
         it (before early stop).\n",
        kind.name(),
        parameters as f64 / 1e6,
        options.alpha_threshold,
        100.0 * occupied,
        ms("dense_camera_march_ms_p50"),
        ms("dense_lidar_march_ms_p50"),
        ms("skipping_camera_march_ms_p50"),
        ms("skipping_lidar_march_ms_p50"),
        dense.0 / (upsampler_ms + grid_ms),
        share("before_return"),
        share("all_before_return"),
        share("before_return_in_an_occupied_voxel"),
        share("within_1m_of_return"),
        share("behind_return"),
    );
    print!("{notes}");
    let command = "cargo run --release -p bevworld-bench --bin tokenizer";
    let results = std::env::var("TOKENIZER_RESULTS").unwrap_or_else(|_| "tokenizer".into());
    let command = match &weights {
        Some(path) => format!("TOKENIZER_WEIGHTS={} {command}", path.display()),
        None => command.to_string(),
    };
    let command = if results == "tokenizer" {
        command
    } else {
        format!("TOKENIZER_RESULTS={results} {command}")
    };
    write_results(
        &results,
        "Tokenizer latency, FLOPs and rendering with and without skipping, tiny config",
        &command,
        &table,
        &notes,
        &serde_json::json!({
            "backend": kind.name(),
            "machine": bevworld_bench::machine(),
            "weights": weights.as_ref().map(|p| p.display().to_string()),
            "parameters": parameters,
            "pillars": pillars.len(),
            "encoder_ms_p50": encoder.0,
            "encoder_gflop": encoder_flop / 1e9,
            "lift_ms_p50": lift.0,
            "lift_gflop": lift_flop / 1e9,
            "render_dense_ms_p50": dense.0,
            "render_dense_gflop": dense_flop / 1e9,
            "render_skipping": skip_json,
            "occupied_fraction": occupied,
            "render_parts": parts,
            "lidar_samples_kept_by_grid": lidar_kept,
            "rays": total_rays,
            "samples_per_ray": config.render.samples,
            "matmul_gflops": matmul,
        }),
    );
}
