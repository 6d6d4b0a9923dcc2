//! The camera PSNR that a ray grid allows: each camera image at the model's size, averaged over
//! the `s × s` pixels of one ray (a perfect rendering of every ray's colour on the 1/`s` grid),
//! then upsampled bilinearly back to full size and scored against the image. A decoder whose
//! upsampler adds no detail of its own cannot beat this; the tokenizer's learned upsampler has
//! to, for a target above it.
//!
//!   cargo run --release -p bevworld-bench --bin ray_grid_ceiling
//!   cargo run --release -p bevworld-bench --bin ray_grid_ceiling -- DATA_DIR [FRAMES] [MODEL.yaml]
//!
//! Defaults: the first 16 keyframes of the held-out synthetic set (`out/synth-val`, made by
//! the training config on first use) at the tiny config's image size.

use std::path::PathBuf;

use bevworld_bench::{held_out_synthetic_set, markdown_table, psnr, write_results};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_tokenizer::TokenizerConfig;
use bevworld_tokenizer::frame_input::image_planes;

/// Ray grid strides: 1/2, 1/4 (the tiny config's) and 1/8 (the paper's).
const STRIDES: [usize; 3] = [2, 4, 8];

fn main() {
    let root = bevworld_bench::manifest_dir().join("..");
    let args: Vec<String> = std::env::args().skip(1).collect();
    let data_dir = match args.first() {
        Some(dir) => root.join(dir),
        None => held_out_synthetic_set(&root),
    };
    let frame_limit: usize = args
        .get(1)
        .map_or(Ok(16), |n| n.parse())
        .expect("FRAMES: a whole number");
    let model_path = root.join(
        args.get(2)
            .map_or("configs/models/tokenizer-tiny.yaml", String::as_str),
    );
    let config = TokenizerConfig::from_yaml_file(&model_path).expect("model config");
    let [height, width] = config.image_size;
    let dataset = Dataset::open(&data_dir, &DatasetOptions::default()).expect("dataset");

    let mut psnr_sums = [0.0f64; STRIDES.len()];
    let mut images = 0usize;
    for index in 0..dataset.len().min(frame_limit) {
        let frame = dataset.read(index).expect("frame");
        for camera in &frame.cameras {
            let planes = image_planes(&camera.image, width, height);
            for (sum, &stride) in psnr_sums.iter_mut().zip(&STRIDES) {
                let upsampled = upsample_bilinear(
                    &block_mean(&planes, width, height, stride),
                    width / stride,
                    height / stride,
                    stride,
                );
                *sum += psnr(&planes, &upsampled);
            }
            images += 1;
        }
    }
    let images_n = images.max(1) as f64;
    let rows: Vec<Vec<String>> = STRIDES
        .iter()
        .zip(&psnr_sums)
        .map(|(stride, sum)| {
            vec![
                format!("1/{stride}"),
                format!("{} × {}", height / stride, width / stride),
                format!("{:.2}", sum / images_n),
            ]
        })
        .collect();
    let table = markdown_table(&["ray grid", "rays per camera", "PSNR ceiling (dB)"], &rows);
    println!("{table}");
    let shown = |p: &PathBuf| p.strip_prefix(&root).unwrap_or(p).display().to_string();
    write_results(
        &format!(
            "ray_grid_ceiling-{}",
            data_dir
                .file_name()
                .map_or("data".into(), |n| n.to_string_lossy())
        ),
        "Camera PSNR ceiling of a ray grid",
        &format!(
            "cargo run --release -p bevworld-bench --bin ray_grid_ceiling -- {} {frame_limit} {}",
            shown(&data_dir),
            shown(&model_path)
        ),
        &table,
        &format!(
            "{images} camera images of {} at {width} × {height} (triangle-filter resize, as the encoder and the metrics resize). Each ray's colour is the mean of its s × s pixels; bilinear upsampling with pixel centres at half-integers, clamped at the borders. PSNR per image, averaged.\n",
            shown(&data_dir)
        ),
        &serde_json::json!({
            "data": shown(&data_dir),
            "images": images,
            "image_size": [height, width],
            "psnr_db": STRIDES.iter().zip(&psnr_sums).map(|(s, sum)| serde_json::json!({
                "stride": s,
                "psnr_db": sum / images_n,
            })).collect::<Vec<_>>(),
        }),
    );
}

/// `[3, H, W]` planes averaged over `s × s` blocks: `[3, H / s, W / s]`.
fn block_mean(planes: &[f32], width: usize, height: usize, s: usize) -> Vec<f32> {
    let (w, h) = (width / s, height / s);
    let mut out = vec![0.0f32; 3 * w * h];
    for c in 0..3 {
        for y in 0..h * s {
            for x in 0..w * s {
                out[(c * h + y / s) * w + x / s] += planes[(c * height + y) * width + x];
            }
        }
    }
    let norm = 1.0 / (s * s) as f32;
    out.iter_mut().for_each(|v| *v *= norm);
    out
}

/// Bilinear upsampling of `[3, h, w]` planes by `s`, sample centres at half-integers (as
/// `align_corners = false`), clamped at the borders.
fn upsample_bilinear(planes: &[f32], w: usize, h: usize, s: usize) -> Vec<f32> {
    let (width, height) = (w * s, h * s);
    let source = |i: usize, n: usize| {
        let u = ((i as f32 + 0.5) / s as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        let lo = u.floor() as usize;
        (lo, (lo + 1).min(n - 1), u - lo as f32)
    };
    let mut out = vec![0.0f32; 3 * width * height];
    for c in 0..3 {
        let plane = &planes[c * w * h..(c + 1) * w * h];
        for y in 0..height {
            let (y0, y1, fy) = source(y, h);
            for x in 0..width {
                let (x0, x1, fx) = source(x, w);
                let top = plane[y0 * w + x0] * (1.0 - fx) + plane[y0 * w + x1] * fx;
                let bottom = plane[y1 * w + x0] * (1.0 - fx) + plane[y1 * w + x1] * fx;
                out[(c * height + y) * width + x] = top * (1.0 - fy) + bottom * fy;
            }
        }
    }
    out
}
