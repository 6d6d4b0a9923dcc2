//! `future_views`: pairs each future latent of a forecast with the frame it is rendered
//! along and, when the log recorded that future, with the truth it is scored against.
//!
//! - A forecast made with the log's own actions is rendered along the logged future frame's
//!   rays (the 4D-Occ protocol: its own LiDAR beams, its cameras) and scored against it.
//! - Any other forecast, or one whose future the log does not hold, is rendered along the rig
//!   at the predicted pose: the context frame's cameras and beam directions moved there
//!   (`virtual_frame`). It has no truth.
//! - `oracle` views carry the tokenizer's latent of the true future frame (from `latent`).
//! - Baselines are rendered only where there is a truth to score them against.
//! - `latent_box_warp` views (asked for in `methods`) carry the ego-warped latent with each
//!   annotated vehicle moved from its box in the context frame to its box in the true future
//!   frame (`bevworld_types::agent_warp`): a bound that reads the truth, never a forecast.
//! - A forecast with several draws of the model (`diffusion_rollout`'s `samples`) gives one
//!   `model` view per draw, numbered by `sample`, the point forecast first.
//!
//! It sees the frames only after the forecast is made, so the forecast cannot depend on them.
//! Frames are held from the oldest context still waiting onwards, never more than
//! `max_frames`.

use std::collections::VecDeque;
use std::sync::Arc;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, Outputs, ParamError, Port, Registry, SyncMode, Task,
};
use bevworld_types::forecast::ForecastHorizon;
use bevworld_types::object_box::ObjectBox;
use bevworld_types::{
    AgentMotion, BevFeatures, Footprint, Forecast, ForecastMethod, FutureView, LatentGrid,
    PlanarMotion, SensorFrame, move_agents, virtual_frame,
};
use glam::DVec3;
use serde::{Deserialize, Serialize};

// The node's ports, each named once (`bevworld_graph::Port`).
const FORECAST: Port<Forecast> = Port::new("forecast");
const FRAME: Port<SensorFrame> = Port::new("frame");
const LATENT: Port<BevFeatures> = Port::new("latent");
const VIEW: Port<FutureView> = Port::new("view");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FutureViewsParams {
    /// What to render: `model`, `latent_copy_last`, `latent_ego_warp`, `oracle`, and on request
    /// `latent_box_warp`.
    #[serde(default = "default_methods")]
    pub methods: Vec<String>,
    /// How far around a vehicle's box `latent_box_warp` carries its cells, in metres.
    #[serde(default = "default_box_margin")]
    pub box_margin_m: f64,
    /// Where `latent_box_warp` carries each vehicle: to its box in the true future frame
    /// (`future_box`), or along its annotated velocity from its box now (`velocity`: what a
    /// perfect detector's constant-velocity motion reaches).
    #[serde(default)]
    pub box_motion: BoxMotion,
    /// What `latent_box_warp` carries the vehicles on: the latent ego warp (`latent_ego_warp`:
    /// the bound of moving agents alone) or the model's forecast (`model`: what the agent
    /// layer, `move_agents`, would give with a perfect motion head).
    #[serde(default)]
    pub box_base: BoxBase,
    /// How far a logged frame's time may lie from a forecast's, in seconds.
    #[serde(default = "default_tolerance")]
    pub tolerance_s: f64,
    /// Most frames (and latents) held while forecasts wait for their futures.
    #[serde(default = "default_max_frames")]
    pub max_frames: usize,
}

fn default_methods() -> Vec<String> {
    ForecastMethod::DEFAULT
        .iter()
        .map(|m| m.name().to_string())
        .collect()
}
/// Where `latent_box_warp` takes each vehicle's future footprint from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BoxMotion {
    /// Its box in the true future frame (same instance).
    #[default]
    FutureBox,
    /// Its box now, moved by its annotated velocity for the horizon, heading kept.
    Velocity,
}

/// The latent `latent_box_warp` moves the vehicles on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BoxBase {
    #[default]
    LatentEgoWarp,
    Model,
}

fn default_box_margin() -> f64 {
    1.25
}
fn default_tolerance() -> f64 {
    0.05
}
fn default_max_frames() -> usize {
    256
}

/// Items of one stream in arrival order: scene by scene, each in time order.
struct Held<T> {
    items: VecDeque<Arc<T>>,
    evicted: u64,
}

trait Timed {
    fn scene(&self) -> &str;
    fn time_us(&self) -> i64;
}
impl Timed for SensorFrame {
    fn scene(&self) -> &str {
        &self.scene_name
    }
    fn time_us(&self) -> i64 {
        self.time_of_validity_us
    }
}
impl Timed for BevFeatures {
    fn scene(&self) -> &str {
        &self.meta.scene_name
    }
    fn time_us(&self) -> i64 {
        self.meta.time_of_validity_us
    }
}

/// What a stream says of a time: it holds an item there, it has passed it without one, or it
/// may still bring one.
enum Lookup<T> {
    Found(Arc<T>),
    Missing,
    Waiting,
}

impl<T: Timed> Held<T> {
    fn new() -> Self {
        Self {
            items: VecDeque::new(),
            evicted: 0,
        }
    }

    fn push(&mut self, item: Arc<T>, max: usize) {
        self.items.push_back(item);
        while self.items.len() > max {
            self.items.pop_front();
            self.evicted += 1;
        }
    }

    fn lookup(&self, scene: &str, time_us: i64, tolerance_us: i64, closed: bool) -> Lookup<T> {
        if let Some(item) = self
            .items
            .iter()
            .find(|i| i.scene() == scene && (i.time_us() - time_us).abs() <= tolerance_us)
        {
            return Lookup::Found(Arc::clone(item));
        }
        let passed = self
            .items
            .back()
            .is_some_and(|last| last.scene() != scene || last.time_us() > time_us + tolerance_us);
        if passed || closed {
            Lookup::Missing
        } else {
            Lookup::Waiting
        }
    }

    /// Drops what lies before `time_us` of `scene` (and every earlier scene).
    fn forget_before(&mut self, scene: &str, time_us: i64, tolerance_us: i64) {
        while self
            .items
            .front()
            .is_some_and(|i| i.scene() != scene || i.time_us() < time_us - tolerance_us)
        {
            // Items of a later scene than `scene` cannot be at the front while `scene`'s are
            // still held behind them, since streams arrive scene by scene.
            if self.items.iter().all(|i| i.scene() != scene) {
                break;
            }
            self.items.pop_front();
        }
    }
}

pub struct FutureViews {
    methods: Vec<ForecastMethod>,
    box_margin_m: f64,
    box_motion: BoxMotion,
    box_base: BoxBase,
    tolerance_us: i64,
    max_frames: usize,
    frames: Held<SensorFrame>,
    latents: Held<BevFeatures>,
    pending: VecDeque<Forecast>,
    pub views: u64,
    /// Horizons of forecasts along the log that the log does not reach.
    pub horizons_without_truth: u64,
    pub contexts_missing: u64,
}

impl FutureViews {
    pub fn new(methods: Vec<ForecastMethod>, tolerance_s: f64, max_frames: usize) -> Self {
        Self {
            methods,
            box_margin_m: default_box_margin(),
            box_motion: BoxMotion::default(),
            box_base: BoxBase::default(),
            tolerance_us: (tolerance_s * 1e6).round() as i64,
            max_frames,
            frames: Held::new(),
            latents: Held::new(),
            pending: VecDeque::new(),
            views: 0,
            horizons_without_truth: 0,
            contexts_missing: 0,
        }
    }

    /// How far around a vehicle's box `latent_box_warp` carries its cells (metres), where it
    /// carries them, and on what.
    pub fn with_box_warp(mut self, margin_m: f64, motion: BoxMotion, base: BoxBase) -> Self {
        self.box_margin_m = margin_m;
        self.box_motion = motion;
        self.box_base = base;
        self
    }

    pub fn push_frame(&mut self, frame: Arc<SensorFrame>) {
        self.frames.push(frame, self.max_frames);
    }

    pub fn push_latent(&mut self, latent: Arc<BevFeatures>) {
        if self.methods.contains(&ForecastMethod::Oracle) {
            self.latents.push(latent, self.max_frames);
        }
    }

    pub fn push_forecast(&mut self, forecast: Forecast) {
        self.pending.push_back(forecast);
        while self.pending.len() > self.max_frames {
            self.pending.pop_front();
            self.contexts_missing += 1;
        }
    }

    /// The views of every forecast whose future is settled, in order; with `closed`, no more
    /// frames or latents will come.
    pub fn ready(&mut self, closed: bool) -> Vec<FutureView> {
        let mut views = Vec::new();
        while let Some(forecast) = self.pending.front() {
            let Some(resolved) = self.resolve(forecast, closed) else {
                break;
            };
            let (scene, time) = (
                forecast.context.scene_name.clone(),
                forecast.context.time_of_validity_us,
            );
            self.pending.pop_front();
            match resolved {
                Some((mut resolved, without_truth)) => {
                    views.append(&mut resolved);
                    self.horizons_without_truth += without_truth;
                }
                None => self.contexts_missing += 1,
            }
            self.frames.forget_before(&scene, time, self.tolerance_us);
            self.latents.forget_before(&scene, time, self.tolerance_us);
        }
        self.views += views.len() as u64;
        views
    }

    /// `None` while waiting; `Some(None)` when the context frame never came; else the views
    /// and how many horizons have no truth.
    #[allow(clippy::type_complexity)]
    fn resolve(&self, forecast: &Forecast, closed: bool) -> Option<Option<(Vec<FutureView>, u64)>> {
        let scene = forecast.context.scene_name.as_str();
        let tol = self.tolerance_us;
        let context =
            match self
                .frames
                .lookup(scene, forecast.context.time_of_validity_us, tol, closed)
            {
                Lookup::Found(frame) => frame,
                Lookup::Missing => return Some(None),
                Lookup::Waiting => return None,
            };
        let mut settled = Vec::new();
        for horizon in &forecast.horizons {
            let Some((_, model)) = horizon.latents.first() else {
                continue;
            };
            let time = model.meta.time_of_validity_us;
            let truth = if forecast.follows_log() {
                match self.frames.lookup(scene, time, tol, closed) {
                    Lookup::Found(frame) => Some(frame),
                    Lookup::Missing => None,
                    Lookup::Waiting => return None,
                }
            } else {
                None
            };
            let oracle = match (&truth, self.methods.contains(&ForecastMethod::Oracle)) {
                (Some(_), true) => match self.latents.lookup(scene, time, tol, closed) {
                    Lookup::Found(latent) => Some(latent),
                    Lookup::Missing => None,
                    Lookup::Waiting => return None,
                },
                _ => None,
            };
            settled.push((horizon, truth, oracle));
        }
        let total = forecast.horizons.len();
        let mut views = Vec::new();
        let mut without_truth = 0;
        for (horizon, truth, oracle) in settled {
            // A manoeuvre has no truth by design; a replay whose log ends too soon is worth
            // saying.
            if truth.is_none() && forecast.follows_log() {
                without_truth += 1;
            }
            for &method in &self.methods {
                // A baseline is rendered to be scored; without a truth only the forecast is,
                // unless the graph asks for the baseline alone (to compare it as a forecast).
                if truth.is_none()
                    && !method.is_forecast()
                    && self.methods.contains(&ForecastMethod::Model)
                {
                    continue;
                }
                let latent = match method {
                    ForecastMethod::Oracle => oracle.clone(),
                    ForecastMethod::LatentBoxWarp => match &truth {
                        Some(truth) => box_warp(
                            forecast,
                            horizon,
                            &context,
                            truth,
                            self.box_margin_m,
                            self.box_motion,
                            self.box_base,
                        ),
                        None => None,
                    },
                    other => horizon.latent(other).cloned(),
                };
                let Some(latent) = latent else { continue };
                let model = horizon.latent(ForecastMethod::Model).unwrap_or(&latent);
                let rays = match &truth {
                    Some(frame) => Arc::clone(frame),
                    None => Arc::new(virtual_frame(
                        &context,
                        model.meta.global_from_ego,
                        model.meta.time_of_validity_us,
                        model.meta.frame_token.clone(),
                    )),
                };
                // The model's further draws follow its point forecast, along the same rays.
                let draws: Vec<Arc<BevFeatures>> = match method {
                    ForecastMethod::Model => std::iter::once(latent)
                        .chain(horizon.samples.iter().cloned())
                        .collect(),
                    _ => vec![latent],
                };
                let samples_in_forecast = 1 + horizon.samples.len();
                for (sample, latent) in draws.into_iter().enumerate() {
                    views.push(FutureView {
                        context: Arc::clone(&context),
                        horizon_s: horizon.horizon_s,
                        frames_ahead: horizon.frames_ahead,
                        horizons_in_forecast: total,
                        method,
                        sample,
                        samples_in_forecast,
                        latent,
                        rays: Arc::clone(&rays),
                        truth: truth.clone(),
                        sampling_ms: forecast.sampling_ms,
                    });
                }
            }
        }
        Some(Some((views, without_truth)))
    }
}

/// The ego-warped latent of a horizon with every annotated vehicle of the context frame carried
/// to its future footprint (`motion`: its box in the true future frame, when that frame holds
/// it, or its box moved by its velocity), all footprints in the context's ego frame, on `base`.
/// `None` without the rollout's baselines (the current latent and its ego warp).
#[allow(clippy::too_many_arguments)]
fn box_warp(
    forecast: &Forecast,
    horizon: &ForecastHorizon,
    context: &SensorFrame,
    truth: &SensorFrame,
    margin_m: f64,
    motion: BoxMotion,
    base: BoxBase,
) -> Option<Arc<BevFeatures>> {
    let current = horizon.latent(ForecastMethod::LatentCopyLast)?;
    let warped = horizon.latent(match base {
        BoxBase::LatentEgoWarp => ForecastMethod::LatentEgoWarp,
        BoxBase::Model => ForecastMethod::Model,
    })?;
    let global_from_current = forecast.context.global_from_ego;
    let current_from_global = global_from_current.inverse();
    let footprint = |object: &ObjectBox| Footprint::of_box(&object.moved(&current_from_global));
    let agents: Vec<AgentMotion> = context
        .boxes
        .iter()
        .filter(|b| b.is_vehicle())
        .filter_map(|now| {
            let then = match motion {
                BoxMotion::FutureBox => footprint(
                    truth
                        .boxes
                        .iter()
                        .find(|b| b.instance_token == now.instance_token)?,
                ),
                BoxMotion::Velocity => {
                    let seconds =
                        (truth.time_of_validity_us - context.time_of_validity_us) as f64 * 1e-6;
                    let [vx, vy] = now.velocity.unwrap_or([0.0, 0.0]);
                    let step = current_from_global.transform_vector3(DVec3::new(
                        vx * seconds,
                        vy * seconds,
                        0.0,
                    ));
                    let now = footprint(now);
                    Footprint {
                        centre: [now.centre[0] + step.x, now.centre[1] + step.y],
                        ..now
                    }
                }
            };
            Some(AgentMotion {
                now: footprint(now),
                then,
            })
        })
        .collect();
    let grid = LatentGrid::of(&current.grid, current.channels.len());
    let current_from_future =
        PlanarMotion::between(&global_from_current, &warped.meta.global_from_ego);
    let data = move_agents(
        &current.data,
        &warped.data,
        &grid,
        &current_from_future,
        &agents,
        margin_m,
    );
    Some(Arc::new(BevFeatures {
        data,
        ..BevFeatures::clone(warped)
    }))
}

pub struct FutureViewsNode {
    views: FutureViews,
}

impl FutureViewsNode {
    fn send(views: Vec<FutureView>, out: &mut Outputs) -> Result<(), NodeError> {
        for view in views {
            out.set_time_of_validity(view.latent.meta.time_of_validity_us);
            out.send(&VIEW, view)?;
        }
        Ok(())
    }
}

impl Task for FutureViewsNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        if inputs.message(FRAME.name).is_some() {
            self.views.push_frame(inputs.shared(&FRAME)?);
        }
        if inputs.message(LATENT.name).is_some() {
            self.views.push_latent(inputs.shared(&LATENT)?);
        }
        if inputs.message(FORECAST.name).is_some() {
            self.views.push_forecast(inputs.get(&FORECAST)?.clone());
        }
        Self::send(self.views.ready(false), out)
    }

    fn finish(&mut self, out: &mut Outputs) -> Result<(), NodeError> {
        let views = self.views.ready(true);
        if self.views.horizons_without_truth > 0 {
            tracing::warn!(
                horizons = self.views.horizons_without_truth,
                "replayed forecast horizons past the end of the log: rendered from the predicted pose, not scored"
            );
        }
        Self::send(views, out)
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        figures.insert("views".into(), self.views.views as f64);
        figures.insert(
            "horizons_without_truth".into(),
            self.views.horizons_without_truth as f64,
        );
        figures.insert(
            "contexts_missing".into(),
            self.views.contexts_missing as f64,
        );
        figures.insert("frames_evicted".into(), self.views.frames.evicted as f64);
        figures
    }
}

fn methods(params: &FutureViewsParams) -> Result<Vec<ForecastMethod>, ParamError> {
    let accepted = || {
        ForecastMethod::ALL
            .iter()
            .map(|m| m.name())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut methods = Vec::new();
    for name in &params.methods {
        let method = ForecastMethod::parse(name).ok_or_else(|| {
            ParamError::field("methods", format!("unknown method '{name}'"))
                .with_accepted(accepted())
        })?;
        if !methods.contains(&method) {
            methods.push(method);
        }
    }
    if methods.is_empty() {
        return Err(ParamError::field("methods", "is empty").with_accepted(accepted()));
    }
    if !(params.tolerance_s.is_finite() && params.tolerance_s >= 0.0 && params.tolerance_s < 1.0) {
        return Err(ParamError::field(
            "tolerance_s",
            format!("{} must lie in [0, 1) s", params.tolerance_s),
        ));
    }
    if !(params.box_margin_m.is_finite() && (0.0..=10.0).contains(&params.box_margin_m)) {
        return Err(ParamError::field(
            "box_margin_m",
            format!("{} must lie in [0, 10] m", params.box_margin_m),
        ));
    }
    if params.max_frames == 0 || params.max_frames > 100_000 {
        return Err(ParamError::field(
            "max_frames",
            format!("{} must lie in 1..=100000", params.max_frames),
        ));
    }
    Ok(methods)
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::task(
            "future_views",
            "each forecast latent with the rays to render it along (the logged future frame, or the rig at the predicted pose) and its truth",
        )
        .input(FORECAST.spec())
        .input(FRAME.spec())
        .input(LATENT.optional())
        .output(VIEW.spec())
        .sync(SyncMode::Any),
        |params: &FutureViewsParams| methods(params).map(|_| ()),
        |params: FutureViewsParams| {
            Ok(Node::Task(Box::new(FutureViewsNode {
                views: FutureViews::new(methods(&params)?, params.tolerance_s, params.max_frames)
                    .with_box_warp(params.box_margin_m, params.box_motion, params.box_base),
            })))
        },
    );
}
