//! `RUN/curves.png`: the training loss (log scale), the validation PSNR and the validation
//! Chamfer against steps, drawn with nothing but the `image` crate (and a 5×7 bitmap font for
//! the labels), so that a run can be judged without a plotting stack.

use std::path::Path;

use image::{Rgb, RgbImage};

use crate::train::glyphs::{GLYPH_HEIGHT, draw_text, text_width};

const WIDTH: u32 = 900;
const HEIGHT: u32 = 400;
const MARGIN: u32 = 30;
/// Font pixels per glyph pixel.
const SCALE: u32 = 2;
const INK: [u8; 3] = [40, 40, 40];

/// A series of (step, value) points with its title and colour.
pub struct Series<'a> {
    /// Drawn above the panel, e.g. "VAL PSNR (DB)".
    pub title: &'a str,
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

/// A value as a short label: whole numbers as they are, three or four significant digits
/// otherwise.
fn label(value: f64) -> String {
    let magnitude = value.abs();
    if value == 0.0 || magnitude >= 1000.0 || (value == value.trunc() && magnitude >= 1.0) {
        format!("{value:.0}")
    } else if magnitude >= 100.0 {
        format!("{value:.1}")
    } else if magnitude >= 1.0 {
        format!("{value:.2}")
    } else {
        // 3 significant digits: 0.0123, 0.000456.
        let decimals = (2 - magnitude.max(1e-9).log10().floor() as i32).clamp(2, 9) as usize;
        format!("{value:.decimals$}")
    }
}

/// Draws each series in its own panel, side by side, each scaled to its own range, with a
/// light grid of 4 divisions, the title above, the value range at the panel's top and bottom
/// left, and the step range below it.
pub fn plot(path: &Path, panels: &[Series]) -> Result<(), image::ImageError> {
    let mut image = RgbImage::from_pixel(WIDTH, HEIGHT, Rgb([255, 255, 255]));
    let count = panels.len().max(1) as u32;
    let panel_width = WIDTH / count;
    for (index, series) in panels.iter().enumerate() {
        let left = index as u32 * panel_width + MARGIN;
        let right = (index as u32 + 1) * panel_width - MARGIN / 2;
        let (top, bottom) = (MARGIN + 8, HEIGHT - MARGIN);
        draw_text(&mut image, series.title, (left, 10), SCALE, INK);
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
        // The range in the series' own units, so a log panel reads in metres or loss units.
        let shown = |v: f64| if series.log_scale { 10f64.powf(v) } else { v };
        let glyph_height = GLYPH_HEIGHT * SCALE;
        draw_text(
            &mut image,
            &label(shown(y_max)),
            (left + 4, top + 4),
            SCALE,
            INK,
        );
        draw_text(
            &mut image,
            &label(shown(y_min)),
            (left + 4, bottom - glyph_height - 4),
            SCALE,
            INK,
        );
        draw_text(&mut image, &label(x_min), (left, bottom + 6), SCALE, INK);
        let steps = format!("STEP {}", label(x_max));
        let steps_left = right.saturating_sub(text_width(&steps, SCALE)).max(left);
        draw_text(&mut image, &steps, (steps_left, bottom + 6), SCALE, INK);
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

#[cfg(test)]
mod tests {
    use super::label;

    #[test]
    fn labels_are_short_and_exact_enough() {
        assert_eq!(label(2800.0), "2800");
        assert_eq!(label(10.0), "10");
        assert_eq!(label(21.2219), "21.22");
        assert_eq!(label(123.45), "123.5");
        assert_eq!(label(0.5912), "0.591");
        assert_eq!(label(0.012345), "0.0123");
        assert_eq!(label(0.0), "0");
        assert_eq!(label(-3.0), "-3");
    }
}
