//! Horizontal bar charts, the benchmarks' plots: one bar per configuration, its value written
//! beside it.

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::PlotError;
use crate::font::{FAMILY, ensure_registered};

const WIDTH: u32 = 820;
const BAR: u32 = 34;

/// Writes an SVG of one horizontal bar per `(label, value)` at `path`, the value axis in
/// `unit`, logarithmic when `log_scale` (for values spanning decades). Non-finite and, on a log
/// axis, non-positive values get no bar but keep their row and label.
pub fn bars_svg(
    path: &Path,
    title: &str,
    unit: &str,
    items: &[(String, f64)],
    log_scale: bool,
) -> Result<(), PlotError> {
    ensure_registered();
    let rows = items.len().max(1);
    let height = 90 + BAR * rows as u32;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (WIDTH, height)).into_drawing_area();
        draw(&root, title, unit, items, log_scale).map_err(|e| PlotError::draw(path, e))?;
        root.present().map_err(|e| PlotError::draw(path, e))?;
    }
    bevworld_atomic_file::write(path, svg.as_bytes()).map_err(|e| PlotError::Write {
        path: path.to_path_buf(),
        source: image::ImageError::IoError(e),
    })
}

fn draw(
    root: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    title: &str,
    unit: &str,
    items: &[(String, f64)],
    log_scale: bool,
) -> Result<(), Box<dyn std::error::Error>> {
    root.fill(&WHITE)?;
    let drawable = |v: f64| v.is_finite() && (!log_scale || v > 0.0);
    let shown: Vec<f64> = items
        .iter()
        .map(|(_, v)| *v)
        .filter(|v| drawable(*v))
        .collect();
    let max = shown.iter().copied().fold(f64::MIN_POSITIVE, f64::max);
    let min = shown.iter().copied().fold(max, f64::min);
    let rows = items.len().max(1) as i32;
    let longest = items
        .iter()
        .map(|(l, _)| l.chars().count())
        .max()
        .unwrap_or(8) as u32;
    // Row 0 is drawn at the top, as the table beside the plot lists it.
    let row_of = |index: usize| rows - 1 - index as i32;
    let label_of = |value: &SegmentValue<i32>| match value {
        SegmentValue::CenterOf(row) | SegmentValue::Exact(row) => items
            .get((rows - 1 - row) as usize)
            .map(|(label, _)| label.clone())
            .unwrap_or_default(),
        SegmentValue::Last => String::new(),
    };
    let describe = format!("{unit}{}", if log_scale { " (log scale)" } else { "" });
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(title, (FAMILY, 18).into_font())
        .margin(14)
        .x_label_area_size(36)
        .y_label_area_size((longest * 7 + 16).min(380));
    let bars = items
        .iter()
        .enumerate()
        .filter(|(_, (_, v))| drawable(*v))
        .map(|(index, (_, v))| (row_of(index), *v));
    let values = items
        .iter()
        .enumerate()
        .filter(|(_, (_, v))| drawable(*v))
        .map(|(index, (_, v))| (row_of(index), *v));
    let colour = RGBColor(59, 110, 168);
    macro_rules! finish {
        ($chart:expr, $floor:expr, $gap:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .disable_y_mesh()
                .y_labels(rows as usize)
                .y_label_formatter(&label_of)
                .x_desc(&describe)
                .label_style((FAMILY, 13))
                .draw()?;
            // One rectangle per bar, in the items' order: plotters' `Histogram` sums its data
            // in a hash map, so the same figures gave an SVG in another order on every run.
            chart.draw_series(bars.map(|(row, v)| {
                let mut bar = Rectangle::new(
                    [
                        ($floor, SegmentValue::Exact(row)),
                        (v, SegmentValue::Exact(row + 1)),
                    ],
                    colour.filled(),
                );
                bar.set_margin(5, 5, 0, 0);
                bar
            }))?;
            chart.draw_series(values.map(|(row, v)| {
                Text::new(
                    format_value(v),
                    ($gap(v), SegmentValue::CenterOf(row)),
                    TextStyle::from((FAMILY, 13).into_font())
                        .pos(Pos::new(HPos::Left, VPos::Center)),
                )
            }))?;
        }};
    }
    if log_scale {
        let floor = min / 2.0;
        let chart = builder
            .build_cartesian_2d((floor..max * 4.0).log_scale(), (0..rows).into_segmented())?;
        finish!(chart, floor, |v: f64| v * 1.06);
    } else {
        let chart = builder.build_cartesian_2d(0f64..max * 1.22, (0..rows).into_segmented())?;
        finish!(chart, 0.0, |v: f64| v + max * 0.01);
    }
    Ok(())
}

/// A value as a short label: `1.25M`, `3.4k`, `12.3`, `0.456`.
pub(crate) fn format_value(v: f64) -> String {
    if v.abs() >= 1e6 {
        format!("{:.2}M", v / 1e6)
    } else if v.abs() >= 1e3 {
        format!("{:.1}k", v / 1e3)
    } else if v.abs() >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    }
}
