//! What flows through the forecast graph: a history of latents ready to forecast from, the
//! forecast made from it, each future latent paired with the rays to render it along, and
//! its renders. The world model's nodes make the first three; the renderer, the writer and
//! the metrics read them, so they live here, with the other shared types.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::action::EgoAction;
use crate::bev::{BevFeatures, FrameMeta};
use crate::camera::ImageSet;
use crate::frame::SensorFrame;
use crate::point_cloud::PointCloud;
use crate::pose::Pose;

/// One frame the log recorded after a window's current frame: when, and where the ego was.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoggedPose {
    pub time_of_validity_us: i64,
    pub global_from_ego: Pose,
}

/// The latents a forecast conditions on, oldest first (the last is the current frame), with
/// the ego's motion into each, and, when replaying a log, the poses of the frames that
/// followed, at the same stride. Nothing else of the future is here.
#[derive(Clone, Debug)]
pub struct LatentWindow {
    pub context: Vec<Arc<BevFeatures>>,
    /// `context_actions[i]` takes the ego from the frame before `context[i]` into it.
    pub context_actions: Vec<EgoAction>,
    /// The logged future, one pose per future frame; empty in live use.
    pub logged_future: Vec<LoggedPose>,
    /// Seconds between the window's frames.
    pub stride_s: f64,
}

impl LatentWindow {
    /// The frame the forecast starts from.
    pub fn current(&self) -> Option<&BevFeatures> {
        self.context.last().map(Arc::as_ref)
    }
}

/// Who made a future latent: the world model, or a baseline it must beat.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ForecastMethod {
    /// The diffusion forecast.
    Model,
    /// The current latent, unchanged.
    LatentCopyLast,
    /// The current latent moved by the ego's motion, as if the world stood still.
    LatentEgoWarp,
    /// The tokenizer's own latent of the true future frame: the floor the tokenizer sets.
    Oracle,
    /// The ego warp with each annotated vehicle's cells carried from its box now to its true
    /// future box (`agent_warp`): what moving the agents as rigid latent patches can reach.
    /// It reads the future's annotations, so it is a bound, not a forecast; it is rendered only
    /// when asked for (`methods`).
    LatentBoxWarp,
    /// The model's forecast with the detected agents carried along the trajectories a motion
    /// head predicts for them (`move_agents`).
    ModelWithAgents,
}

impl ForecastMethod {
    pub const ALL: [ForecastMethod; 6] = [
        ForecastMethod::Model,
        ForecastMethod::ModelWithAgents,
        ForecastMethod::LatentCopyLast,
        ForecastMethod::LatentEgoWarp,
        ForecastMethod::Oracle,
        ForecastMethod::LatentBoxWarp,
    ];

    /// What a forecast graph renders unless told otherwise: the model and the baselines that
    /// need no annotations beyond the truth they are scored against.
    pub const DEFAULT: [ForecastMethod; 4] = [
        ForecastMethod::Model,
        ForecastMethod::LatentCopyLast,
        ForecastMethod::LatentEgoWarp,
        ForecastMethod::Oracle,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ForecastMethod::Model => "model",
            ForecastMethod::LatentCopyLast => "latent_copy_last",
            ForecastMethod::LatentEgoWarp => "latent_ego_warp",
            ForecastMethod::Oracle => "oracle",
            ForecastMethod::LatentBoxWarp => "latent_box_warp",
            ForecastMethod::ModelWithAgents => "model_with_agents",
        }
    }

    /// Whether it forecasts (the model, with or without its agents carried), as opposed to a
    /// baseline, which is worth rendering only beside a truth.
    pub fn is_forecast(self) -> bool {
        matches!(
            self,
            ForecastMethod::Model | ForecastMethod::ModelWithAgents
        )
    }

    pub fn parse(text: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == text)
    }
}

/// The latents of one forecast horizon. Each `BevFeatures` lies over the predicted future ego
/// frame: its `meta` holds the future time of validity and the predicted `global_from_ego`
/// (the current pose moved by the actions the forecast was conditioned on).
#[derive(Clone, Debug)]
pub struct ForecastHorizon {
    pub horizon_s: f64,
    pub frames_ahead: usize,
    pub latents: Vec<(ForecastMethod, Arc<BevFeatures>)>,
    /// The model's further draws from other noise, when the rollout was asked for more than
    /// one sample (`samples: K`): draws 1 to K−1. Draw 0 is the `Model` latent above, the
    /// point forecast every consumer reads.
    pub samples: Vec<Arc<BevFeatures>>,
}

impl ForecastHorizon {
    pub fn latent(&self, method: ForecastMethod) -> Option<&Arc<BevFeatures>> {
        self.latents
            .iter()
            .find(|(m, _)| *m == method)
            .map(|(_, latent)| latent)
    }
}

/// One forecast: from a window's current frame, the requested horizons.
#[derive(Clone, Debug)]
pub struct Forecast {
    /// The current frame the forecast starts from.
    pub context: FrameMeta,
    /// Where the future actions came from: `log`, a manoeuvre's name, or `list`.
    pub actions_from: String,
    /// The actions into each future frame, one per frame up to the model's last.
    pub future_actions: Vec<EgoAction>,
    pub horizons: Vec<ForecastHorizon>,
    /// Milliseconds the sampler took, every draw together.
    pub sampling_ms: f64,
}

impl Forecast {
    /// Whether the future actions are the log's own, so that the logged future is its truth.
    pub fn follows_log(&self) -> bool {
        self.actions_from == "log"
    }
}

/// One future latent to render, with the frame whose rays it is cast along and, when the log
/// recorded the future it forecasts, that frame to score against.
#[derive(Clone, Debug)]
pub struct FutureView {
    pub context: Arc<SensorFrame>,
    pub horizon_s: f64,
    pub frames_ahead: usize,
    /// How many horizons the forecast has, so that a consumer knows when one is complete.
    pub horizons_in_forecast: usize,
    pub method: ForecastMethod,
    /// Which of the model's draws this is: 0 for the point forecast (and for every baseline),
    /// 1 to K−1 for the further draws of `ForecastHorizon::samples`. Consumers that show or
    /// write one forecast read draw 0 only; the metrics score the best of the K.
    pub sample: usize,
    /// How many draws of the model each horizon has (K; 1 without `samples`).
    pub samples_in_forecast: usize,
    pub latent: Arc<BevFeatures>,
    /// The logged future frame (when it is the truth), or the rig at the predicted pose: the
    /// context frame's cameras and beam directions, moved there.
    pub rays: Arc<SensorFrame>,
    pub truth: Option<Arc<SensorFrame>>,
    /// Milliseconds the forecast's sampling took.
    pub sampling_ms: f64,
}

/// A `FutureView` rendered: the images and the sweep along its rays.
#[derive(Clone, Debug)]
pub struct RenderedFuture {
    pub view: Arc<FutureView>,
    pub images: Option<ImageSet>,
    /// In the LiDAR frame of `view.rays`.
    pub lidar: Option<PointCloud>,
    /// Milliseconds the render of this view took (images and sweep).
    pub render_ms: f64,
}

/// The rig of `frame` moved to `global_from_ego` at `time_of_validity_us`: its cameras (with
/// their images, which a render does not read) and its sweep's beams, as if the ego stood
/// there. What a forecast is rendered along when the log has no frame for it.
pub fn virtual_frame(
    frame: &SensorFrame,
    global_from_ego: Pose,
    time_of_validity_us: i64,
    token: String,
) -> SensorFrame {
    let mut cloud = PointCloud::clone(&frame.lidar);
    cloud.global_from_ego = global_from_ego;
    cloud.timestamp_us = time_of_validity_us;
    cloud.source_file = format!("virtual:{}", cloud.source_file);
    let cameras = frame
        .cameras
        .iter()
        .map(|camera| {
            let mut camera = camera.clone();
            camera.global_from_ego = global_from_ego;
            camera.timestamp_us = time_of_validity_us;
            camera
        })
        .collect();
    SensorFrame {
        time_of_validity_us,
        sample_token: token.clone(),
        frame_token: token,
        scene_name: frame.scene_name.clone(),
        index_in_scene: frame.index_in_scene,
        // A predicted frame is no dataset's sample.
        keyframe: false,
        global_from_ego,
        cameras,
        lidar: Arc::new(cloud),
        action: None,
        // A predicted pose has no annotation: what would have been there is not known.
        boxes: Vec::new(),
    }
}
