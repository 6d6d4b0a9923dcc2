//! Line charts side by side: one panel per quantity (a training run's loss, PSNR and Chamfer
//! against steps), each scaled to its own data.

use std::ops::Range;
use std::path::Path;

use plotters::coord::Shift;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::font::{FAMILY, ensure_registered};
use crate::{PALETTE, PlotError, write_png};

/// One line of a panel.
pub struct Series<'a> {
    pub label: &'a str,
    /// `(x, y)` in drawing order; non-finite points (and, on a log axis, values ≤ 0) are left
    /// out.
    pub points: &'a [(f64, f64)],
}

/// One chart of the row.
pub struct Panel<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub log_y: bool,
    pub series: Vec<Series<'a>>,
}

const PANEL_WIDTH: u32 = 420;
const HEIGHT: u32 = 360;

/// Draws the panels in one row into a PNG at `path`. A panel with no drawable point is drawn
/// empty, with "no data" in place of its curves, so a run's first plot still has its layout.
pub fn panels_png(path: &Path, panels: &[Panel]) -> Result<(), PlotError> {
    ensure_registered();
    let width = PANEL_WIDTH * panels.len().max(1) as u32;
    let mut buffer = vec![0u8; (width * HEIGHT * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, HEIGHT)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| PlotError::draw(path, e))?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        for (panel, area) in panels.iter().zip(&areas) {
            draw_panel(panel, area).map_err(|e| PlotError::draw(path, e))?;
        }
        root.present().map_err(|e| PlotError::draw(path, e))?;
    }
    write_png(path, buffer, width, HEIGHT)
}

type Area<'b> = DrawingArea<BitMapBackend<'b>, Shift>;
type DrawResult = Result<(), Box<dyn std::error::Error>>;

fn drawable(panel: &Panel) -> Vec<Vec<(f64, f64)>> {
    panel
        .series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .copied()
                .filter(|(x, y)| x.is_finite() && y.is_finite() && (!panel.log_y || *y > 0.0))
                .collect()
        })
        .collect()
}

/// A range around `lo..hi` that is never empty: a flat series gets a band around its value.
pub(crate) fn padded(lo: f64, hi: f64, log: bool) -> Range<f64> {
    if log {
        let (lo, hi) = if hi > lo {
            (lo, hi)
        } else {
            (lo / 2.0, hi * 2.0)
        };
        lo / 1.15..hi * 1.15
    } else if hi > lo {
        let margin = (hi - lo) * 0.06;
        lo - margin..hi + margin
    } else {
        let margin = lo.abs().max(1.0) * 0.05;
        lo - margin..hi + margin
    }
}

fn draw_panel(panel: &Panel, area: &Area) -> DrawResult {
    let lines = drawable(panel);
    let all: Vec<(f64, f64)> = lines.iter().flatten().copied().collect();
    let title = (FAMILY, 17).into_font();
    if all.is_empty() {
        let mut chart = ChartBuilder::on(area)
            .caption(panel.title, title)
            .margin(12)
            .build_cartesian_2d(0f64..1f64, 0f64..1f64)?;
        chart.configure_mesh().disable_mesh().draw()?;
        chart.draw_series(std::iter::once(Text::new(
            "no data",
            (0.4, 0.5),
            (FAMILY, 15).into_font(),
        )))?;
        return Ok(());
    }
    let fold = |f: fn(f64, f64) -> f64, start: f64, pick: fn(&(f64, f64)) -> f64| {
        all.iter().map(pick).fold(start, f)
    };
    let x = padded(
        fold(f64::min, f64::INFINITY, |p| p.0),
        fold(f64::max, f64::NEG_INFINITY, |p| p.0),
        false,
    );
    let (y_lo, y_hi) = (
        fold(f64::min, f64::INFINITY, |p| p.1),
        fold(f64::max, f64::NEG_INFINITY, |p| p.1),
    );
    // A log axis only pays across a decade; within one it shows a single tick.
    let log_y = panel.log_y && y_hi >= 10.0 * y_lo;
    let y = padded(y_lo, y_hi, log_y);
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(panel.title, title)
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(58);
    if log_y {
        let chart = builder.build_cartesian_2d(x, y.log_scale())?;
        finish(chart, panel, &lines)
    } else {
        let chart = builder.build_cartesian_2d(x, y)?;
        finish(chart, panel, &lines)
    }
}

/// An axis tick: whole numbers without decimals, others to three significant digits.
pub(crate) fn tick(value: f64) -> String {
    let magnitude = value.abs();
    if value == 0.0
        || (magnitude >= 1.0 && (value - value.round()).abs() < 1e-9)
        || magnitude >= 1e4
    {
        format!("{value:.0}")
    } else {
        let decimals = (2 - magnitude.log10().floor() as i32).clamp(0, 9) as usize;
        let text = format!("{value:.decimals$}");
        if text.contains('.') {
            text.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            text
        }
    }
}

fn finish<'b, Y>(
    mut chart: ChartContext<'b, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, Y>>,
    panel: &Panel,
    lines: &[Vec<(f64, f64)>],
) -> DrawResult
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc(panel.x_label)
        .x_labels(6)
        .y_labels(7)
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .label_style((FAMILY, 13))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()?;
    for (index, (series, points)) in panel.series.iter().zip(lines).enumerate() {
        let [r, g, b] = PALETTE[index % PALETTE.len()];
        let colour = RGBColor(r, g, b);
        if points.len() <= 40 {
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))?;
        }
        let drawn = chart.draw_series(LineSeries::new(
            points.iter().copied(),
            colour.stroke_width(2),
        ))?;
        if panel.series.len() > 1 {
            drawn.label(series.label).legend(move |(x, y)| {
                PathElement::new([(x, y), (x + 16, y)], colour.stroke_width(2))
            });
        }
    }
    if panel.series.len() > 1 {
        chart
            .configure_series_labels()
            .label_font((FAMILY, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(200, 200, 200))
            .draw()?;
    }
    Ok(())
}
