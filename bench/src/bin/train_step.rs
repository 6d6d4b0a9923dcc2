//! Where a tokenizer training step's time goes, and what the worker threads give.
//!
//! - Phases of one frame's step, on the calling thread with its tensor ops spread over rayon's
//!   global pool (intra-op parallelism; flex is synchronous, so the wall clock between
//!   phases is the phase's time): encode, lift, camera render, RGB upsampling, LiDAR render,
//!   backward, AdamW.
//! - Whole `Trainer` steps of `frames_per_step` frames, on 1 thread and on every core.
//!
//! Frames are the first 4 keyframes of the config's synthetic training set (made if missing).
//!
//!   cargo run --release -p bevworld-bench --bin train_step
//!   TRAIN_CONFIG=configs/models/train-tokenizer-tiny.yaml cargo run --release -p bevworld-bench --bin train_step

use std::time::Instant;

use bevworld_bench::{markdown_table, results_dir, write_results};
use bevworld_tokenizer::FrameInputs;
use bevworld_tokenizer::render::rays::sample_positions;
use bevworld_tokenizer_train::data::load_frames;
use bevworld_tokenizer_train::{TrainConfig, Trainer};
use burn::optim::GradientsParams;
use burn::prelude::*;

const PHASES: [&str; 7] = [
    "encode (6 cameras + pillars -> latent)",
    "lift (latent -> voxel field)",
    "camera render (all camera rays)",
    "RGB upsampling",
    "LiDAR render (the step's rays)",
    "backward",
    "AdamW",
];

fn main() {
    bevworld_device::keep_freed_memory();
    let root = bevworld_bench::manifest_dir().join("..");
    let config_name = std::env::var("TRAIN_CONFIG")
        .unwrap_or_else(|_| "configs/models/train-tokenizer-tiny.yaml".into());
    let (config, model_config) =
        TrainConfig::from_yaml_file(&root.join(&config_name)).expect("training config");
    let mut set = config.data.train.clone();
    set.dir = root.join(&set.dir);
    set.ensure().expect("synthetic training set");
    let inputs = FrameInputs::new(&model_config);
    let frames = load_frames(&set.dir, &inputs, 4, |_, _| {}).expect("frames");

    // Phases of one frame, its ops over every core.
    let device = Device::flex().autodiff();
    let mut model = model_config.init_seeded(config.seed, &device);
    let mut optimizer = config.optimizer.adamw();
    let depths = model_config.render.sample_depths();
    let placement = model_config.voxel_placement();
    let (warmup, steps) = (2, 10);
    let mut totals = [0f64; PHASES.len()];
    for step in 0..warmup + steps {
        let frame = &frames[step % frames.len()];
        let mut lap = {
            let mut t = Instant::now();
            move |totals: &mut [f64; PHASES.len()], i: usize| {
                if step >= warmup {
                    totals[i] += t.elapsed().as_secs_f64();
                }
                t = Instant::now();
            }
        };
        let latent = model.encode(frame.encoder.to_input(&device)).latent;
        let _: f32 = latent.clone().sum().into_scalar();
        lap(&mut totals, 0);
        let field = model.voxels(latent);
        let _: f32 = field.table().clone().sum().into_scalar();
        lap(&mut totals, 1);
        let depth_row =
            Tensor::<2>::from_data(TensorData::new(depths.clone(), [1, depths.len()]), &device);
        let rays = &frame.rays;
        let positions = sample_positions(&rays.camera, &depths, &placement);
        let rendered = model.render_rays(&field, &positions, rays.camera.len(), depth_row.clone());
        let _: f32 = rendered.features.clone().sum().into_scalar();
        lap(&mut totals, 2);
        let rgb = model.camera_rgb(
            rendered.features,
            rendered.opacity,
            rays.camera.directions_tensor(&device),
            rays.cameras,
            rays.rows,
            rays.columns,
        );
        let _: f32 = rgb.clone().sum().into_scalar();
        lap(&mut totals, 3);
        let count = config.rays.lidar_rays.min(frame.lidar.len());
        let chosen: Vec<usize> = (0..count).map(|i| (i * 13) % frame.lidar.len()).collect();
        let lidar = frame.lidar.subset(&chosen);
        let ranges: Vec<f32> = chosen.iter().map(|&i| frame.lidar_ranges[i]).collect();
        let positions = sample_positions(&lidar, &depths, &placement);
        let lidar_render = model.render_rays(&field, &positions, lidar.len(), depth_row);
        let _: f32 = lidar_render.depth.clone().sum().into_scalar();
        lap(&mut totals, 4);
        let [_, _, h, w] = frame.encoder.image_shape;
        let target = Tensor::<4>::from_data(
            TensorData::new(frame.encoder.images.clone(), [rays.cameras, 3, h, w]),
            &device,
        );
        let truth = Tensor::<1>::from_data(TensorData::new(ranges, [count]), &device);
        let loss = (rgb - target).abs().mean()
            + (lidar_render.depth - truth).abs().mean().mul_scalar(0.05);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        lap(&mut totals, 5);
        model = optimizer.step(1e-4, model, grads);
        lap(&mut totals, 6);
    }
    let total: f64 = totals.iter().sum();
    let mut rows: Vec<Vec<String>> = PHASES
        .iter()
        .zip(totals)
        .map(|(name, seconds)| {
            vec![
                name.to_string(),
                format!("{:.1}", seconds / steps as f64 * 1e3),
                format!("{:.0}%", 100.0 * seconds / total),
            ]
        })
        .collect();
    rows.push(vec![
        "one frame's step".into(),
        format!("{:.1}", total / steps as f64 * 1e3),
        "100%".into(),
    ]);
    let phase_table = markdown_table(&["phase", "ms", "share"], &rows);
    println!("{phase_table}");

    // Whole steps of `frames_per_step` frames, on one thread and on every core.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut step_rows = Vec::new();
    let mut json_steps = Vec::new();
    for threads in [1, cores.min(config.frames_per_step.max(1))] {
        let mut trainer = Trainer::new(
            config.clone(),
            model_config.clone(),
            &Device::flex(),
            frames.clone(),
            frames.clone(),
        )
        .expect("trainer")
        .with_threads(threads);
        for _ in 0..warmup {
            trainer.train_step().expect("step");
        }
        let started = Instant::now();
        for _ in 0..steps {
            trainer.train_step().expect("step");
        }
        let seconds = started.elapsed().as_secs_f64() / steps as f64;
        let frames_per_second = config.frames_per_step as f64 / seconds;
        step_rows.push(vec![
            format!("{}", config.frames_per_step),
            format!("{threads}"),
            format!("{:.0}", seconds * 1e3),
            format!("{frames_per_second:.2}"),
        ]);
        json_steps.push(serde_json::json!({
            "frames_per_step": config.frames_per_step,
            "threads": threads,
            "seconds_per_step": seconds,
            "frames_per_second": frames_per_second,
        }));
        if threads == cores.min(config.frames_per_step.max(1)) {
            break;
        }
    }
    let step_table = markdown_table(
        &["frames per step", "threads", "ms per step", "frames/s"],
        &step_rows,
    );
    println!("{step_table}");
    let json = serde_json::json!({
        "config": config_name,
        "model": model_config.name,
        "phases_ms": PHASES.iter().zip(totals).map(|(name, s)| serde_json::json!({
            "phase": name, "ms": s / steps as f64 * 1e3
        })).collect::<Vec<_>>(),
        "steps": json_steps,
    });
    write_results(
        "train_step",
        "Tokenizer training step",
        &format!(
            "TRAIN_CONFIG={config_name} cargo run --release -p bevworld-bench --bin train_step"
        ),
        &format!("{phase_table}\n{step_table}"),
        &format!(
            "Phases: one frame of `{}` ({} camera rays, {} LiDAR rays, {} samples each), mean of {steps} steps after {warmup} of warm-up, the frame's tensor ops spread over every core (intra-op). Steps: `Trainer::train_step` with the config's {} frames per step, each frame's ops on one thread (per-frame parallelism, as training runs). Two frames one after the other with intra-op parallelism would take twice the one-frame total; compare it with the steps on every core.\n\n![phases](train_step.svg)\n",
            model_config.name,
            frames[0].rays.camera.len(),
            config.rays.lidar_rays,
            depths.len(),
            config.frames_per_step
        ),
        &json,
    );
    let bars: Vec<(String, f64)> = PHASES
        .iter()
        .zip(totals)
        .map(|(name, s)| (name.to_string(), s / steps as f64 * 1e3))
        .collect();
    if let Err(error) = bevworld_plot::bars_svg(
        &results_dir().join("train_step.svg"),
        "Tokenizer training step: one frame's phases (ops over every core)",
        "ms",
        &bars,
        false,
    ) {
        eprintln!("{error}");
    }
}
