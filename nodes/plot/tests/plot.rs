//! The charts are checked by what they draw: sizes, where a series' colour lands, the text in
//! an SVG, and that bad values are left out instead of failing.

use bevworld_plot::{
    Cloud, Labelled, PALETTE, Panel, Reference, ScatterPlot, Series, bars_svg, panels_png,
    scatter_png, top_down,
};

fn coloured_pixels(image: &image::RgbImage, colour: [u8; 3]) -> Vec<(u32, u32)> {
    image
        .enumerate_pixels()
        .filter(|(_, _, p)| p.0 == colour)
        .map(|(x, y, _)| (x, y))
        .collect()
}

#[test]
fn panels_draw_each_series_in_its_panel_and_skip_what_a_log_axis_cannot_show() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("curves.png");
    let loss = [
        (1.0, 2.0),
        (2.0, 1.0),
        (3.0, 0.0),
        (4.0, f64::NAN),
        (5.0, 0.25),
    ];
    let psnr = [(1.0, 18.0), (5.0, 24.0)];
    panels_png(
        &path,
        &[
            Panel {
                title: "training loss",
                x_label: "step",
                log_y: true,
                series: vec![Series {
                    label: "loss",
                    points: &loss,
                }],
            },
            Panel {
                title: "PSNR (dB)",
                x_label: "step",
                log_y: false,
                series: vec![Series {
                    label: "val",
                    points: &psnr,
                }],
            },
            Panel {
                title: "Chamfer (m²)",
                x_label: "step",
                log_y: true,
                series: vec![],
            },
        ],
    )
    .expect("plot");
    let image = image::open(&path).expect("png").to_rgb8();
    assert_eq!(image.width(), 3 * 420);
    assert_eq!(image.height(), 360);
    let line = coloured_pixels(&image, PALETTE[0]);
    assert!(
        line.len() > 50,
        "the series were drawn: {} pixels",
        line.len()
    );
    // Both first series share the first colour: one in each of the first two panels, none in
    // the empty third.
    assert!(line.iter().any(|(x, _)| *x < 420));
    assert!(line.iter().any(|(x, _)| (420..840).contains(x)));
    assert!(line.iter().all(|(x, _)| *x < 840));
    // Text was set in the embedded font: dark pixels in each panel's title band.
    let dark_in = |x0: u32, x1: u32| {
        (x0..x1).any(|x| (0..30).any(|y| image.get_pixel(x, y).0.iter().all(|&c| c < 90)))
    };
    assert!(dark_in(0, 420) && dark_in(420, 840) && dark_in(840, 1260));
}

#[test]
fn a_flat_series_still_gets_a_range() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("flat.png");
    let flat = [(0.0, 3.0), (10.0, 3.0)];
    panels_png(
        &path,
        &[Panel {
            title: "flat",
            x_label: "step",
            log_y: true,
            series: vec![Series {
                label: "a",
                points: &flat,
            }],
        }],
    )
    .expect("a flat series is drawn");
    let image = image::open(&path).expect("png").to_rgb8();
    assert!(!coloured_pixels(&image, PALETTE[0]).is_empty());
}

#[test]
fn bars_name_every_row_and_value_and_leave_out_what_cannot_be_drawn() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("bars.svg");
    let items = vec![
        ("bare channel".to_string(), 5.2e6),
        ("runtime".to_string(), 9.6e5),
        ("broken".to_string(), f64::NAN),
        ("zero".to_string(), 0.0),
    ];
    bars_svg(&path, "throughput", "messages/s", &items, true).expect("svg");
    let svg = std::fs::read_to_string(&path).expect("read");
    for text in [
        "throughput",
        "bare channel",
        "runtime",
        "broken",
        "zero",
        "5.20M",
        "960.0k",
    ] {
        assert!(svg.contains(text), "{text} missing from the SVG");
    }
    assert!(svg.contains("messages/s (log scale)"));
    // Two bars: the NaN and the zero (on a log axis) get a label and no bar.
    let bars = svg.matches("fill=\"#3B6EA8\"").count();
    assert_eq!(bars, 2, "{svg}");
}

#[test]
fn the_same_bars_give_the_same_svg_with_the_bars_in_the_items_order() {
    let dir = tempfile::tempdir().expect("dir");
    let items: Vec<(String, f64)> = (0..12)
        .map(|i| (format!("stage {i}"), 10.0 + f64::from(i) * 7.0))
        .collect();
    let (first, second) = (dir.path().join("a.svg"), dir.path().join("b.svg"));
    bars_svg(&first, "stages", "ms", &items, false).expect("svg");
    bars_svg(&second, "stages", "ms", &items, false).expect("svg");
    let svg = std::fs::read_to_string(&first).expect("read");
    assert_eq!(svg, std::fs::read_to_string(&second).expect("read"));
    // Row 0 at the top: each bar lower and wider than the one before.
    let bars: Vec<(u32, u32)> = svg
        .lines()
        .filter(|line| line.starts_with("<rect") && line.contains("#3B6EA8"))
        .map(|line| {
            let number = |key: &str| -> u32 {
                let rest = line.split(&format!(" {key}=\"")).nth(1).expect("attribute");
                rest.split('"')
                    .next()
                    .expect("value")
                    .parse()
                    .expect("number")
            };
            (number("y"), number("width"))
        })
        .collect();
    assert_eq!(bars.len(), items.len(), "{svg}");
    assert!(
        bars.windows(2).all(|w| w[1].0 > w[0].0 && w[1].1 > w[0].1),
        "{bars:?}"
    );
}

#[test]
fn a_scatter_writes_its_points_and_reference_lines() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("scatter.png");
    scatter_png(
        &path,
        &ScatterPlot {
            title: "speed against error",
            x_label: "ms per forecast",
            y_label: "Chamfer at 3 s (m²)",
            log_x: true,
            points: vec![
                Labelled {
                    label: "1 step",
                    x: 40.0,
                    y: 1.2,
                },
                Labelled {
                    label: "50 steps",
                    x: 2000.0,
                    y: 1.0,
                },
                Labelled {
                    label: "bad",
                    x: -1.0,
                    y: 1.0,
                },
            ],
            references: vec![Reference {
                label: "copy_last",
                y: 2.3,
            }],
        },
    )
    .expect("scatter");
    let image = image::open(&path).expect("png").to_rgb8();
    assert!(!coloured_pixels(&image, PALETTE[0]).is_empty(), "points");
    assert!(
        !coloured_pixels(&image, PALETTE[1]).is_empty(),
        "reference line"
    );
}

#[test]
fn top_down_puts_forward_up_and_left_to_the_left() {
    let ahead = [[20.0f32, 0.0]];
    let left = [[0.0f32, 20.0]];
    let image = top_down(
        400,
        40.0,
        "sweep",
        &[
            Cloud {
                label: "ahead",
                points: &ahead,
                colour: [255, 0, 0],
            },
            Cloud {
                label: "left",
                points: &left,
                colour: [0, 0, 255],
            },
        ],
    );
    let red = coloured_pixels(&image, [255, 0, 0]);
    let blue = coloured_pixels(&image, [0, 0, 255]);
    let centre_of = |pixels: &[(u32, u32)]| {
        let n = pixels.len().max(1) as f64;
        (
            pixels.iter().map(|p| f64::from(p.0)).sum::<f64>() / n,
            pixels.iter().map(|p| f64::from(p.1)).sum::<f64>() / n,
        )
    };
    // The legend's swatches share the colours; the plotted points are single pixels away from
    // the upper right corner where the legend sits.
    let red: Vec<_> = red.into_iter().filter(|p| p.0 < 300).collect();
    let blue: Vec<_> = blue.into_iter().filter(|p| p.0 < 300).collect();
    assert!(!red.is_empty() && !blue.is_empty());
    let (red_x, red_y) = centre_of(&red);
    let (blue_x, blue_y) = centre_of(&blue);
    assert!(red_y < blue_y - 50.0, "ahead is above: {red_y} vs {blue_y}");
    assert!(
        blue_x < red_x - 50.0,
        "left is to the left: {blue_x} vs {red_x}"
    );
}
