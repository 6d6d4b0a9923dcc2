//! `reconstruction_metrics`: compares a rendered frame with the frame it came from. Camera
//! PSNR and SSIM are taken at the rendered size, against the input image resized to it
//! (triangle filter, as the encoder resizes); the LiDAR Chamfer distance is taken in the ego
//! frame within an ROI (4D-Occ's by default), applied to each cloud on its own. The input's
//! returns off the ego vehicle's body (`EgoBody`) leave the ground truth, as 4D-Occ drops them.
//! Every rendered point counts: the render casts one ray per remaining return, and a ray it
//! ends on the car, or short of a return beyond its far plane, is an error that 4D-Occ's
//! protocol (a prediction for every ray with a return) counts too. Means over frames go into
//! the node's metrics.

use std::path::PathBuf;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, ParamError, PortSpec, Registry, Sink,
};
use bevworld_types::{ImageSet, PointCloud, SensorFrame};
use image::imageops::FilterType;
use serde::{Deserialize, Serialize};

use crate::chamfer::{ChamferResult, Roi, chamfer_in_roi};
use crate::image::{ImageMetricError, Planes, psnr, rgb_planes, ssim};

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ReconstructionMetricsParams {
    /// ROI preset for the Chamfer distance: `4docc` or `vidar`.
    #[serde(default = "default_roi")]
    pub roi: String,
    /// Also write one CSV row per frame here.
    #[serde(default)]
    pub csv: Option<PathBuf>,
}

fn default_roi() -> String {
    "4docc".into()
}

/// One frame's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameScores {
    pub frame_token: String,
    pub psnr_db: f64,
    pub ssim: f64,
    /// `None` when the rendered or the true sweep has no point in the ROI: an empty cloud is
    /// reported and counted, never scored as a perfect 0.
    pub chamfer_m2: Option<f64>,
    /// NaN or infinite points the source dropped from the true sweep.
    pub truth_non_finite_points_dropped: usize,
}

/// Why a reconstruction could not be scored.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ScoreError {
    #[error("rendered image '{image}' has no camera of that name in frame {frame}")]
    NoSuchCamera { image: String, frame: String },
    #[error("no rendered images for frame {frame}")]
    NoImages { frame: String },
    #[error("frame {frame}, image '{image}': {source}")]
    Image {
        frame: String,
        image: String,
        source: ImageMetricError,
    },
}

/// Mean camera PSNR and SSIM of `images` against `frame`'s cameras, each resized to the
/// rendered size.
pub fn score_images(frame: &SensorFrame, images: &ImageSet) -> Result<(f64, f64), ScoreError> {
    let (mut psnr_sum, mut ssim_sum, mut count) = (0.0, 0.0, 0usize);
    for rendered in &images.images {
        let Some(input) = frame
            .cameras
            .iter()
            .find(|c| c.channel.name() == rendered.name)
        else {
            return Err(ScoreError::NoSuchCamera {
                image: rendered.name.clone(),
                frame: frame.frame_token.clone(),
            });
        };
        let (w, h) = rendered.image.dimensions();
        let resized = image::imageops::resize(input.image.as_ref(), w, h, FilterType::Triangle);
        let (a, b) = (rgb_planes(&resized), rgb_planes(&rendered.image));
        let planes = |data| Planes {
            data,
            channels: 3,
            height: h as usize,
            width: w as usize,
        };
        let (pa, pb) = (planes(&a), planes(&b));
        // Identical images have infinite PSNR; cap at 100 dB so means stay finite.
        let image_error = |source| ScoreError::Image {
            frame: frame.frame_token.clone(),
            image: rendered.name.clone(),
            source,
        };
        psnr_sum += psnr(&pa, &pb, 255.0).map_err(image_error)?.min(100.0);
        ssim_sum += ssim(&pa, &pb, 255.0).map_err(image_error)?;
        count += 1;
    }
    if count == 0 {
        return Err(ScoreError::NoImages {
            frame: frame.frame_token.clone(),
        });
    }
    Ok((psnr_sum / count as f64, ssim_sum / count as f64))
}

/// The Chamfer distance of a rendered sweep against `frame`'s returns off the ego body, both
/// in the ego frame, within `roi`.
pub fn score_lidar(frame: &SensorFrame, lidar: &PointCloud, roi: &Roi) -> ChamferResult {
    chamfer_in_roi(
        &to_f64(lidar.ego_points()),
        &to_f64(frame.lidar.scene_ego_points()),
        roi,
    )
}

pub fn to_f64(points: Vec<[f32; 3]>) -> Vec<[f64; 3]> {
    points
        .into_iter()
        .map(|p| [p[0].into(), p[1].into(), p[2].into()])
        .collect()
}

/// Scores a reconstruction against its input frame.
pub fn score_frame(
    frame: &SensorFrame,
    images: &ImageSet,
    lidar: &PointCloud,
    roi: &Roi,
) -> Result<FrameScores, ScoreError> {
    let (psnr_db, ssim) = score_images(frame, images)?;
    Ok(FrameScores {
        frame_token: frame.frame_token.clone(),
        psnr_db,
        ssim,
        chamfer_m2: {
            let result = score_lidar(frame, lidar, roi);
            (result.pred_points > 0 && result.gt_points > 0).then_some(result.chamfer)
        },
        truth_non_finite_points_dropped: frame.lidar.dropped_non_finite,
    })
}

pub struct ReconstructionMetrics {
    roi: Roi,
    csv: Option<PathBuf>,
    scores: Vec<FrameScores>,
}

impl Sink for ReconstructionMetrics {
    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let frame = inputs.get::<SensorFrame>("frame")?;
        let images = inputs.get::<ImageSet>("images")?;
        let lidar = inputs.get::<PointCloud>("lidar")?;
        let scores =
            score_frame(frame, images, lidar, &self.roi).map_err(|e| NodeError::item_from(&e))?;
        tracing::info!(
            frame = %scores.frame_token,
            psnr_db = format!("{:.2}", scores.psnr_db),
            ssim = format!("{:.3}", scores.ssim),
            chamfer_m2 = scores
                .chamfer_m2
                .map_or("empty cloud".to_string(), |c| format!("{c:.3}")),
            "reconstruction"
        );
        self.scores.push(scores);
        Ok(())
    }

    fn finish(&mut self) -> Result<(), NodeError> {
        let Some(path) = &self.csv else {
            return Ok(());
        };
        let mut text =
            String::from("frame_token,psnr_db,ssim,chamfer_m2,truth_non_finite_points_dropped\n");
        for s in &self.scores {
            text.push_str(&format!(
                "{},{:.4},{:.5},{},{}\n",
                s.frame_token,
                s.psnr_db,
                s.ssim,
                s.chamfer_m2.map_or(String::new(), |c| format!("{c:.5}")),
                s.truth_non_finite_points_dropped
            ));
        }
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)
                .map_err(|e| NodeError::fatal(format!("creating {}: {e}", parent.display())))?;
        }
        std::fs::write(path, text)
            .map_err(|e| NodeError::fatal(format!("writing {}: {e}", path.display())))
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        let n = self.scores.len();
        figures.insert("frames_scored".into(), n as f64);
        if n > 0 {
            let mean =
                |f: fn(&FrameScores) -> f64| self.scores.iter().map(f).sum::<f64>() / n as f64;
            figures.insert("psnr_db_mean".into(), mean(|s| s.psnr_db));
            figures.insert("ssim_mean".into(), mean(|s| s.ssim));
            let chamfers: Vec<f64> = self.scores.iter().filter_map(|s| s.chamfer_m2).collect();
            figures.insert("empty_clouds".into(), (n - chamfers.len()) as f64);
            // The truth is what the source kept: say how much it could not keep.
            figures.insert(
                "truth_non_finite_points_dropped".into(),
                self.scores
                    .iter()
                    .map(|s| s.truth_non_finite_points_dropped as f64)
                    .sum(),
            );
            if !chamfers.is_empty() {
                figures.insert(
                    "chamfer_m2_mean".into(),
                    chamfers.iter().sum::<f64>() / chamfers.len() as f64,
                );
            }
        }
        figures
    }
}

fn roi_of(params: &ReconstructionMetricsParams) -> Result<Roi, ParamError> {
    Roi::preset(&params.roi).ok_or_else(|| {
        ParamError::field("roi", format!("unknown preset '{}'", params.roi))
            .with_accepted("4docc, vidar")
    })
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::sink(
            "reconstruction_metrics",
            "camera PSNR/SSIM and LiDAR Chamfer of a rendered frame against its input frame",
        )
        .input(PortSpec::new::<SensorFrame>("frame"))
        .input(PortSpec::new::<ImageSet>("images"))
        .input(PortSpec::new::<PointCloud>("lidar")),
        |params: &ReconstructionMetricsParams| roi_of(params).map(|_| ()),
        |params: ReconstructionMetricsParams| {
            let roi = roi_of(&params)?;
            Ok(Node::Sink(Box::new(ReconstructionMetrics {
                roi,
                csv: params.csv,
                scores: Vec::new(),
            })))
        },
    );
}
