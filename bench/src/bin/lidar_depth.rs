//! Where a trained tokenizer's LiDAR error lies, and which depth of a rendered ray to report.
//!
//! - **Depth error by range.** Every in-range LiDAR ray of each keyframe, rendered densely: the
//!   error of the rendered depth `D = Σ wᵢtᵢ` against the return's range, by range bucket, with
//!   each bucket's share of the summed squared error and its mean opacity. A ray's own error
//!   bounds its point's nearest-neighbour distance from above, so this says where the Chamfer
//!   distance can come from.
//! - **Depth estimators.** The Chamfer distance (4D-Occ ROI) of the rendered sweep with each
//!   ray's depth taken as the expected depth (what training fits and the `render` node writes),
//!   the expected depth over the ray's opacity, or the median of the ray's weights (the depth
//!   where the accumulated weight reaches half the opacity, interpolated between samples, or at
//!   the sample itself).
//!
//!   cargo run --release -p bevworld-bench --bin lidar_depth
//!   cargo run --release -p bevworld-bench --bin lidar_depth -- MODEL.yaml WEIGHTS.bpk DATA_DIR FRAMES
//!
//! Defaults: the tiny config, the shipped weights, the first 16 keyframes of the held-out
//! synthetic set (`out/synth-val`, made by the training config on first use).

use std::path::PathBuf;

use bevworld_bench::{held_out_synthetic_set, markdown_table, results_dir, write_results};
use bevworld_metrics::{Roi, chamfer_in_roi};
use bevworld_tokenizer::render::rays::{points_from_depths, sample_positions};
use bevworld_tokenizer::render::{render_weights, sample_trilinear};
use bevworld_tokenizer::{FrameInputs, TokenizerConfig, load_weights};
use bevworld_tokenizer_train::data::load_frames;
use burn::prelude::*;

/// Range buckets, metres from the LiDAR.
const EDGES: [f32; 7] = [0.0, 5.0, 10.0, 20.0, 40.0, 80.0, f32::INFINITY];

const ESTIMATORS: [&str; 4] = [
    "expected depth Σ wᵢtᵢ (trained; the render node's)",
    "expected depth / opacity",
    "median of the weights, interpolated between samples",
    "median of the weights, at the sample",
];

/// Rays per pass through the model.
const CHUNK: usize = 4096;

#[derive(Default, Clone, Copy)]
struct Bucket {
    rays: usize,
    abs_sum: f64,
    sq_sum: f64,
    opacity_sum: f64,
}

fn main() {
    bevworld_device::keep_freed_memory();
    let root = bevworld_bench::manifest_dir().join("..");
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.into());
    let model_path = root.join(arg(0, "configs/models/tokenizer-tiny.yaml"));
    let weights_path = root.join(arg(1, "nodes/tokenizer/weights/tokenizer-tiny.bpk"));
    let data_dir = match args.get(2) {
        Some(dir) => root.join(dir),
        None => held_out_synthetic_set(&root),
    };
    let frame_limit: usize = arg(3, "16").parse().expect("FRAMES: a whole number");

    let config = TokenizerConfig::from_yaml_file(&model_path).expect("model config");
    let device = Device::flex();
    let model = load_weights(&config, &weights_path, &device).expect("weights");
    let frames = load_frames(
        &data_dir,
        &FrameInputs::new(&config),
        frame_limit,
        |_, _| {},
    )
    .expect("frames");
    let depths = config.render.sample_depths();
    let placement = config.voxel_placement();
    let samples = depths.len();

    let mut buckets = [Bucket::default(); EDGES.len() - 1];
    let mut chamfer_sums = [0.0f64; ESTIMATORS.len()];
    for frame in &frames {
        let latent = model.encode(frame.encoder.to_input(&device)).latent;
        let field = model.voxels(latent);
        let rays = &frame.lidar;
        // Per-sample weights of every ray, [R * S] row-major.
        let mut weights: Vec<f32> = Vec::with_capacity(rays.len() * samples);
        for start in (0..rays.len()).step_by(CHUNK) {
            let indices: Vec<usize> = (start..(start + CHUNK).min(rays.len())).collect();
            let part = rays.subset(&indices);
            let features = sample_trilinear(&field, &sample_positions(&part, &depths, &placement));
            let [_, channels] = features.dims();
            let logits = model.alpha_logits(features.reshape([part.len(), samples, channels]));
            let part_weights = render_weights(logits).into_data();
            weights.extend(part_weights.iter::<f32>());
        }
        let mut estimates = vec![Vec::with_capacity(rays.len()); ESTIMATORS.len()];
        for (ray, w) in weights.chunks_exact(samples).enumerate() {
            let opacity: f32 = w.iter().sum();
            let expected: f32 = w.iter().zip(&depths).map(|(w, t)| w * t).sum();
            let normalised = if opacity > 1e-6 {
                expected / opacity
            } else {
                depths[samples - 1]
            };
            estimates[0].push(expected);
            estimates[1].push(normalised);
            estimates[2].push(weight_median(w, &depths, true).unwrap_or(normalised));
            estimates[3].push(weight_median(w, &depths, false).unwrap_or(normalised));

            let range = frame.lidar_ranges[ray];
            if let Some(b) = EDGES.windows(2).position(|e| e[0] <= range && range < e[1]) {
                let error = f64::from(expected - range);
                let bucket = &mut buckets[b];
                bucket.rays += 1;
                bucket.abs_sum += error.abs();
                bucket.sq_sum += error * error;
                bucket.opacity_sum += f64::from(opacity);
            }
        }
        let to_f64 = |p: &[f32; 3]| p.map(f64::from);
        let truth: Vec<[f64; 3]> = frame.lidar_points.iter().map(to_f64).collect();
        for (sum, depth) in chamfer_sums.iter_mut().zip(&estimates) {
            let predicted: Vec<[f64; 3]> =
                points_from_depths(rays, depth).iter().map(to_f64).collect();
            *sum += chamfer_in_roi(&predicted, &truth, &Roi::FOUR_D_OCC).chamfer;
        }
    }

    let total_sq: f64 = buckets.iter().map(|b| b.sq_sum).sum::<f64>().max(1e-12);
    let range_name = |i: usize| {
        if EDGES[i + 1].is_finite() {
            format!("{}–{}", EDGES[i], EDGES[i + 1])
        } else {
            format!("beyond {}", EDGES[i])
        }
    };
    let mut range_rows = Vec::new();
    let mut shares = Vec::new();
    for (i, b) in buckets.iter().enumerate().filter(|(_, b)| b.rays > 0) {
        let n = b.rays as f64;
        range_rows.push(vec![
            range_name(i),
            b.rays.to_string(),
            format!("{:.2}", b.abs_sum / n),
            format!("{:.2}", b.sq_sum / n),
            format!("{:.0}%", 100.0 * b.sq_sum / total_sq),
            format!("{:.3}", b.opacity_sum / n),
        ]);
        shares.push((format!("{} m", range_name(i)), 100.0 * b.sq_sum / total_sq));
    }
    let range_table = markdown_table(
        &[
            "range (m)",
            "rays",
            "mean abs error (m)",
            "mean squared error (m²)",
            "share of squared error",
            "mean opacity",
        ],
        &range_rows,
    );
    let frames_n = frames.len().max(1) as f64;
    let estimator_rows: Vec<Vec<String>> = ESTIMATORS
        .iter()
        .zip(&chamfer_sums)
        .map(|(name, sum)| vec![(*name).to_string(), format!("{:.3}", sum / frames_n)])
        .collect();
    let estimator_table = markdown_table(&["depth of a ray", "Chamfer (m²)"], &estimator_rows);
    println!("{range_table}\n{estimator_table}");

    let shown = |p: &PathBuf| p.strip_prefix(&root).unwrap_or(p).display().to_string();
    let json = serde_json::json!({
        "model": shown(&model_path),
        "weights": shown(&weights_path),
        "data": shown(&data_dir),
        "frames": frames.len(),
        "by_range": buckets.iter().enumerate().filter(|(_, b)| b.rays > 0).map(|(i, b)| serde_json::json!({
            "range_m": range_name(i),
            "rays": b.rays,
            "mean_abs_error_m": b.abs_sum / b.rays as f64,
            "mean_squared_error_m2": b.sq_sum / b.rays as f64,
            "mean_opacity": b.opacity_sum / b.rays as f64,
        })).collect::<Vec<_>>(),
        "chamfer_m2": ESTIMATORS.iter().zip(&chamfer_sums).map(|(name, sum)| serde_json::json!({
            "depth": name,
            "chamfer_m2": sum / frames_n,
        })).collect::<Vec<_>>(),
    });
    let name = format!(
        "lidar_depth-{}",
        data_dir
            .file_name()
            .map_or("data".into(), |n| n.to_string_lossy())
    );
    write_results(
        &name,
        "LiDAR depth error of a trained tokenizer",
        &format!(
            "cargo run --release -p bevworld-bench --bin lidar_depth -- {} {} {} {frame_limit}",
            shown(&model_path),
            shown(&weights_path),
            shown(&data_dir)
        ),
        &format!("{range_table}\n{estimator_table}"),
        &format!(
            "{} keyframes, every in-range LiDAR ray rendered densely ({samples} samples). The share is of the summed squared error of the rendered depth along each ray; a ray's error bounds its point's nearest-neighbour distance from above. The Chamfer distance is 4D-Occ's (ROI |x|, |y| ≤ 70 m, |z| ≤ 4.5 m), averaged over the keyframes.\n\n![share of squared error]({name}.svg)\n",
            frames.len()
        ),
        &json,
    );
    if let Err(error) = bevworld_plot::bars_svg(
        &results_dir().join(format!("{name}.svg")),
        "Share of the squared depth error by range",
        "%",
        &shares,
        false,
    ) {
        eprintln!("{error}");
    }
}

/// The depth where a ray's accumulated weight reaches half its opacity: the sample's depth
/// (`interpolate = false`), or interpolated linearly between it and the sample before, as if
/// each sample's weight were spread over the interval that ends at it. None for a ray with no
/// weight.
fn weight_median(weights: &[f32], depths: &[f32], interpolate: bool) -> Option<f32> {
    let half = 0.5 * weights.iter().sum::<f32>();
    if half <= 0.0 {
        return None;
    }
    let mut before = 0.0f32;
    for (i, &w) in weights.iter().enumerate() {
        if before + w >= half {
            if !interpolate || i == 0 || w <= 0.0 {
                return Some(depths[i]);
            }
            let fraction = (half - before) / w;
            return Some(depths[i - 1] + fraction * (depths[i] - depths[i - 1]));
        }
        before += w;
    }
    None
}
