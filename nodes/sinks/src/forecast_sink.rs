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

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::PathBuf;
use std::sync::Arc;

use bevworld_graph::{Inputs, KindSpec, Node, NodeError, ParamError, PortSpec, Registry, Sink};
use bevworld_plot::{Cloud, caption, top_down};
use bevworld_types::{ForecastMethod, FutureView, ImageSet, PointCloud, RenderedFuture};
use image::imageops::FilterType;
use image::{ImageFormat, RgbImage};
use serde::{Deserialize, Serialize};

use crate::ply::{PlyEncoding, PlyPoint, encode_ply};
use crate::writes::Writes;

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

/// The folder of a view's context frame.
pub fn context_folder(view: &FutureView) -> String {
    format!(
        "{}-{:04}",
        view.context.scene_name, view.context.index_in_scene
    )
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
}

fn png(image: &RgbImage, name: &str) -> Result<Vec<u8>, NodeError> {
    let mut bytes = Vec::new();
    image
        .write_to(&mut Cursor::new(&mut bytes), ImageFormat::Png)
        .map_err(|error| NodeError::item(format!("encoding {name} as PNG: {error}")))?;
    Ok(bytes)
}

fn ply(points: &[[f32; 3]], comment: &str) -> Result<Vec<u8>, NodeError> {
    let points: Vec<PlyPoint> = points
        .iter()
        .map(|p| PlyPoint::new(p[0], p[1], p[2], 0.0))
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

impl ForecastSink {
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
            self.writes.write(
                self.params
                    .out
                    .join(folder)
                    .join(format!("strip_{}.png", named.name)),
                bytes,
            )?;
        }
        Ok(())
    }
}

impl Sink for ForecastSink {
    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let rendered = inputs.get::<RenderedFuture>("rendered")?;
        let view = &rendered.view;
        if view.method != self.method {
            return Ok(());
        }
        let folder = context_folder(view);
        let dir = self
            .params
            .out
            .join(&folder)
            .join(horizon_folder(view.horizon_s));
        if let Some(images) = &rendered.images {
            for named in &images.images {
                self.writes.write(
                    dir.join(format!("{}.png", named.name)),
                    png(&named.image, &named.name)?,
                )?;
            }
        }
        let comment = format!(
            "bevworld forecast, ego frame; context {}; horizon {} s; timestamp_us {}",
            view.context.frame_token, view.horizon_s, view.latent.meta.time_of_validity_us
        );
        let forecast_points = rendered.lidar.as_ref().map(PointCloud::ego_points);
        let truth_points = view.truth.as_ref().map(|t| t.lidar.scene_ego_points());
        if let Some(points) = &forecast_points {
            self.writes
                .write(dir.join("LIDAR_TOP.ply"), ply(points, &comment)?)?;
        }
        if let Some(points) = &truth_points {
            self.writes.write(
                dir.join("LIDAR_TOP_true.ply"),
                ply(
                    points,
                    &format!(
                        "bevworld logged sweep, ego frame; {}",
                        view.rays.frame_token
                    ),
                )?,
            )?;
        }
        if let Some(points) = &forecast_points {
            let flat = |points: &[[f32; 3]]| -> Vec<[f32; 2]> {
                points.iter().map(|p| [p[0], p[1]]).collect()
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
            self.writes
                .write(dir.join("top_down.png"), png(&pair, "top_down")?)?;
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
        self.writes.flush()
    }
}

pub fn register(registry: &mut Registry) {
    registry.register(
        KindSpec::sink(
            "forecast_sink",
            "a forecast's renders as PNG and PLY per context and horizon, with strips per camera and top-down sweeps",
        )
        .input(PortSpec::new::<RenderedFuture>("rendered")),
        |params: ForecastSinkParams| {
            if !(params.top_down_half_extent_m.is_finite() && params.top_down_half_extent_m > 0.0) {
                return Err(ParamError::field("top_down_half_extent_m", "must be a number > 0"));
            }
            let method = ForecastMethod::parse(&params.method).ok_or_else(|| {
                ParamError::field("method", format!("unknown method '{}'", params.method))
                    .with_accepted("model, latent_copy_last, latent_ego_warp, oracle")
            })?;
            Ok(Node::Sink(Box::new(ForecastSink {
                method,
                params,
                writes: Writes::new(16),
                strips: BTreeMap::new(),
            })))
        },
    );
}
