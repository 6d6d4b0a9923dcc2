//! `detect`: a trained detector on a graph's BEV features, one message of boxes and
//! trajectories per frame (`FrameDetections`).
//!
//! - The detector reads only the features it was trained on: a map made by another model or
//!   other weights (the encoder's digest), on another grid or with other channels, is refused
//!   at the first frame, naming both digests.
//! - A two-frame detector keeps each scene's recent maps and takes the one nearest
//!   `PREVIOUS_FRAME_S` before the current frame (within a fifth of it) as its previous frame,
//!   so replay at 12 Hz and keyframes at 2 Hz both give it what it trained on; without one (a
//!   scene's first half second) it reads the current map twice.
//! - A frame with nothing to detect gives an empty message, not an error.

use std::collections::VecDeque;
use std::path::PathBuf;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, Outputs, ParamError, Port, Registry, Task,
};
use bevworld_types::{BevFeatures, FrameDetections};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::decode::FrameMaps;
use crate::input::PosedMap;
use crate::weights::{DetectorWeights, load_detector, load_meta};

const FEATURES: Port<BevFeatures> = Port::new("features");
const DETECTIONS: Port<FrameDetections> = Port::new("detections");

/// How far before the current frame a two-frame detector's previous frame lies: the keyframes'
/// interval it was trained on (nuScenes keyframes, 2 Hz).
pub const PREVIOUS_FRAME_S: f64 = 0.5;

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DetectParams {
    /// The detector's weights (`detector.bpk`, its `.meta.json` beside it).
    pub weights: PathBuf,
}

struct DetectNode {
    detector: DetectorWeights,
    device: Device,
    /// The current scene's maps of the last `PREVIOUS_FRAME_S` and a little more, oldest first.
    history: VecDeque<std::sync::Arc<BevFeatures>>,
    frames: u64,
    agents: u64,
}

impl DetectNode {
    fn check(&self, features: &BevFeatures) -> Result<(), NodeError> {
        self.detector
            .check_features(&features.model, &features.weights_hash)
            .map_err(|error| NodeError::fatal(error.to_string()))?;
        let input = &self.detector.meta.input;
        if features.grid != input.grid || features.channels.len() != input.channels {
            return Err(NodeError::fatal(format!(
                "{}: the detector reads {} channels on {:?}, but frame {} has {} channels on {:?}",
                self.detector.path.display(),
                input.channels,
                input.grid,
                features.meta.frame_token,
                features.channels.len(),
                features.grid
            )));
        }
        Ok(())
    }

    /// The scene's map nearest `PREVIOUS_FRAME_S` before `now`, within a fifth of it.
    fn previous(&self, now: &BevFeatures) -> Option<&BevFeatures> {
        let wanted = now.meta.time_of_validity_us as f64 - PREVIOUS_FRAME_S * 1e6;
        self.history
            .iter()
            .map(|f| (f, (f.meta.time_of_validity_us as f64 - wanted).abs()))
            .filter(|(_, gap)| *gap <= 0.2 * PREVIOUS_FRAME_S * 1e6)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(f, _)| f.as_ref())
    }
}

impl Task for DetectNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let features = inputs.shared(&FEATURES)?;
        self.check(&features)?;
        if self
            .history
            .back()
            .is_some_and(|last| last.meta.scene_name != features.meta.scene_name)
        {
            self.history.clear();
        }
        let meta = &self.detector.meta;
        let input = &meta.input;
        let current = PosedMap {
            values: &features.data,
            global_from_ego: features.meta.global_from_ego,
        };
        let previous = (input.frames > 1)
            .then(|| self.previous(&features))
            .flatten()
            .map(|f| PosedMap {
                values: &f.data,
                global_from_ego: f.meta.global_from_ego,
            });
        let values = input
            .assemble(&current, previous.as_ref())
            .map_err(|e| NodeError::item(format!("{}: {e}", features.meta.frame_token)))?;
        let tensor = Tensor::<4>::from_data(
            TensorData::new(
                values,
                [
                    1,
                    input.channels * input.frames,
                    input.grid.height,
                    input.grid.width,
                ],
            ),
            &self.device,
        );
        let outputs = self.detector.model.forward(tensor);
        let read = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap_or_default();
        let (heatmap, boxes, motion) = (
            read(outputs.heatmap),
            read(outputs.boxes),
            read(outputs.motion),
        );
        let agents = meta.config.decode(
            &meta.config.output_grid(input),
            &FrameMaps {
                heatmap: &heatmap,
                boxes: &boxes,
                motion: &motion,
            },
        );
        self.frames += 1;
        self.agents += agents.len() as u64;
        // Keep a little more than the previous frame's distance.
        let oldest = features.meta.time_of_validity_us - (1.5 * PREVIOUS_FRAME_S * 1e6) as i64;
        while self
            .history
            .front()
            .is_some_and(|f| f.meta.time_of_validity_us < oldest)
        {
            self.history.pop_front();
        }
        if input.frames > 1 {
            self.history.push_back(features.clone());
        }
        out.send(
            &DETECTIONS,
            FrameDetections {
                meta: features.meta.clone(),
                agents,
                interval_s: meta.config.motion.interval_s,
                model: meta.config.name.clone(),
                weights_hash: meta.weights_hash.clone(),
            },
        )
    }

    fn report(&self) -> Figures {
        Figures::from([
            ("frames".to_string(), self.frames as f64),
            ("agents".to_string(), self.agents as f64),
        ])
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::task(
            "detect",
            "a trained detector (bevworld train detector) on BEV features: 3D boxes with class, score, velocity and K trajectory modes per frame",
        )
        .input(FEATURES.spec())
        .output(DETECTIONS.spec()),
        |params: &DetectParams| {
            load_meta(&params.weights)
                .map(|_| ())
                .map_err(|error| ParamError::field("weights", error.to_string()))
        },
        |params: DetectParams| {
            let (_, device) = bevworld_device::from_env().map_err(|error| {
                ParamError::field("weights", format!("no device to run it on: {error}"))
            })?;
            let detector = load_detector(&params.weights, &device)
                .map_err(|error| ParamError::field("weights", error.to_string()))?;
            Ok(Node::Task(Box::new(DetectNode {
                detector,
                device,
                history: VecDeque::new(),
                frames: 0,
                agents: 0,
            })))
        },
    );
}
