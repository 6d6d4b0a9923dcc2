//! Charts for the benchmarks and the training runs, drawn with `plotters`: the one plotting
//! module of the workspace.
//!
//! Text is set in DejaVu Sans, embedded (a subset of its Latin, Greek and symbol glyphs; the
//! licence is beside it in `fonts/`), so a chart looks the same on every machine and needs no
//! system font library.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

mod bars;
mod curves;
mod font;
mod scatter;
mod top_down;

pub use bars::bars_svg;
pub use curves::{Panel, Series, panels_png};
pub use scatter::{Labelled, Reference, ScatterPlot, scatter_png};
pub use top_down::{Cloud, Polyline, caption, top_down, top_down_with_lines};

use std::path::{Path, PathBuf};

/// A chart that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("plot {path}: {message}")]
    Draw { path: PathBuf, message: String },
    #[error("plot {path}: {source}")]
    Write {
        path: PathBuf,
        source: image::ImageError,
    },
}

impl PlotError {
    fn draw(path: &Path, error: impl std::fmt::Display) -> Self {
        Self::Draw {
            path: path.to_path_buf(),
            message: error.to_string(),
        }
    }
}

/// Colours of successive series, from a palette that stays apart for the colour-blind (Okabe
/// and Ito).
pub const PALETTE: [[u8; 3]; 7] = [
    [0, 114, 178],
    [213, 94, 0],
    [0, 158, 115],
    [204, 121, 167],
    [230, 159, 0],
    [86, 180, 233],
    [0, 0, 0],
];

/// Encodes an RGB buffer of `width × height` pixels as PNG at `path`.
fn write_png(path: &Path, buffer: Vec<u8>, width: u32, height: u32) -> Result<(), PlotError> {
    let image = image::RgbImage::from_raw(width, height, buffer)
        .ok_or_else(|| PlotError::draw(path, "the drawing buffer has the wrong size"))?;
    save_png(path, &image)
}

/// Writes `image` as a PNG at `path`, whole or not at all (`bevworld_atomic_file`): every
/// picture the workspace draws outside a graph goes through here.
pub fn save_png(path: &Path, image: &image::RgbImage) -> Result<(), PlotError> {
    let write_error = |source| PlotError::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(write_error)?;
    bevworld_atomic_file::write(path, &bytes)
        .map_err(|e| write_error(image::ImageError::IoError(e)))
}
