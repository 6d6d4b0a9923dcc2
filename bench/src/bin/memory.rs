//! Peak resident memory of the world model: one forecast (one DDIM step, the shipped sampler)
//! and one training step (forward and backward of the L1 loss on one window), at the tiny size
//! and at the paper's. Measured as the process's high-water mark (`VmHWM`), reset through
//! `/proc/self/clear_refs` before each, so each figure is that operation's own peak with the
//! process's baseline under it (reported beside it).
//!
//! The paper size's training step is not run here: under autodiff, attention keeps its L × L
//! logits and weights for the backward pass, and at 2,304 tokens a frame that alone is more
//! than this machine's memory (the estimate is printed). It is a GPU job.
//!
//!   cargo run --release -p bevworld-bench --bin memory

use bevworld_bench::{markdown_table, write_results};
use bevworld_blocks::init::random_normal;
use bevworld_world_model::ddim::noisy_and_target;
use bevworld_world_model::{DdimConfig, ForecastInputs, NoiseSchedule, WorldModelConfig, forecast};
use burn::prelude::*;

fn status_kib(field: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find(|l| l.starts_with(field))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

/// Runs `work` and returns (resident before, peak during) in MiB.
fn peak_mib(work: impl FnOnce()) -> (f64, f64) {
    // Writing 5 resets the high-water mark to the current resident size (Linux ≥ 4.0).
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let before = status_kib("VmRSS:").unwrap_or(0);
    work();
    let peak = status_kib("VmHWM:").unwrap_or(0);
    (before as f64 / 1024.0, peak as f64 / 1024.0)
}

fn config(root: &std::path::Path, name: &str) -> WorldModelConfig {
    WorldModelConfig::from_yaml_file(&root.join(format!("configs/models/{name}.yaml")))
        .expect("world model config")
}

fn one_forecast(config: &WorldModelConfig) {
    let device = Device::flex();
    let model = config.init(&device);
    let [h, w] = config.latent_size;
    let (p, n) = (config.context_frames, config.future_frames);
    let inputs = ForecastInputs {
        context: random_normal(1, [1, p, config.latent_channels, h, w], 0.0, 1.0, &device),
        actions: random_normal(2, [1, p + n, 5], 0.0, 0.5, &device),
        base: None,
        warped: random_normal(3, [1, n, config.latent_channels, h, w], 0.0, 1.0, &device),
        fine_tokens: Default::default(),
    };
    let schedule = NoiseSchedule::new(&config.diffusion);
    let sampler = DdimConfig::deterministic(1, 0);
    let _ = forecast(&model, config, &schedule, &inputs, &sampler)
        .expect("forecast")
        .into_data();
}

fn one_training_step(config: &WorldModelConfig) {
    let device = Device::flex().autodiff();
    let model = config.init(&device);
    let [h, w] = config.latent_size;
    let (p, n) = (config.context_frames, config.future_frames);
    let schedule = NoiseSchedule::new(&config.diffusion);
    let clean = random_normal(3, [1, n, config.latent_channels, h, w], 0.0, 1.0, &device);
    let noise = random_normal(4, [1, n, config.latent_channels, h, w], 0.0, 1.0, &device);
    let (noisy, target) =
        noisy_and_target(&schedule, config.diffusion.target, clean, noise, &[500]);
    let context = random_normal(5, [1, p, config.latent_channels, h, w], 0.0, 1.0, &device);
    let actions = random_normal(6, [1, p + n, 5], 0.0, 0.5, &device);
    let levels: Vec<f32> = (0..p + n)
        .map(|f| if f < p { 0.0 } else { 500.0 })
        .collect();
    let warped = random_normal(7, [1, n, config.latent_channels, h, w], 0.0, 1.0, &device);
    let output = model.forward(
        Tensor::cat(vec![context, noisy], 1),
        actions,
        &levels,
        n,
        Some(warped),
    );
    let loss = (output - target).abs().mean();
    let _gradients = loss.backward();
}

/// The bytes attention's logits and weights keep for the backward pass, per training step.
fn attention_kept_gib(config: &WorldModelConfig) -> f64 {
    let tokens = (config.latent_size[0] / config.patch) * (config.latent_size[1] / config.patch);
    let frames = config.context_frames + config.future_frames;
    let spatial = frames * config.heads * tokens * tokens;
    let temporal = tokens * config.heads * frames * frames;
    2.0 * config.depth as f64 * (spatial + temporal) as f64 * 4.0 / (1u64 << 30) as f64
}

fn main() {
    let root = bevworld_bench::manifest_dir().join("..");
    let tiny = config(&root, "world-model-tiny");
    let paper = config(&root, "world-model-paper");
    let mut rows = Vec::new();
    let mut json = Vec::new();
    for (size, config, train) in [("tiny", &tiny, true), ("paper", &paper, false)] {
        let (before, forecast_peak) = peak_mib(|| one_forecast(config));
        println!("{size}: one forecast peaks at {forecast_peak:.0} MiB (from {before:.0})");
        let training = train.then(|| peak_mib(|| one_training_step(config)));
        if let Some((_, peak)) = training {
            println!("{size}: one training step peaks at {peak:.0} MiB");
        }
        let kept = attention_kept_gib(config);
        rows.push(vec![
            size.to_string(),
            format!("{forecast_peak:.0}"),
            training.map_or("not run (see below)".into(), |(_, p)| format!("{p:.0}")),
            format!("{before:.0}"),
            format!("{kept:.2}"),
        ]);
        json.push(serde_json::json!({
            "size": size,
            "forecast_peak_mib": forecast_peak,
            "training_step_peak_mib": training.map(|(_, p)| p),
            "baseline_mib": before,
            "attention_kept_for_backward_gib": kept,
        }));
    }
    let table = markdown_table(
        &[
            "size",
            "one forecast, 1 DDIM step: peak (MiB)",
            "one training step, batch 1: peak (MiB)",
            "process before (MiB)",
            "attention logits and weights a training step keeps (GiB, computed)",
        ],
        &rows,
    );
    write_results(
        "memory",
        "Peak resident memory of the world model",
        "cargo run --release -p bevworld-bench --bin memory",
        &table,
        "\nThe paper size's training step is not run on this 24 GiB machine: under autodiff the \
         attention keeps its logits and weights for the backward pass (last column), more than \
         the machine holds before any other activation. It is a job for a GPU with that much \
         memory, or for attention that recomputes in the backward pass.",
        &serde_json::json!(json),
    );
}
