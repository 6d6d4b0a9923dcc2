//! `forecast_sink`: a forecast's renders as files, for each context frame:
//!
//! - `<out>/<scene>-<index>/+0.5s/CAM_*.png` and `LIDAR_TOP.ply` (the forecast, the sweep in
//!   the predicted ego frame), `LIDAR_TOP_true.ply` where the log recorded that future;
//! - `<out>/<scene>-<index>/+0.5s/top_down.png`: the true sweep beside the forecast one, seen
//!   from above, the picture a user looks at first;
//! - `<out>/<scene>-<index>/strip_CAM_*.png` once every horizon is in: one column per horizon,
//!   the truth above the forecast (grey where the log has no truth).
//!
//! Only one method's renders are written (`method`, the forecast by default); the others are
//! scored, not saved.
//!
//! - **PLY intensity.** `LIDAR_TOP_true.ply` holds the logged returns with their logged
//!   intensity. The tokenizer does not model reflectance, so a forecast's `intensity` is the
//!   rendered ray's opacity `1 − T` in [0, 1]: how surely the ray met a surface.
//! - **The folder is this run's.** Scene names come from the dataset and become one file
//!   name each (`safe_file_name`), so nothing lands outside `out`. The folder is claimed for
//!   the run (`FolderClaim`: a second run into it at the same time is refused), and at the end
//!   the files of the sink's layout that this run did not write (a previous run's other
//!   horizons, contexts or truths) are removed and counted (`previous_run_files_removed`), so
//!   that the folder holds one run's forecast and nothing stale beside it.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use bevworld_graph::io::{FolderClaim, safe_file_name};
use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, ParamError, Port, Registry, Sink,
};
use bevworld_plot::{Cloud, caption, top_down};
use bevworld_types::{
    ForecastMethod, FutureView, ImageSet, LidarPoint, PointCloud, RenderedFuture,
};
use image::imageops::FilterType;
use image::{ImageFormat, RgbImage};
use serde::{Deserialize, Serialize};

use crate::ply::{PlyEncoding, PlyPoint, encode_ply};
use crate::writes::Writes;

// The node's ports, each named once (`bevworld_graph::Port`).
const RENDERED: Port<RenderedFuture> = Port::new("rendered");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ForecastSinkParams {
    /// Output folder; one sub-folder per context frame.
    pub out: PathBuf,
    /// Half the side of the top-down picture, in metres.
    #[serde(default = "default_extent")]
    pub top_down_half_extent_m: f64,
    /// Whose renders are written: `model` (the forecast), or a baseline's name.
    #[serde(default = "default_method")]
    pub method: String,
}

fn default_method() -> String {
    ForecastMethod::Model.name().into()
}

fn default_extent() -> f64 {
    50.0
}

/// The folder of a view's context frame: the scene's name made safe as one file name
/// (`safe_file_name`), whatever the dataset calls it.
pub fn context_folder(view: &FutureView) -> String {
    safe_file_name(&format!(
        "{}-{:04}",
        view.context.scene_name, view.context.index_in_scene
    ))
}

/// A horizon's folder name: `+0.5s`.
pub fn horizon_folder(horizon_s: f64) -> String {
    format!("+{horizon_s}s")
}

/// One horizon's renders of one context, kept until the strip of every horizon is drawn.
struct Column {
    horizon_s: f64,
    forecast: ImageSet,
    truth: Option<ImageSet>,
}

pub struct ForecastSink {
    params: ForecastSinkParams,
    method: ForecastMethod,
    writes: Writes,
    /// Per context folder, the columns seen so far.
    strips: BTreeMap<String, Vec<Column>>,
    /// Every file this run wrote: the rest of the sink's layout in `out` is a previous run's.
    written: BTreeSet<PathBuf>,
    /// Views received, and those of the method this sink writes.
    views: u64,
    views_written: u64,
    previous_run_files_removed: u64,
    _claim: Option<FolderClaim>,
}

pub(crate) fn png(image: &RgbImage, name: &str) -> Result<Vec<u8>, NodeError> {
    let mut bytes = Vec::new();
    image
        .write_to(&mut Cursor::new(&mut bytes), ImageFormat::Png)
        .map_err(|error| NodeError::item(format!("encoding {name} as PNG: {error}")))?;
    Ok(bytes)
}

fn ply(points: &[LidarPoint], comment: &str) -> Result<Vec<u8>, NodeError> {
    let points: Vec<PlyPoint> = points
        .iter()
        .map(|p| PlyPoint::new(p.x, p.y, p.z, p.intensity))
        .collect();
    encode_ply(&points, PlyEncoding::BinaryLittleEndian, Some(comment))
        .map_err(|error| NodeError::item(error.to_string()))
}

/// The truth's camera images at the forecast's size, in the forecast's order.
fn truth_images(view: &FutureView, like: &ImageSet) -> Option<ImageSet> {
    let truth = view.truth.as_ref()?;
    let images = like
        .images
        .iter()
        .map(|named| {
            let (w, h) = named.image.dimensions();
            let image = truth
                .cameras
                .iter()
                .find(|c| c.channel.name() == named.name)
                .map(|c| image::imageops::resize(c.image.as_ref(), w, h, FilterType::Triangle))
                .unwrap_or_else(|| RgbImage::from_pixel(w, h, image::Rgb([128, 128, 128])));
            bevworld_types::NamedImage {
                name: named.name.clone(),
                image: Arc::new(image),
            }
        })
        .collect();
    Some(ImageSet { images })
}

/// Whether `name`, in a context folder (`in_horizon`: in one of its horizon folders), is a
/// file of this sink's layout.
fn is_layout_file(name: &str, in_horizon: bool) -> bool {
    if in_horizon {
        matches!(
            name,
            "LIDAR_TOP.ply" | "LIDAR_TOP_true.ply" | "top_down.png"
        ) || (name.starts_with("CAM_") && name.ends_with(".png"))
    } else {
        name.starts_with("strip_CAM_") && name.ends_with(".png")
    }
}

/// The files of the sink's layout under `out`: `<context>/strip_CAM_*.png` and
/// `<context>/+<h>s/{CAM_*.png, LIDAR_TOP.ply, LIDAR_TOP_true.ply, top_down.png}`.
fn layout_files(out: &Path) -> Vec<PathBuf> {
    let entries = |dir: &Path| -> Vec<std::fs::DirEntry> {
        std::fs::read_dir(dir)
            .map(|read| read.flatten().collect())
            .unwrap_or_default()
    };
    let mut files = Vec::new();
    for context in entries(out).into_iter().filter(|e| e.path().is_dir()) {
        for entry in entries(&context.path()) {
            let name = entry.file_name().to_string_lossy().to_string();
            let path = entry.path();
            if path.is_dir() && name.starts_with('+') && name.ends_with('s') {
                files.extend(
                    entries(&path)
                        .into_iter()
                        .filter(|e| is_layout_file(&e.file_name().to_string_lossy(), true))
                        .map(|e| e.path()),
                );
            } else if path.is_file() && is_layout_file(&name, false) {
                files.push(path);
            }
        }
    }
    files
}

impl ForecastSink {
    /// Writes one file, remembering it as this run's.
    fn put(&mut self, path: PathBuf, bytes: Vec<u8>) -> Result<(), NodeError> {
        self.written.insert(path.clone());
        self.writes.write(path, bytes)
    }

    /// Removes the files of the layout this run did not write, and folders left empty.
    fn remove_previous_run(&mut self) -> Result<(), NodeError> {
        for stale in layout_files(&self.params.out) {
            if self.written.contains(&stale) {
                continue;
            }
            std::fs::remove_file(&stale).map_err(|error| {
                NodeError::fatal(format!(
                    "{}: a previous run's file, which cannot be removed: {error}",
                    stale.display()
                ))
            })?;
            self.previous_run_files_removed += 1;
            // Its folder, and the context folder above it, go once empty (remove_dir refuses
            // a folder that is not).
            if let Some(parent) = stale.parent() {
                let _ = std::fs::remove_dir(parent);
                if let Some(context) = parent.parent().filter(|p| *p != self.params.out) {
                    let _ = std::fs::remove_dir(context);
                }
            }
        }
        if self.previous_run_files_removed > 0 {
            tracing::info!(
                out = %self.params.out.display(),
                files = self.previous_run_files_removed,
                "removed the files of a previous run that this one did not write"
            );
        }
        Ok(())
    }

    fn write_strips(&mut self, folder: &str) -> Result<(), NodeError> {
        let Some(mut columns) = self.strips.remove(folder) else {
            return Ok(());
        };
        columns.sort_by(|a, b| a.horizon_s.total_cmp(&b.horizon_s));
        let Some(first) = columns.first() else {
            return Ok(());
        };
        for (camera, named) in first.forecast.images.iter().enumerate() {
            let (w, h) = named.image.dimensions();
            let (label, margin) = (16, 72);
            let mut strip = RgbImage::from_pixel(
                margin + w * columns.len() as u32,
                2 * h + label,
                image::Rgb([255, 255, 255]),
            );
            for (row, text) in [(0, "truth"), (1, "forecast")] {
                let tile = caption(margin, label, text);
                let y = i64::from(label + row * h + h / 2 - label / 2);
                image::imageops::replace(&mut strip, &tile, 0, y);
            }
            for (i, column) in columns.iter().enumerate() {
                let x = i64::from(margin) + i64::from(w) * i as i64;
                let title = caption(w, label, &horizon_folder(column.horizon_s));
                image::imageops::replace(&mut strip, &title, x, 0);
                let grey = RgbImage::from_pixel(w, h, image::Rgb([128, 128, 128]));
                let truth = column
                    .truth
                    .as_ref()
                    .and_then(|t| t.images.get(camera))
                    .map_or(&grey, |n| n.image.as_ref());
                image::imageops::replace(&mut strip, truth, x, i64::from(label));
                if let Some(forecast) = column.forecast.images.get(camera) {
                    image::imageops::replace(
                        &mut strip,
                        forecast.image.as_ref(),
                        x,
                        i64::from(label + h),
                    );
                }
            }
            let bytes = png(&strip, &named.name)?;
            let path = self
                .params
                .out
                .join(folder)
                .join(safe_file_name(&format!("strip_{}.png", named.name)));
            self.put(path, bytes)?;
        }
        Ok(())
    }
}

impl Sink for ForecastSink {
    fn start(&mut self) -> Result<(), NodeError> {
        self._claim = Some(FolderClaim::acquire(&self.params.out).map_err(NodeError::fatal)?);
        Ok(())
    }

    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let rendered = inputs.get(&RENDERED)?;
        let view = &rendered.view;
        self.views += 1;
        // One forecast is written: the method's point forecast, not the model's further draws.
        if view.method != self.method || view.sample != 0 {
            return Ok(());
        }
        self.views_written += 1;
        let folder = context_folder(view);
        let dir = self
            .params
            .out
            .join(&folder)
            .join(horizon_folder(view.horizon_s));
        if let Some(images) = &rendered.images {
            for named in &images.images {
                self.put(
                    dir.join(safe_file_name(&format!("{}.png", named.name))),
                    png(&named.image, &named.name)?,
                )?;
            }
        }
        let comment = format!(
            "bevworld forecast, ego frame; context {}; horizon {} s; timestamp_us {}",
            view.context.frame_token, view.horizon_s, view.latent.meta.time_of_validity_us
        );
        let forecast_points = rendered.lidar.as_ref().map(PointCloud::ego_returns);
        let truth_points = view.truth.as_ref().map(|t| t.lidar.scene_ego_returns());
        if let Some(points) = &forecast_points {
            let comment = format!("{comment}; intensity: the rendered ray's opacity 1 - T");
            self.put(dir.join("LIDAR_TOP.ply"), ply(points, &comment)?)?;
        }
        if let Some(points) = &truth_points {
            self.put(
                dir.join("LIDAR_TOP_true.ply"),
                ply(
                    points,
                    &format!(
                        "bevworld logged sweep, ego frame; {}; intensity as logged",
                        view.rays.frame_token
                    ),
                )?,
            )?;
        }
        if let Some(points) = &forecast_points {
            let flat = |points: &[LidarPoint]| -> Vec<[f32; 2]> {
                points.iter().map(|p| [p.x, p.y]).collect()
            };
            let size = 480;
            let half = self.params.top_down_half_extent_m;
            let forecast_xy = flat(points);
            let right = top_down(
                size,
                half,
                &format!("forecast {}", horizon_folder(view.horizon_s)),
                &[Cloud {
                    label: "forecast",
                    points: &forecast_xy,
                    colour: [230, 120, 20],
                }],
            );
            let truth_xy = truth_points.as_deref().map(flat).unwrap_or_default();
            let left = match &truth_points {
                Some(_) => top_down(
                    size,
                    half,
                    "logged sweep",
                    &[Cloud {
                        label: "truth",
                        points: &truth_xy,
                        colour: [90, 90, 90],
                    }],
                ),
                None => {
                    let mut blank = RgbImage::from_pixel(size, size, image::Rgb([255, 255, 255]));
                    let text = caption(size, 24, "no logged sweep at this horizon");
                    image::imageops::replace(&mut blank, &text, 0, i64::from(size / 2 - 12));
                    blank
                }
            };
            let mut pair = RgbImage::new(2 * size, size);
            image::imageops::replace(&mut pair, &left, 0, 0);
            image::imageops::replace(&mut pair, &right, i64::from(size), 0);
            self.put(dir.join("top_down.png"), png(&pair, "top_down")?)?;
        }
        if let Some(images) = &rendered.images {
            let columns = self.strips.entry(folder.clone()).or_default();
            columns.push(Column {
                horizon_s: view.horizon_s,
                truth: truth_images(view, images),
                forecast: images.clone(),
            });
            if columns.len() >= view.horizons_in_forecast {
                self.write_strips(&folder)?;
            }
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), NodeError> {
        let folders: Vec<String> = self.strips.keys().cloned().collect();
        for folder in folders {
            self.write_strips(&folder)?;
        }
        self.writes.flush()?;
        self.remove_previous_run()
    }

    fn report(&self) -> Figures {
        Figures::from([
            ("views".to_string(), self.views as f64),
            ("views_written".to_string(), self.views_written as f64),
            ("files_written".to_string(), self.written.len() as f64),
            (
                "previous_run_files_removed".to_string(),
                self.previous_run_files_removed as f64,
            ),
        ])
    }

    fn nothing_made(&self) -> Option<String> {
        (self.views_written == 0 && self.views > 0).then(|| {
            format!(
                "none of the {} views it received was of method '{}', the one it writes",
                self.views,
                self.method.name()
            )
        })
    }
}

pub fn register(registry: &mut Registry) {
    registry.register(
        KindSpec::sink(
            "forecast_sink",
            "a forecast's renders as PNG and PLY per context and horizon, with strips per camera and top-down sweeps",
        )
        .input(RENDERED.spec()),
        |params: ForecastSinkParams| {
            if !(params.top_down_half_extent_m.is_finite() && params.top_down_half_extent_m > 0.0) {
                return Err(ParamError::field("top_down_half_extent_m", "must be a number > 0"));
            }
            let method = ForecastMethod::parse(&params.method).ok_or_else(|| {
                ParamError::field("method", format!("unknown method '{}'", params.method))
                    .with_accepted(
                        ForecastMethod::ALL
                            .iter()
                            .map(|m| m.name())
                            .collect::<Vec<_>>()
                            .join(", "),
                    )
            })?;
            Ok(Node::Sink(Box::new(ForecastSink {
                method,
                writes: Writes::new(params.out.clone(), 16),
                params,
                strips: BTreeMap::new(),
                written: BTreeSet::new(),
                views: 0,
                views_written: 0,
                previous_run_files_removed: 0,
                _claim: None,
            })))
        },
    );
}
