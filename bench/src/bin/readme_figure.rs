//! The README's picture: one frame of `reconstruct.yaml`'s output, three cameras as input |
//! reconstruction beside the LiDAR sweep and its rendering seen from above.
//!
//!   cargo run --release -- run configs/graphs/reconstruct.yaml
//!   cargo run --release -p bevworld-bench --bin readme_figure [-- FRAME_DIR [OUT.png]]
//!
//! FRAME_DIR defaults to `out/reconstruct/000004` (a keyframe of the demo scene, which no
//! training run has seen); OUT defaults to `bench/results/reconstruction.png`.

use std::path::{Path, PathBuf};

use bevworld_plot::{Cloud, caption, top_down};
use bevworld_sinks::ply::read_ply;
use image::RgbImage;
use image::imageops::{FilterType, replace, resize};

const CAMERAS: [&str; 3] = ["CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"];
/// Pixels per model pixel: the tiny model's images are 112 × 64.
const SCALE: u32 = 3;
const LABEL: u32 = 28;

fn sweep(path: &Path) -> Vec<[f32; 2]> {
    read_ply(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .iter()
        .map(|p| [p.x, p.y])
        .collect()
}

fn main() {
    let root = bevworld_bench::manifest_dir().join("..");
    let mut args = std::env::args().skip(1);
    let frame = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("out/reconstruct/000004"));
    let out = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("bench/results/reconstruction.png"));
    let pairs: Vec<RgbImage> = CAMERAS
        .iter()
        .map(|camera| {
            let path = frame.join(format!("{camera}_input_vs_recon.png"));
            let pair = image::open(&path)
                .unwrap_or_else(|e| {
                    panic!(
                        "{}: {e} (run `bevworld run configs/graphs/reconstruct.yaml` first)",
                        path.display()
                    )
                })
                .to_rgb8();
            resize(
                &pair,
                pair.width() * SCALE,
                pair.height() * SCALE,
                FilterType::Nearest,
            )
        })
        .collect();
    let (pair_w, pair_h) = (pairs[0].width(), pairs[0].height());
    let column_h = CAMERAS.len() as u32 * (pair_h + LABEL) + LABEL;
    let side = column_h;
    let mut figure = RgbImage::from_pixel(pair_w + side + 16, column_h, image::Rgb([255; 3]));
    let heading = caption(
        pair_w,
        LABEL,
        "input  |  reconstruction from the 4×64×64 latent",
    );
    replace(&mut figure, &heading, 0, 0);
    for (k, (camera, pair)) in CAMERAS.iter().zip(&pairs).enumerate() {
        let y = LABEL + k as u32 * (pair_h + LABEL);
        replace(
            &mut figure,
            &caption(pair_w, LABEL, camera),
            0,
            i64::from(y),
        );
        replace(&mut figure, pair, 0, i64::from(y + LABEL));
    }
    let truth = sweep(&frame.join("LIDAR_TOP.ply"));
    let rendered = sweep(&frame.join("LIDAR_TOP_recon.ply"));
    let lidar = top_down(
        side,
        40.0,
        "LIDAR_TOP from above (m)",
        &[
            Cloud {
                label: "input sweep",
                points: &truth,
                colour: [60, 60, 60],
            },
            Cloud {
                label: "rendered depth",
                points: &rendered,
                colour: [213, 94, 0],
            },
        ],
    );
    replace(&mut figure, &lidar, i64::from(pair_w + 16), 0);
    bevworld_plot::save_png(&out, &figure).unwrap_or_else(|e| panic!("{e}"));
    println!("figure written to {}", out.display());
}
