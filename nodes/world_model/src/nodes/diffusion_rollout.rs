//! `diffusion_rollout`: from a window of past latents, the world model's forecast of the next
//! N, of which it emits the requested horizons. Each future latent is a `BevFeatures` over
//! the predicted future ego frame: the current pose moved by the actions it was conditioned
//! on, at the future time of validity.
//!
//! The future actions are the log's (`actions: log`, replay), a manoeuvre from the current
//! motion (`keep`, the default since live use has no logged future; `left`, `right`,
//! `faster`, `slower`, `stop`: `Manoeuvre`), or an explicit list of speeds and yaw rates
//! (`actions: list`, `action_list`). With `baselines`, the latent baselines ride along: the
//! current latent as it is (`latent_copy_last`) and moved by the same actions
//! (`latent_ego_warp`).

use std::sync::Arc;
use std::time::Instant;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Models, Node, NodeError, Outputs, ParamError, Port, Registry, Task,
};
use bevworld_types::{
    BevFeatures, EgoAction, Forecast, ForecastHorizon, ForecastMethod, FrameMeta, LatentWindow,
    Pose,
};
use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::config::WorldModelConfig;
use crate::ddim::{DdimConfig, DdimError, Spacing};
use crate::ego_warp::PlanarMotion;
use crate::forecast::draw_seed;
use crate::manoeuvre::{Manoeuvre, constant_turn, current_motion};
use crate::nodes::model_params::WorldModelParams;
use crate::rollout::{LoadedWorldModel, Rollout};
use crate::shrink::ResidualShrink;

// The node's ports, each named once (`bevworld_graph::Port`).
const WINDOW: Port<LatentWindow> = Port::new("window");
const FORECAST: Port<Forecast> = Port::new("forecast");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DiffusionRolloutParams {
    /// The bundle of the graph's `models:` section whose world model (and whose tokenizer's
    /// latent statistics) the rollout runs.
    #[serde(flatten)]
    pub model: WorldModelParams,
    /// Horizons to emit, in seconds: multiples of the model's frame interval up to its last
    /// future frame.
    pub horizons: Vec<f64>,
    /// DDIM steps, η and the noise seed.
    #[serde(default = "one")]
    pub steps: usize,
    #[serde(default)]
    pub eta: f64,
    #[serde(default)]
    pub spacing: Spacing,
    #[serde(default)]
    pub seed: u64,
    /// Draws of the model per forecast, K: the point forecast (from `seed`) and K − 1 more
    /// from other noise (`draw_seed`), for the metrics' best of K. Each draw costs a whole
    /// sampling run; the render and the metrics then see K model views per horizon.
    #[serde(default = "one")]
    pub samples: usize,
    /// Soft-threshold the sampled residual over the ego warp, `{tau, fade_s}`
    /// (`shrink.rs`): the static world is moved, not re-predicted. Residual models only.
    #[serde(default)]
    pub shrink: Option<ResidualShrink>,
    /// `log`, a manoeuvre (`keep`, `left`, `right`, `faster`, `slower`, `stop`) or `list`.
    #[serde(default = "default_actions")]
    pub actions: String,
    /// With `actions: list`: `[speed m/s, yaw rate rad/s]` for each future frame.
    #[serde(default)]
    pub action_list: Option<Vec<[f64; 2]>>,
    /// Emit the latent baselines (copy-last, ego-warp) with the forecast.
    #[serde(default = "yes")]
    pub baselines: bool,
}

fn one() -> usize {
    1
}
fn yes() -> bool {
    true
}
fn default_actions() -> String {
    "keep".into()
}

/// Where the future actions come from.
#[derive(Clone, Debug, PartialEq)]
pub enum FutureActions {
    Log,
    Manoeuvre(Manoeuvre),
    /// `[speed, yaw rate]` per future frame.
    List(Vec<[f64; 2]>),
}

impl FutureActions {
    pub fn name(&self) -> String {
        match self {
            FutureActions::Log => "log".into(),
            FutureActions::Manoeuvre(m) => m.name().to_string(),
            FutureActions::List(_) => "list".into(),
        }
    }

    /// The actions into each of the `frames` future frames `dt_s` apart.
    pub fn resolve(
        &self,
        window: &LatentWindow,
        frames: usize,
        dt_s: f64,
    ) -> Result<Vec<EgoAction>, String> {
        match self {
            FutureActions::Log => {
                let current = window.current().ok_or("an empty window")?;
                let mut previous = (
                    current.meta.global_from_ego,
                    current.meta.time_of_validity_us,
                );
                let mut actions = Vec::with_capacity(frames);
                for logged in window.logged_future.iter().take(frames) {
                    let action = EgoAction::between(
                        &previous.0,
                        previous.1,
                        &logged.global_from_ego,
                        logged.time_of_validity_us,
                    )
                    .ok_or("the logged future's times do not increase")?;
                    actions.push(action);
                    previous = (logged.global_from_ego, logged.time_of_validity_us);
                }
                // Past the end of the log, the ego keeps its last speed and yaw rate.
                if actions.len() < frames {
                    let last = actions
                        .last()
                        .or(window.context_actions.last())
                        .copied()
                        .unwrap_or_default();
                    let rest = frames - actions.len();
                    actions.extend(Manoeuvre::Keep.actions(&last, rest, dt_s));
                }
                Ok(actions)
            }
            FutureActions::Manoeuvre(manoeuvre) => {
                let current = current_motion(&window.context_actions);
                Ok(manoeuvre.actions(&current, frames, dt_s))
            }
            FutureActions::List(list) => Ok(list
                .iter()
                .map(|&[speed, yaw_rate]| constant_turn(speed, yaw_rate, dt_s))
                .collect()),
        }
    }
}

/// The names `actions` accepts, for its errors.
pub fn accepted_actions() -> String {
    let mut names: Vec<String> = vec!["log".into()];
    names.extend(
        Manoeuvre::ALL
            .iter()
            .map(|m| format!("{m:?}").to_lowercase()),
    );
    names.push("list (with action_list)".into());
    names.join(", ")
}

/// Checked params: the actions, and each horizon's frame count.
pub struct RolloutPlan {
    pub config: WorldModelConfig,
    pub actions: FutureActions,
    pub horizons: Vec<(f64, usize)>,
    pub sampler: DdimConfig,
    /// Draws per forecast (`samples`).
    pub samples: usize,
}

/// Most draws one forecast may ask for: each is a whole sampling run.
pub const MAX_SAMPLES: usize = 64;

pub fn plan(params: &DiffusionRolloutParams, models: &Models) -> Result<RolloutPlan, ParamError> {
    let (config, _) = params.model.check(models)?;
    let n = config.future_frames;
    let interval = config.frame_interval_s;
    let actions = match params.actions.as_str() {
        "log" => FutureActions::Log,
        "list" => {
            let Some(list) = &params.action_list else {
                return Err(ParamError::field(
                    "action_list",
                    format!(
                        "`actions: list` needs `action_list`: {n} pairs [speed m/s, yaw rate rad/s]"
                    ),
                ));
            };
            if list.len() != n || list.iter().flatten().any(|v| !v.is_finite()) {
                return Err(ParamError::field(
                    "action_list",
                    format!(
                        "{} entries; the model forecasts {n} frames, so it needs {n} finite pairs [speed m/s, yaw rate rad/s]",
                        list.len()
                    ),
                ));
            }
            // Unusual actions are forecast and counted; impossible ones are refused here.
            for (k, &[speed, yaw_rate]) in list.iter().enumerate() {
                if let Some(reason) = constant_turn(speed, yaw_rate, interval).impossible() {
                    return Err(ParamError::field(
                        "action_list",
                        format!("entry {k}, [{speed}, {yaw_rate}]: {reason}"),
                    ));
                }
            }
            FutureActions::List(list.clone())
        }
        other => FutureActions::Manoeuvre(Manoeuvre::parse(other).ok_or_else(|| {
            ParamError::field("actions", format!("unknown actions '{other}'"))
                .with_accepted(accepted_actions())
        })?),
    };
    if params.action_list.is_some()
        && actions != FutureActions::List(params.action_list.clone().unwrap_or_default())
    {
        return Err(ParamError::field(
            "action_list",
            "is read only with `actions: list`",
        ));
    }
    if params.horizons.is_empty() {
        return Err(ParamError::field(
            "horizons",
            "is empty: name at least one, e.g. [0.5, 1.0, 3.0]",
        ));
    }
    let mut horizons = Vec::new();
    for &h in &params.horizons {
        let frames = (h / interval).round();
        if !h.is_finite()
            || frames < 1.0
            || (frames * interval - h).abs() > 1e-6
            || frames as usize > n
        {
            return Err(ParamError::field(
                "horizons",
                format!(
                    "{h} s is not a forecast the model makes: it forecasts N = {n} frames {interval} s apart, so a horizon is a multiple of {interval} s up to {} s",
                    n as f64 * interval
                ),
            ));
        }
        // The forecast is the model's frame: a horizon within 1e-6 s of it is that frame,
        // and is named, written and scored as it (0.5000000001 is +0.5s).
        let h = frames * interval;
        if horizons.iter().any(|&(seen, _)| seen == h) {
            return Err(ParamError::field(
                "horizons",
                format!("{h} s is named twice"),
            ));
        }
        horizons.push((h, frames as usize));
    }
    if params.shrink.is_some() && !config.residual_over_ego_warp {
        return Err(ParamError::field(
            "shrink",
            format!(
                "model '{}' predicts latents, not a residual over the ego warp: there is no residual to shrink",
                config.name
            ),
        ));
    }
    if params.samples == 0 || params.samples > MAX_SAMPLES {
        return Err(ParamError::field(
            "samples",
            format!(
                "{} draws per forecast: must be 1 (the point forecast) to {MAX_SAMPLES}",
                params.samples
            ),
        ));
    }
    let sampler = DdimConfig {
        steps: params.steps,
        eta: params.eta,
        spacing: params.spacing,
        seed: params.seed,
        shrink: params.shrink,
    };
    sampler
        .check(&crate::schedule::NoiseSchedule::new(&config.diffusion))
        .map_err(|error| {
            let field = match error {
                DdimError::Steps { .. } => "steps",
                DdimError::Eta(_) => "eta",
                DdimError::Shrink(_) => "shrink",
            };
            ParamError::field(field, error.to_string())
        })?;
    Ok(RolloutPlan {
        config,
        actions,
        horizons,
        sampler,
        samples: params.samples,
    })
}

pub struct DiffusionRolloutNode {
    plan: RolloutPlan,
    /// The graph's world model, shared with any other node of the graph that runs it.
    loaded: Arc<LoadedWorldModel>,
    baselines: bool,
    forecasts: u64,
    sampling_ms: f64,
    /// Forecasts conditioned on an action outside the training range (`outside_training`).
    outside_training: u64,
}

/// `global_from_future = global_from_current · current_from_future`, on the ground plane.
fn moved(global_from_current: &Pose, current_from_future: &PlanarMotion) -> Pose {
    let current_from_future = Pose::from_rotation_translation(
        DQuat::from_rotation_z(current_from_future.yaw),
        DVec3::new(current_from_future.x, current_from_future.y, 0.0),
    );
    *global_from_current * current_from_future
}

impl DiffusionRolloutNode {
    pub fn forecast(&self, window: &LatentWindow) -> Result<Forecast, String> {
        let config = &self.plan.config;
        let n = config.future_frames;
        let current = window.current().ok_or("an empty window")?;
        let future_actions = self
            .plan
            .actions
            .resolve(window, n, config.frame_interval_s)?;
        let rollout = Rollout {
            config,
            ..self.loaded.rollout()
        };
        let context: Vec<Vec<f32>> = window.context.iter().map(|l| l.data.clone()).collect();
        let started = Instant::now();
        let run = |sampler: &DdimConfig| {
            rollout
                .run(&context, &window.context_actions, &future_actions, sampler)
                .map_err(|error| format!("frame {}: {error}", current.meta.frame_token))
        };
        let output = run(&self.plan.sampler)?;
        // The further draws: the same context and actions, other noise.
        let mut draws = Vec::with_capacity(self.plan.samples - 1);
        for draw in 1..self.plan.samples {
            let sampler = DdimConfig {
                seed: draw_seed(self.plan.sampler.seed, draw),
                ..self.plan.sampler.clone()
            };
            draws.push(run(&sampler)?.future);
        }
        let sampling_ms = started.elapsed().as_secs_f64() * 1e3;

        let mut current_from_future = PlanarMotion::default();
        let mut poses = Vec::with_capacity(n);
        for action in &future_actions {
            current_from_future = current_from_future.then(&PlanarMotion::of_action(action));
            poses.push(moved(&current.meta.global_from_ego, &current_from_future));
        }
        let horizons = self
            .plan
            .horizons
            .iter()
            .map(|&(horizon_s, frames_ahead)| {
                let k = frames_ahead - 1;
                let time = match window.logged_future.get(k) {
                    Some(logged) if self.plan.actions == FutureActions::Log => {
                        logged.time_of_validity_us
                    }
                    _ => current.meta.time_of_validity_us + (horizon_s * 1e6).round() as i64,
                };
                let latent = |method: ForecastMethod, data: Vec<f32>| {
                    let features = BevFeatures {
                        meta: FrameMeta {
                            sample_token: current.meta.sample_token.clone(),
                            frame_token: format!("{}+{horizon_s}s", current.meta.frame_token),
                            scene_name: current.meta.scene_name.clone(),
                            time_of_validity_us: time,
                            global_from_ego: poses[k],
                            // A forecast frame is no dataset's sample.
                            keyframe: false,
                        },
                        data,
                        ..BevFeatures::clone(current)
                    };
                    (method, Arc::new(features))
                };
                let mut latents = vec![latent(ForecastMethod::Model, output.future[k].clone())];
                if self.baselines {
                    latents.push(latent(ForecastMethod::LatentCopyLast, current.data.clone()));
                    latents.push(latent(
                        ForecastMethod::LatentEgoWarp,
                        output.ego_warped[k].clone(),
                    ));
                }
                let samples = draws
                    .iter()
                    .map(|future| latent(ForecastMethod::Model, future[k].clone()).1)
                    .collect();
                ForecastHorizon {
                    horizon_s,
                    frames_ahead,
                    latents,
                    samples,
                }
            })
            .collect();
        Ok(Forecast {
            context: current.meta.clone(),
            actions_from: self.plan.actions.name(),
            future_actions,
            horizons,
            sampling_ms,
        })
    }
}

impl Task for DiffusionRolloutNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let window = inputs.get(&WINDOW)?;
        let forecast = self.forecast(window).map_err(NodeError::item)?;
        if forecast.future_actions.iter().any(|action| {
            self.loaded
                .weights
                .meta
                .action_stats
                .outside_training(action)
        }) {
            if self.outside_training == 0 {
                tracing::warn!(
                    frame = %forecast.context.frame_token,
                    "a forecast is conditioned on actions outside the training range: an extrapolation (counted as `forecasts_outside_training`)"
                );
            }
            self.outside_training += 1;
        }
        self.forecasts += 1;
        self.sampling_ms += forecast.sampling_ms;
        out.send(&FORECAST, forecast)
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        figures.insert("forecasts".into(), self.forecasts as f64);
        figures.insert(
            "forecasts_outside_training".into(),
            self.outside_training as f64,
        );
        if self.forecasts > 0 {
            figures.insert(
                "sampling_ms_mean".into(),
                self.sampling_ms / self.forecasts as f64,
            );
        }
        figures
    }
}

/// Builds the node: the checked plan and the graph's world model, loaded once per graph and
/// paired with its tokenizer's statistics.
pub fn build(
    params: &DiffusionRolloutParams,
    models: &Models,
) -> Result<DiffusionRolloutNode, ParamError> {
    let plan = plan(params, models)?;
    Ok(DiffusionRolloutNode {
        loaded: params.model.load_shared(models)?,
        baselines: params.baselines,
        plan,
        forecasts: 0,
        outside_training: 0,
        sampling_ms: 0.0,
    })
}

pub fn register(registry: &mut Registry) {
    registry.register_with_models(
        KindSpec::task(
            "diffusion_rollout",
            "the world model: a window of past latents to the future latents at the requested horizons, by DDIM",
        )
        .input(WINDOW.spec())
        .output(FORECAST.spec()),
        |params: &DiffusionRolloutParams, models: &Models| plan(params, models).map(|_| ()),
        |params: DiffusionRolloutParams, models: &Models| {
            Ok(Node::Task(Box::new(build(&params, models)?)))
        },
    );
}
