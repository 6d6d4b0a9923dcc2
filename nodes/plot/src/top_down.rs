//! Point clouds seen from above: the picture of a LiDAR sweep a reader takes in first.

use plotters::prelude::*;

use crate::curves::tick;
use crate::font::{FAMILY, ensure_registered};

/// One cloud to draw, `(x, y)` in metres in one frame (forward x, left y), in its colour.
pub struct Cloud<'a> {
    pub label: &'a str,
    pub points: &'a [[f32; 2]],
    pub colour: [u8; 3],
}

/// A line to draw over the clouds, `(x, y)` in metres in the clouds' frame: a box's outline
/// (closed) or a trajectory (open).
pub struct Polyline {
    pub points: Vec<[f32; 2]>,
    pub colour: [u8; 3],
    pub closed: bool,
}

/// A `size × size` RGB image of the clouds over the square `[-half_extent_m, half_extent_m]²`
/// around the origin, forward up and left to the left, as a driver sees the map. Later clouds
/// are drawn over earlier ones; points outside the square are left out.
pub fn top_down(size: u32, half_extent_m: f64, title: &str, clouds: &[Cloud]) -> image::RgbImage {
    top_down_with_lines(size, half_extent_m, title, clouds, &[])
}

/// `top_down` with `lines` drawn over the clouds.
pub fn top_down_with_lines(
    size: u32,
    half_extent_m: f64,
    title: &str,
    clouds: &[Cloud],
    lines: &[Polyline],
) -> image::RgbImage {
    ensure_registered();
    let mut buffer = vec![0u8; (size * size * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (size, size)).into_drawing_area();
        // Drawing into a buffer of the right size only fails on a font fault; the image is
        // then returned as far as it was drawn.
        let _ = draw(&root, half_extent_m, title, clouds, lines);
        let _ = root.present();
    }
    image::RgbImage::from_raw(size, size, buffer)
        .unwrap_or_else(|| image::RgbImage::new(size, size))
}

fn draw(
    root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
    half: f64,
    title: &str,
    clouds: &[Cloud],
    lines: &[Polyline],
) -> Result<(), Box<dyn std::error::Error>> {
    root.fill(&WHITE)?;
    // Screen x is the ego's left (−y), screen y its forward (x).
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FAMILY, 15).into_font())
        .margin(8)
        .x_label_area_size(24)
        .y_label_area_size(34)
        .build_cartesian_2d(-half..half, -half..half)?;
    chart
        .configure_mesh()
        .label_style((FAMILY, 11))
        .light_line_style(RGBColor(240, 240, 240))
        .x_label_formatter(&|v| tick(0.0 - v))
        .y_label_formatter(&|v| tick(*v))
        .draw()?;
    for cloud in clouds {
        let [r, g, b] = cloud.colour;
        let colour = RGBColor(r, g, b);
        chart
            .draw_series(
                cloud
                    .points
                    .iter()
                    .map(|p| (-f64::from(p[1]), f64::from(p[0])))
                    .filter(|(x, y)| x.abs() <= half && y.abs() <= half)
                    .map(|p| Pixel::new(p, colour)),
            )?
            .label(cloud.label)
            .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 8, y + 4)], colour.filled()));
    }
    for line in lines {
        let [r, g, b] = line.colour;
        let mut points: Vec<(f64, f64)> = line
            .points
            .iter()
            .map(|p| (-f64::from(p[1]), f64::from(p[0])))
            .collect();
        if line.closed
            && let Some(&first) = points.first()
        {
            points.push(first);
        }
        chart.draw_series(std::iter::once(PathElement::new(
            points,
            RGBColor(r, g, b).stroke_width(2),
        )))?;
    }
    chart.draw_series(std::iter::once(Circle::new((0.0, 0.0), 3, BLACK.filled())))?;
    if clouds.len() > 1 {
        chart
            .configure_series_labels()
            .label_font((FAMILY, 12))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(200, 200, 200))
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
    }
    Ok(())
}

/// A `width × height` white strip with `text` centred in it, to label the panels of a
/// composed figure.
pub fn caption(width: u32, height: u32, text: &str) -> image::RgbImage {
    ensure_registered();
    let mut buffer = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let style = TextStyle::from((FAMILY, (height as f64 * 0.6).max(10.0)).into_font()).pos(
            plotters::style::text_anchor::Pos::new(
                plotters::style::text_anchor::HPos::Center,
                plotters::style::text_anchor::VPos::Center,
            ),
        );
        let _ = root.draw_text(text, &style, (width as i32 / 2, height as i32 / 2));
        let _ = root.present();
    }
    image::RgbImage::from_raw(width, height, buffer)
        .unwrap_or_else(|| image::RgbImage::new(width, height))
}
