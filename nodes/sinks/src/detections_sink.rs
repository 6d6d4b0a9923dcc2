//! `detections_sink`: a detector's output written as a user scores and looks at it.
//!
//! - `<out>/results_nusc.json`: the keyframes' boxes in the nuScenes detection submission
//!   format (`meta` plus `results` keyed by sample token), which the official devkit and
//!   `bevworld eval detector` score. Sweeps between keyframes share their sample's token and
//!   are not samples of their own, so only keyframes enter it.
//! - `<out>/trajectories.json`: per sample token, each box's predicted modes (probability and
//!   positions in the global frame, `interval_s` apart), in the order of the boxes.
//! - `<out>/<frame>/detections.png` (with `pictures`): the sweep from above in the ego frame,
//!   every box's outline in its class's colour, its most probable trajectory drawn from its
//!   centre.
//!
//! Both JSON files are written whole at the end.

use std::collections::BTreeMap;
use std::path::PathBuf;

use bevworld_graph::io::FolderClaim;
use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, ParamError, Port, Registry, Sink,
};
use bevworld_plot::{Cloud, Polyline, top_down_with_lines};
use bevworld_types::{Detection, DetectionResults, FrameDetections, SensorFrame, SubmissionMeta};
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::forecast_sink::png;
use crate::writes::Writes;

const DETECTIONS: Port<FrameDetections> = Port::new("detections");
const FRAME: Port<SensorFrame> = Port::new("frame");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DetectionsSinkParams {
    pub out: PathBuf,
    /// A top-down picture per frame.
    #[serde(default = "default_pictures")]
    pub pictures: bool,
    /// The picture's square, ±metres around the ego.
    #[serde(default = "default_half_extent")]
    pub half_extent_m: f64,
    /// The picture draws the boxes scoring at least this (the JSON files keep every box).
    #[serde(default = "default_picture_min_score")]
    pub picture_min_score: f64,
    /// What the submission's `meta` says the detector used.
    #[serde(default)]
    pub use_camera: bool,
}

fn default_pictures() -> bool {
    true
}

fn default_half_extent() -> f64 {
    60.0
}

fn default_picture_min_score() -> f64 {
    0.3
}

/// One box's modes, as `trajectories.json` lists them.
#[derive(Serialize)]
struct Trajectories {
    detection_name: String,
    detection_score: f64,
    modes: Vec<Mode>,
}

#[derive(Serialize)]
struct Mode {
    probability: f64,
    /// (x, y) in the global frame.
    positions: Vec<[f64; 2]>,
}

pub struct DetectionsSink {
    params: DetectionsSinkParams,
    writes: Writes,
    results: BTreeMap<String, Vec<Detection>>,
    trajectories: BTreeMap<String, Vec<Trajectories>>,
    interval_s: f64,
    frames: u64,
    _claim: Option<FolderClaim>,
}

/// The colour a class is drawn in.
fn class_colour(name: &str) -> [u8; 3] {
    match name {
        "car" | "truck" | "bus" | "trailer" | "construction_vehicle" => [30, 100, 220],
        "pedestrian" => [220, 40, 40],
        "bicycle" | "motorcycle" => [20, 160, 60],
        _ => [150, 60, 180],
    }
}

impl DetectionsSink {
    fn picture(
        &mut self,
        frame: &SensorFrame,
        detections: &FrameDetections,
        seq: u64,
    ) -> Result<(), NodeError> {
        let points: Vec<[f32; 2]> = frame
            .lidar
            .ego_points()
            .iter()
            .map(|p| [p[0], p[1]])
            .collect();
        let mut lines = Vec::new();
        let shown: Vec<_> = detections
            .agents
            .iter()
            .filter(|a| a.score >= self.params.picture_min_score)
            .collect();
        for agent in &shown {
            let (s, c) = agent.yaw.sin_cos();
            let (half_w, half_l) = (agent.size[0] / 2.0, agent.size[1] / 2.0);
            let corner = |l: f64, w: f64| {
                [
                    (agent.centre[0] + c * l - s * w) as f32,
                    (agent.centre[1] + s * l + c * w) as f32,
                ]
            };
            let colour = class_colour(&agent.detection_name);
            lines.push(Polyline {
                points: vec![
                    corner(half_l, half_w),
                    corner(half_l, -half_w),
                    corner(-half_l, -half_w),
                    corner(-half_l, half_w),
                ],
                colour,
                closed: true,
            });
            if let Some(best) = agent.modes.first() {
                let mut path = vec![[agent.centre[0] as f32, agent.centre[1] as f32]];
                path.extend(best.positions.iter().map(|p| [p[0] as f32, p[1] as f32]));
                lines.push(Polyline {
                    points: path,
                    colour: [240, 150, 0],
                    closed: false,
                });
            }
        }
        let image = top_down_with_lines(
            640,
            self.params.half_extent_m,
            &format!(
                "{} of {} detections (score >= {}), best trajectory over {:.1} s",
                shown.len(),
                detections.agents.len(),
                self.params.picture_min_score,
                detections.interval_s
                    * detections
                        .agents
                        .first()
                        .map_or(0, |a| a.modes.first().map_or(0, |m| m.positions.len()))
                        as f64
            ),
            &[Cloud {
                label: "sweep",
                points: &points,
                colour: [150, 150, 150],
            }],
            &lines,
        );
        let path = self
            .params
            .out
            .join(format!("{seq:06}"))
            .join("detections.png");
        self.writes.write(path, png(&image, "detections")?)
    }
}

impl Sink for DetectionsSink {
    fn start(&mut self) -> Result<(), NodeError> {
        self._claim = Some(FolderClaim::acquire(&self.params.out).map_err(NodeError::fatal)?);
        Ok(())
    }

    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let detections = inputs.get(&DETECTIONS)?;
        let frame = inputs.get(&FRAME)?;
        if frame.frame_token != detections.meta.frame_token {
            return Err(NodeError::fatal(format!(
                "the detections belong to frame {}, not to frame {}: connect `frame` to the source the detector's features came from",
                detections.meta.frame_token, frame.frame_token
            )));
        }
        let seq = inputs.header().map_or(0, |h| h.seq);
        self.frames += 1;
        self.interval_s = detections.interval_s;
        if self.params.pictures {
            self.picture(frame, detections, seq)?;
        }
        let meta = &detections.meta;
        if !meta.keyframe || meta.sample_token.is_empty() {
            return Ok(());
        }
        let boxes = detections
            .agents
            .iter()
            .map(|a| a.to_detection(&meta.sample_token, &meta.global_from_ego))
            .collect();
        let trajectories = detections
            .agents
            .iter()
            .map(|a| Trajectories {
                detection_name: a.detection_name.clone(),
                detection_score: a.score,
                modes: a
                    .modes
                    .iter()
                    .map(|m| Mode {
                        probability: m.probability,
                        positions: m
                            .positions
                            .iter()
                            .map(|p| {
                                let g = meta
                                    .global_from_ego
                                    .transform_point3(DVec3::new(p[0], p[1], 0.0));
                                [g.x, g.y]
                            })
                            .collect(),
                    })
                    .collect(),
            })
            .collect();
        self.results.insert(meta.sample_token.clone(), boxes);
        self.trajectories
            .insert(meta.sample_token.clone(), trajectories);
        Ok(())
    }

    fn finish(&mut self) -> Result<(), NodeError> {
        let results = DetectionResults {
            meta: SubmissionMeta {
                use_camera: self.params.use_camera,
                use_lidar: true,
                ..Default::default()
            },
            results: std::mem::take(&mut self.results),
        };
        self.writes.write(
            self.params.out.join("results_nusc.json"),
            json_bytes(&results, "results_nusc.json")?,
        )?;
        let trajectories = serde_json::json!({
            "interval_s": self.interval_s,
            "frame": "global",
            "samples": &self.trajectories,
        });
        self.writes.write(
            self.params.out.join("trajectories.json"),
            json_bytes(&trajectories, "trajectories.json")?,
        )?;
        self.writes.flush()
    }

    fn report(&self) -> Figures {
        Figures::from([
            ("frames".to_string(), self.frames as f64),
            ("samples".to_string(), self.trajectories.len() as f64),
        ])
    }
}

/// JSON bytes of a file, named in the error.
fn json_bytes<T: Serialize>(value: &T, name: &str) -> Result<Vec<u8>, NodeError> {
    serde_json::to_vec_pretty(value).map_err(|error| NodeError::fatal(format!("{name}: {error}")))
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::sink(
            "detections_sink",
            "a detector's boxes as results_nusc.json (keyframes, the nuScenes submission format), their trajectories as trajectories.json, and a top-down picture per frame",
        )
        .input(DETECTIONS.spec())
        .input(FRAME.spec()),
        |params: &DetectionsSinkParams| {
            if params.out.as_os_str().is_empty() {
                return Err(ParamError::field("out", "is empty").with_accepted("an output folder"));
            }
            if !(params.half_extent_m.is_finite() && params.half_extent_m > 0.0) {
                return Err(ParamError::field("half_extent_m", "must be a number > 0"));
            }
            if !(0.0..=1.0).contains(&params.picture_min_score) {
                return Err(ParamError::field("picture_min_score", "must lie in [0, 1]"));
            }
            Ok(())
        },
        |params: DetectionsSinkParams| {
            let writes = Writes::new(params.out.clone(), 8);
            Ok(Node::Sink(Box::new(DetectionsSink {
                params,
                writes,
                results: BTreeMap::new(),
                trajectories: BTreeMap::new(),
                interval_s: 0.0,
                frames: 0,
                _claim: None,
            })))
        },
    );
}
