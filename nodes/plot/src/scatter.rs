//! A labelled scatter plot with horizontal reference lines: one point per configuration (speed
//! against error), the baselines as lines across.

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::curves::{padded, tick};
use crate::font::{FAMILY, ensure_registered};
use crate::{PALETTE, PlotError, write_png};

/// One labelled point.
pub struct Labelled<'a> {
    pub label: &'a str,
    pub x: f64,
    pub y: f64,
}

/// A horizontal line across the plot at `y`.
pub struct Reference<'a> {
    pub label: &'a str,
    pub y: f64,
}

pub struct ScatterPlot<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub log_x: bool,
    pub points: Vec<Labelled<'a>>,
    pub references: Vec<Reference<'a>>,
}

const WIDTH: u32 = 900;
const HEIGHT: u32 = 560;

/// Draws `plot` into a PNG at `path`. Non-finite points (and, on a log axis, x ≤ 0) are left
/// out.
pub fn scatter_png(path: &Path, plot: &ScatterPlot) -> Result<(), PlotError> {
    ensure_registered();
    let mut buffer = vec![0u8; (WIDTH * HEIGHT * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (WIDTH, HEIGHT)).into_drawing_area();
        draw(&root, plot).map_err(|e| PlotError::draw(path, e))?;
        root.present().map_err(|e| PlotError::draw(path, e))?;
    }
    write_png(path, buffer, WIDTH, HEIGHT)
}

fn draw(
    root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
    plot: &ScatterPlot,
) -> Result<(), Box<dyn std::error::Error>> {
    root.fill(&WHITE)?;
    let points: Vec<&Labelled> = plot
        .points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite() && (!plot.log_x || p.x > 0.0))
        .collect();
    let references: Vec<&Reference> = plot.references.iter().filter(|r| r.y.is_finite()).collect();
    let xs = points.iter().map(|p| p.x);
    let ys = points
        .iter()
        .map(|p| p.y)
        .chain(references.iter().map(|r| r.y));
    let (x_lo, x_hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    let (y_lo, y_hi) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    let (x_lo, x_hi) = if x_lo.is_finite() {
        (x_lo, x_hi)
    } else {
        (1.0, 10.0)
    };
    let (y_lo, y_hi) = if y_lo.is_finite() {
        (y_lo, y_hi)
    } else {
        (0.0, 1.0)
    };
    let y = padded(y_lo.min(0.0), y_hi, false);
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(plot.title, (FAMILY, 18).into_font())
        .margin(16)
        .x_label_area_size(40)
        .y_label_area_size(60);
    macro_rules! finish {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(plot.x_label)
                .y_desc(plot.y_label)
                .x_label_formatter(&|v| tick(*v))
                .y_label_formatter(&|v| tick(*v))
                .label_style((FAMILY, 13))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()?;
            let (left, right) = (chart.x_range().start, chart.x_range().end);
            for (index, reference) in references.iter().enumerate() {
                let [r, g, b] = PALETTE[(index + 1) % PALETTE.len()];
                let colour = RGBColor(r, g, b);
                chart.draw_series(LineSeries::new(
                    [(left, reference.y), (right, reference.y)],
                    colour.stroke_width(1),
                ))?;
                chart.draw_series(std::iter::once(Text::new(
                    reference.label.to_string(),
                    (left, reference.y),
                    (FAMILY, 12)
                        .into_font()
                        .color(&colour)
                        .pos(Pos::new(HPos::Left, VPos::Bottom)),
                )))?;
            }
            let [r, g, b] = PALETTE[0];
            let colour = RGBColor(r, g, b);
            chart.draw_series(
                points
                    .iter()
                    .map(|p| Circle::new((p.x, p.y), 4, colour.filled())),
            )?;
            chart.draw_series(points.iter().map(|p| {
                Text::new(
                    p.label.to_string(),
                    (p.x, p.y),
                    TextStyle::from((FAMILY, 12).into_font())
                        .pos(Pos::new(HPos::Left, VPos::Bottom)),
                )
            }))?;
        }};
    }
    if plot.log_x {
        finish!(builder.build_cartesian_2d((x_lo / 1.6..x_hi * 1.6).log_scale(), y)?);
    } else {
        finish!(builder.build_cartesian_2d(padded(x_lo, x_hi, false), y)?);
    }
    Ok(())
}
