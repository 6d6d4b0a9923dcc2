//! `reconstruction_metrics`: compares a rendered frame with the frame it came from. Camera
//! PSNR and SSIM are taken at the rendered size, against the input image resized to it
//! (triangle filter, as the encoder resizes); the LiDAR Chamfer distance is taken in the ego
//! frame within an ROI (4D-Occ's by default), applied to each cloud on its own. The input's
//! returns off the ego vehicle's body (`EgoBody`) leave the ground truth, as 4D-Occ drops them.
//! Every rendered point counts: the render casts one ray per remaining return, and a ray it
//! ends on the car, or short of a return beyond its far plane, is an error that 4D-Occ's
//! protocol (a prediction for every ray with a return) counts too. Means over frames go into
//! the node's metrics; each scene's means and their spread over scenes go into its JSON summary,
//! with the rendered sweep's agent-level scores (`agents.rs`) against the frame's annotated
//! vehicles: the tokenizer's floor on the other road users.

use std::collections::BTreeMap;
use std::path::PathBuf;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, Outputs, ParamError, Port, Registry, Task,
};
use bevworld_types::{ImageSet, PointCloud, ScoreTable, SensorFrame};
use image::imageops::FilterType;
use serde::{Deserialize, Serialize};

use crate::agents::{self, AgentSums};
use crate::chamfer::{ChamferResult, Roi, chamfer_in_roi};
use crate::image::{ImageMetricError, Planes, psnr, rgb_planes, ssim};

// The node's ports, each named once (`bevworld_graph::Port`).
const FRAME: Port<SensorFrame> = Port::new("frame");
const IMAGES: Port<ImageSet> = Port::new("images");
const LIDAR: Port<PointCloud> = Port::new("lidar");
const TABLE: Port<ScoreTable> = Port::new("table");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ReconstructionMetricsParams {
    /// ROI preset for the Chamfer distance: `4docc` or `vidar`.
    #[serde(default = "default_roi")]
    pub roi: String,
    /// Also write one CSV row per frame here.
    #[serde(default)]
    pub csv: Option<PathBuf>,
    /// Also write the summary here (`summary`): the means over frames, each scene's, and
    /// their spread over scenes.
    #[serde(default)]
    pub json: Option<PathBuf>,
}

fn default_roi() -> String {
    "4docc".into()
}

/// One frame's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameScores {
    pub frame_token: String,
    pub scene_name: String,
    pub psnr_db: f64,
    pub ssim: f64,
    /// `None` when the rendered or the true sweep has no point in the ROI: an empty cloud is
    /// reported and counted, never scored as a perfect 0.
    pub chamfer_m2: Option<f64>,
    /// NaN or infinite points the source dropped from the true sweep.
    pub truth_non_finite_points_dropped: usize,
    /// The rendered sweep's agent-level sums against the frame's annotated vehicles: the
    /// tokenizer's floor on moving and parked vehicles, which no forecast decoded through it
    /// can beat by much. All static (and all zero for the vehicles) without annotations.
    pub agents: AgentSums,
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
        scene_name: frame.scene_name.clone(),
        psnr_db,
        ssim,
        chamfer_m2: {
            let result = score_lidar(frame, lidar, roi);
            (result.pred_points > 0 && result.gt_points > 0).then_some(result.chamfer)
        },
        truth_non_finite_points_dropped: frame.lidar.dropped_non_finite,
        agents: agents::score(
            &agents::split_truth(frame, roi),
            &to_f64(lidar.ego_points()),
            roi,
        ),
    })
}

pub struct ReconstructionMetrics {
    roi: Roi,
    csv: Option<PathBuf>,
    json: Option<PathBuf>,
    scores: Vec<FrameScores>,
}

impl Task for ReconstructionMetrics {
    fn process(&mut self, inputs: &Inputs, _: &mut Outputs) -> Result<(), NodeError> {
        let frame = inputs.get(&FRAME)?;
        let images = inputs.get(&IMAGES)?;
        let lidar = inputs.get(&LIDAR)?;
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

    fn finish(&mut self, out: &mut Outputs) -> Result<(), NodeError> {
        if let Some(path) = &self.csv {
            let mut text = String::from(
                "frame_token,scene,psnr_db,ssim,chamfer_m2,truth_non_finite_points_dropped\n",
            );
            for s in &self.scores {
                text.push_str(&format!(
                    "{},{},{:.4},{:.5},{},{}\n",
                    s.frame_token,
                    s.scene_name,
                    s.psnr_db,
                    s.ssim,
                    s.chamfer_m2.map_or(String::new(), |c| format!("{c:.5}")),
                    s.truth_non_finite_points_dropped
                ));
            }
            crate::report_file::write_report(path, &text)?;
        }
        if let Some(path) = &self.json {
            let text = serde_json::to_string_pretty(&summary(&self.scores))
                .map_err(|e| NodeError::fatal(format!("writing {}: {e}", path.display())))?;
            crate::report_file::write_report(path, &text)?;
        }
        if out.is_connected(&TABLE) {
            out.send(&TABLE, ScoreTable(summary(&self.scores)))?;
        }
        Ok(())
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

/// The means over `scores` of camera PSNR, SSIM and LiDAR Chamfer, the same of each scene
/// (in the order scenes first appear), and the spread of the scenes' means: their population
/// standard deviation, how much a figure moves with the scene. A frame whose render or truth
/// had no point in the ROI counts in `empty_clouds` and stays out of every Chamfer mean.
pub fn summary(scores: &[FrameScores]) -> serde_json::Value {
    let means = |frames: &[&FrameScores]| {
        let mean = |values: Vec<f64>| {
            (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
        };
        [
            mean(frames.iter().map(|s| s.psnr_db).collect()),
            mean(frames.iter().map(|s| s.ssim).collect()),
            mean(frames.iter().filter_map(|s| s.chamfer_m2).collect()),
        ]
    };
    const NAMES: [&str; 3] = ["psnr_db", "ssim", "chamfer_m2"];
    let figures = |values: [Option<f64>; 3]| {
        NAMES
            .iter()
            .zip(values)
            .map(|(name, value)| ((*name).to_string(), serde_json::json!(value)))
            .collect::<serde_json::Map<_, _>>()
    };
    let mut scene_names: Vec<&str> = Vec::new();
    for s in scores {
        if !scene_names.contains(&s.scene_name.as_str()) {
            scene_names.push(&s.scene_name);
        }
    }
    let per_scene: Vec<(&str, usize, [Option<f64>; 3])> = scene_names
        .iter()
        .map(|&name| {
            let frames: Vec<&FrameScores> =
                scores.iter().filter(|s| s.scene_name == name).collect();
            (name, frames.len(), means(&frames))
        })
        .collect();
    let spread: Vec<Option<f64>> = (0..NAMES.len())
        .map(|k| {
            let values: Vec<f64> = per_scene.iter().filter_map(|(_, _, m)| m[k]).collect();
            crate::report_file::population_std(&values)
        })
        .collect();
    let mut table = figures(means(&scores.iter().collect::<Vec<_>>()));
    table.insert("frames".into(), scores.len().into());
    table.insert(
        "empty_clouds".into(),
        scores
            .iter()
            .filter(|s| s.chamfer_m2.is_none())
            .count()
            .into(),
    );
    table.insert(
        "truth_non_finite_points_dropped".into(),
        scores
            .iter()
            .map(|s| s.truth_non_finite_points_dropped)
            .sum::<usize>()
            .into(),
    );
    table.insert(
        "scene_std".into(),
        figures([spread[0], spread[1], spread[2]]).into(),
    );
    // The rendered sweeps' agent-level scores, pooled over keyframes and per scene (null
    // without annotations).
    let mut pooled = AgentSums::default();
    let mut by_scene: BTreeMap<String, AgentSums> = BTreeMap::new();
    for s in scores {
        pooled.add(&s.agents);
        by_scene
            .entry(s.scene_name.clone())
            .or_default()
            .add(&s.agents);
    }
    table.insert(
        "agents".into(),
        agents::agents_json(&pooled, &by_scene).into(),
    );
    table.insert(
        "scenes".into(),
        per_scene
            .into_iter()
            .map(|(name, frames, values)| {
                let mut scene = figures(values);
                scene.insert("scene".into(), name.into());
                scene.insert("frames".into(), frames.into());
                serde_json::Value::Object(scene)
            })
            .collect::<Vec<_>>()
            .into(),
    );
    table.into()
}

fn roi_of(params: &ReconstructionMetricsParams) -> Result<Roi, ParamError> {
    Roi::preset(&params.roi).ok_or_else(|| {
        ParamError::field("roi", format!("unknown preset '{}'", params.roi))
            .with_accepted("4docc, vidar")
    })
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::task(
            "reconstruction_metrics",
            "camera PSNR/SSIM and LiDAR Chamfer of a rendered frame against its input frame; the summary on `table` at the end",
        )
        .input(FRAME.spec())
        .input(IMAGES.spec())
        .input(LIDAR.spec())
        .output(TABLE.spec()),
        |params: &ReconstructionMetricsParams| roi_of(params).map(|_| ()),
        |params: ReconstructionMetricsParams| {
            let roi = roi_of(&params)?;
            Ok(Node::Task(Box::new(ReconstructionMetrics {
                roi,
                csv: params.csv,
                json: params.json,
                scores: Vec::new(),
            })))
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(scene: &str, psnr_db: f64, ssim: f64, chamfer_m2: Option<f64>) -> FrameScores {
        FrameScores {
            frame_token: format!("{scene}-{psnr_db}"),
            scene_name: scene.into(),
            psnr_db,
            ssim,
            chamfer_m2,
            truth_non_finite_points_dropped: 1,
            agents: AgentSums::default(),
        }
    }

    /// `points` true points on moving vehicles, `near` of them with a rendered point within
    /// 0.5 m.
    fn with_moving(mut scores: FrameScores, points: u64, near: u64) -> FrameScores {
        let class = &mut scores.agents.classes[0];
        (class.points, class.within_near) = (points, near);
        scores
    }

    #[test]
    fn the_agent_scores_pool_over_keyframes_and_spread_over_scenes_by_hand() {
        let scores = [
            with_moving(frame("b", 20.0, 0.5, Some(1.0)), 4, 1),
            with_moving(frame("a", 30.0, 0.7, Some(1.0)), 2, 2),
            with_moving(frame("b", 22.0, 0.7, Some(3.0)), 4, 3),
        ];
        let agents = &summary(&scores)["agents"]["moving_vehicles"];
        // Pooled: (1 + 2 + 3) / (4 + 2 + 4) = 0.6. Per scene: b 4 / 8, a 2 / 2; their mean
        // 0.75 and population spread 0.25.
        assert_eq!(agents["points"], 10);
        assert!((agents["recall_0.5m"].as_f64().expect("pooled") - 0.6).abs() < 1e-12);
        assert_eq!(agents["over_scenes"]["scenes"], 2);
        assert_eq!(agents["over_scenes"]["recall_0.5m"]["mean"], 0.75);
        assert_eq!(agents["over_scenes"]["recall_0.5m"]["std"], 0.25);
        // Frames without annotated points have no agent scores, not zeros.
        assert!(summary(&[frame("a", 20.0, 0.5, None)])["agents"].is_null());
    }

    #[test]
    fn the_summary_gives_each_scenes_mean_and_their_spread_by_hand() {
        let scores = [
            frame("b", 20.0, 0.5, Some(1.0)),
            frame("a", 30.0, 0.7, None),
            frame("b", 22.0, 0.7, Some(3.0)),
            frame("a", 28.0, 0.9, Some(0.5)),
        ];
        let table = summary(&scores);
        assert_eq!(table["frames"], 4);
        assert_eq!(table["empty_clouds"], 1);
        assert_eq!(table["truth_non_finite_points_dropped"], 4);
        // Over frames: PSNR (20 + 30 + 22 + 28) / 4; Chamfer over the three with a cloud.
        assert_eq!(table["psnr_db"], 25.0);
        assert!((table["ssim"].as_f64().expect("ssim") - 0.7).abs() < 1e-12);
        assert_eq!(table["chamfer_m2"], 1.5);
        // Scenes in the order they first appear: b (21 dB, 2 m²), then a (29 dB, 0.5 m²).
        let scenes = table["scenes"].as_array().expect("scenes");
        assert_eq!(scenes[0]["scene"], "b");
        assert_eq!(scenes[0]["frames"], 2);
        assert_eq!(scenes[0]["psnr_db"], 21.0);
        assert_eq!(scenes[0]["chamfer_m2"], 2.0);
        assert_eq!(scenes[1]["psnr_db"], 29.0);
        assert_eq!(scenes[1]["chamfer_m2"], 0.5);
        // The population spread of {21, 29} is 4; of {2, 0.5}, 0.75.
        assert_eq!(table["scene_std"]["psnr_db"], 4.0);
        assert_eq!(table["scene_std"]["chamfer_m2"], 0.75);
    }

    #[test]
    fn one_scene_has_no_spread_and_nothing_scored_has_no_means() {
        let table = summary(&[frame("a", 20.0, 0.5, None)]);
        assert_eq!(table["psnr_db"], 20.0);
        assert!(table["chamfer_m2"].is_null(), "an empty cloud is no 0");
        assert!(table["scene_std"]["psnr_db"].is_null());
        let table = summary(&[]);
        assert_eq!(table["frames"], 0);
        assert!(table["psnr_db"].is_null());
        assert_eq!(table["scenes"].as_array().map(Vec::len), Some(0));
    }
}
