//! `RUN/curves.png`: the training loss (log scale) and the validation PSNR against steps, drawn
//! with nothing but the `image` crate, so that a run can be judged without a plotting stack.

use std::path::Path;

use image::{Rgb, RgbImage};

const WIDTH: u32 = 900;
const HEIGHT: u32 = 360;
const MARGIN: u32 = 30;

/// A series of (step, value) points with its colour.
pub struct Series<'a> {
    pub points: &'a [(f64, f64)],
    pub colour: [u8; 3],
    pub log_scale: bool,
}

fn draw_line(image: &mut RgbImage, (x0, y0): (f64, f64), (x1, y1): (f64, f64), colour: [u8; 3]) {
    let steps = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).max(1);
    for i in 0..=steps {
        let t = i as f64 / steps as f64;
        let (x, y) = (x0 + t * (x1 - x0), y0 + t * (y1 - y0));
        if x >= 0.0 && y >= 0.0 && (x as u32) < image.width() && (y as u32) < image.height() {
            image.put_pixel(x as u32, y as u32, Rgb(colour));
        }
    }
}

/// Draws each series in its own panel, side by side, each scaled to its own range, with a
/// frame and a light grid of 4 divisions.
pub fn plot(path: &Path, panels: &[Series]) -> Result<(), image::ImageError> {
    let mut image = RgbImage::from_pixel(WIDTH, HEIGHT, Rgb([255, 255, 255]));
    let count = panels.len().max(1) as u32;
    let panel_width = WIDTH / count;
    for (index, series) in panels.iter().enumerate() {
        let left = index as u32 * panel_width + MARGIN;
        let right = (index as u32 + 1) * panel_width - MARGIN / 2;
        let (top, bottom) = (MARGIN / 2, HEIGHT - MARGIN);
        for k in 0..=4 {
            let y = f64::from(top) + f64::from(bottom - top) * f64::from(k) / 4.0;
            draw_line(
                &mut image,
                (f64::from(left), y),
                (f64::from(right), y),
                [225, 225, 225],
            );
            let x = f64::from(left) + f64::from(right - left) * f64::from(k) / 4.0;
            draw_line(
                &mut image,
                (x, f64::from(top)),
                (x, f64::from(bottom)),
                [225, 225, 225],
            );
        }
        let transform = |v: f64| {
            if series.log_scale {
                v.max(1e-12).log10()
            } else {
                v
            }
        };
        let finite: Vec<(f64, f64)> = series
            .points
            .iter()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .map(|&(x, y)| (x, transform(y)))
            .collect();
        if finite.len() < 2 {
            continue;
        }
        let (x_min, x_max) = finite
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
        let (y_min, y_max) = finite
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
        let to_pixel = |(x, y): (f64, f64)| {
            let u = (x - x_min) / (x_max - x_min).max(1e-12);
            let v = (y - y_min) / (y_max - y_min).max(1e-12);
            (
                f64::from(left) + u * f64::from(right - left),
                f64::from(bottom) - v * f64::from(bottom - top),
            )
        };
        for pair in finite.windows(2) {
            draw_line(
                &mut image,
                to_pixel(pair[0]),
                to_pixel(pair[1]),
                series.colour,
            );
        }
    }
    image.save(path)
}
