//! `move_agents`: the world model's forecast with the other road users carried along the
//! trajectories a motion head predicts for them (`detect`), as the ego warp carries the static
//! world (`bevworld_types::agent_warp`).
//!
//! - Each horizon of a forecast gains a `model_with_agents` latent: the model's latent, where
//!   every detected agent of an accepted class, scored at least `min_score`, whose most probable
//!   mode moves it at least `min_move_m` by that horizon, reads the current latent's cells
//!   from where it is now. The cells it leaves take the ground around it. Agents that stand are
//!   left to the model.
//! - Its heading follows its path: the turn between the mode's first step and its step at the
//!   horizon. With `follow: velocity` it goes on at its detected velocity instead, heading kept.
//!   With `follow: track` it goes on at the velocity of its track: where the same agent was
//!   detected in the frames before (`bevworld_types::agent_track`), its footprint turned along
//!   that velocity; an agent no earlier frame holds is left to the model.
//! - A forecast waits for the current frame's latent and detections (matched by frame token).
//!   One whose frame never brings them passes on without the new latent, and is counted.

use std::collections::VecDeque;
use std::sync::Arc;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, Outputs, ParamError, Port, Registry, SyncMode, Task,
};
use bevworld_types::action::wrap_angle;
use bevworld_types::detection::DETECTION_NAMES;
use bevworld_types::{
    AgentMotion, BevFeatures, DetectedAgent, Footprint, Forecast, ForecastMethod, FrameDetections,
    LatentGrid, PlanarMotion, TrackParams, move_agents, track_agents,
};
use serde::{Deserialize, Serialize};

const FORECAST: Port<Forecast> = Port::new("forecast");
const DETECTIONS: Port<FrameDetections> = Port::new("detections");
const LATENT: Port<BevFeatures> = Port::new("latent");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MoveAgentsParams {
    /// Detections scored under this are left to the model.
    #[serde(default = "default_min_score")]
    pub min_score: f64,
    /// An agent whose predicted path moves it less than this by a horizon is left to the model
    /// there, metres.
    #[serde(default = "default_min_move")]
    pub min_move_m: f64,
    /// How far around a box its cells are carried, metres.
    #[serde(default = "default_margin")]
    pub margin_m: f64,
    /// The detection names moved.
    #[serde(default = "default_classes")]
    pub classes: Vec<String>,
    /// What carries an agent: its most probable trajectory mode, its detected velocity, or
    /// the velocity of its track across frames.
    #[serde(default)]
    pub follow: Follow,
    /// How `follow: track` links an agent to its detections in earlier frames.
    #[serde(default)]
    pub track: TrackParams,
    /// Most forecasts, latents and detections held while they wait for each other.
    #[serde(default = "default_max_held")]
    pub max_held: usize,
}

/// What carries a detected agent to its future footprint.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Follow {
    /// The motion head's most probable mode.
    #[default]
    Mode,
    /// The detected velocity, constant.
    Velocity,
    /// The velocity of its track through the earlier frames' detections, constant.
    Track,
}

fn default_min_score() -> f64 {
    0.3
}
fn default_min_move() -> f64 {
    1.0
}
fn default_margin() -> f64 {
    1.25
}
fn default_classes() -> Vec<String> {
    [
        "car",
        "truck",
        "bus",
        "trailer",
        "construction_vehicle",
        "motorcycle",
        "bicycle",
    ]
    .map(String::from)
    .to_vec()
}
fn default_max_held() -> usize {
    64
}

fn check(params: &MoveAgentsParams) -> Result<(), ParamError> {
    if !(params.min_score.is_finite() && (0.0..=1.0).contains(&params.min_score)) {
        return Err(ParamError::field(
            "min_score",
            format!("{} must lie in [0, 1]", params.min_score),
        ));
    }
    if !(params.min_move_m.is_finite() && params.min_move_m >= 0.0) {
        return Err(ParamError::field(
            "min_move_m",
            format!("{} must be a distance ≥ 0 m", params.min_move_m),
        ));
    }
    if !(params.margin_m.is_finite() && (0.0..=10.0).contains(&params.margin_m)) {
        return Err(ParamError::field(
            "margin_m",
            format!("{} must lie in [0, 10] m", params.margin_m),
        ));
    }
    if let Some(unknown) = params
        .classes
        .iter()
        .find(|c| !DETECTION_NAMES.contains(&c.as_str()))
    {
        return Err(
            ParamError::field("classes", format!("unknown detection name '{unknown}'"))
                .with_accepted(DETECTION_NAMES.join(", ")),
        );
    }
    if let Some((field, message)) = params.track.problem() {
        return Err(ParamError::field(format!("track.{field}"), message));
    }
    if params.max_held == 0 || params.max_held > 100_000 {
        return Err(ParamError::field(
            "max_held",
            format!("{} must lie in 1..=100000", params.max_held),
        ));
    }
    Ok(())
}

/// Where a detected agent will be `frames_ahead` trajectory steps (of `interval_s`) on, in the
/// current ego frame: by its most probable mode, or its velocity (`follow`: `velocity` and
/// `track` carry the agent's `velocity`, whichever gave it). `None` past the
/// mode's end or when it moves less than `min_move_m`.
pub fn agent_motion(
    agent: &DetectedAgent,
    frames_ahead: usize,
    interval_s: f64,
    follow: Follow,
    min_move_m: f64,
) -> Option<AgentMotion> {
    let now = [agent.centre[0], agent.centre[1]];
    let footprint = Footprint {
        centre: now,
        yaw: agent.yaw,
        length: agent.size[1],
        width: agent.size[0],
    };
    let moved_enough = |then: [f64; 2]| (then[0] - now[0]).hypot(then[1] - now[1]) >= min_move_m;
    if follow != Follow::Mode {
        let seconds = frames_ahead as f64 * interval_s;
        let then = [
            now[0] + agent.velocity[0] * seconds,
            now[1] + agent.velocity[1] * seconds,
        ];
        return (frames_ahead >= 1 && moved_enough(then)).then_some(AgentMotion {
            now: footprint,
            then: Footprint {
                centre: then,
                ..footprint
            },
        });
    }
    let mode = agent.modes.first()?;
    let then = *mode.positions.get(frames_ahead.checked_sub(1)?)?;
    if !moved_enough(then) {
        return None;
    }
    // The turn along the path: from its first step's heading to the heading into `then`.
    let heading = |from: [f64; 2], to: [f64; 2]| {
        let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
        (dx.hypot(dy) > 0.25).then(|| dy.atan2(dx))
    };
    let before = if frames_ahead >= 2 {
        mode.positions[frames_ahead - 2]
    } else {
        now
    };
    let turn = match (heading(now, mode.positions[0]), heading(before, then)) {
        (Some(first), Some(last)) => wrap_angle(last - first),
        _ => 0.0,
    };
    Some(AgentMotion {
        now: footprint,
        then: Footprint {
            centre: then,
            yaw: wrap_angle(agent.yaw + turn),
            ..footprint
        },
    })
}

/// What one forecast became.
#[derive(Debug, Default, PartialEq)]
pub struct Moved {
    /// Agents carried, summed over the horizons.
    pub agents: u64,
    /// Horizons past the detector's trajectories: the model's latent unchanged.
    pub horizons_past_trajectories: u64,
}

/// The agents `follow` moves: `detections`' own, or with `follow: track` those whose track
/// through `earlier` (the scene's frames before, newest first) gives a velocity, with it.
fn agents_to_move(
    detections: &FrameDetections,
    earlier: &[&FrameDetections],
    params: &MoveAgentsParams,
) -> Vec<DetectedAgent> {
    let accepted = |a: &DetectedAgent| {
        a.score >= params.min_score && params.classes.contains(&a.detection_name)
    };
    if params.follow != Follow::Track {
        return detections
            .agents
            .iter()
            .filter(|a| accepted(a))
            .cloned()
            .collect();
    }
    track_agents(detections, earlier, &params.track.rule(params.min_score))
        .iter()
        .zip(&detections.agents)
        .filter(|(_, a)| accepted(a))
        .filter_map(|(track, a)| {
            let velocity = track.velocity()?;
            // A moving car points where it drives, which its track says better than a
            // detector's heading (a car's box is the same turned half a turn).
            (velocity[0].hypot(velocity[1]) >= params.track.min_speed_mps).then(|| DetectedAgent {
                velocity,
                yaw: velocity[1].atan2(velocity[0]),
                ..a.clone()
            })
        })
        .collect()
}

/// Adds `model_with_agents` to every horizon of `forecast`: its model latent with the agents
/// of `detections` (of the forecast's current frame, whose latent is `current`) carried.
/// `earlier` holds the scene's detections before it, newest first (`follow: track` reads them).
pub fn with_agents(
    forecast: &mut Forecast,
    current: &BevFeatures,
    detections: &FrameDetections,
    earlier: &[&FrameDetections],
    params: &MoveAgentsParams,
) -> Result<Moved, String> {
    let interval = detections.interval_s;
    let candidates = agents_to_move(detections, earlier, params);
    let grid = LatentGrid::of(&current.grid, current.channels.len());
    let mut moved = Moved::default();
    for horizon in &mut forecast.horizons {
        let Some(model) = horizon.latent(ForecastMethod::Model).cloned() else {
            continue;
        };
        if model.data.len() != current.data.len()
            || model.grid != current.grid
            || model.weights_hash != current.weights_hash
        {
            return Err(format!(
                "frame {}: the forecast's latent ({} values of {} {}) is not the current latent's kind ({} values of {} {})",
                forecast.context.frame_token,
                model.data.len(),
                model.model,
                model.weights_hash,
                current.data.len(),
                current.model,
                current.weights_hash
            ));
        }
        let steps = horizon.horizon_s / interval;
        let frames_ahead = steps.round() as usize;
        let on_step = (steps - frames_ahead as f64).abs() < 1e-3 && frames_ahead >= 1;
        let trajectory_len = detections
            .agents
            .iter()
            .filter_map(|a| a.modes.first())
            .map(|m| m.positions.len())
            .max()
            .unwrap_or(0);
        let past_modes = params.follow == Follow::Mode && frames_ahead > trajectory_len;
        if !on_step || past_modes {
            moved.horizons_past_trajectories += 1;
            continue;
        }
        let agents: Vec<AgentMotion> = candidates
            .iter()
            .filter_map(|a| {
                agent_motion(a, frames_ahead, interval, params.follow, params.min_move_m)
            })
            .collect();
        moved.agents += agents.len() as u64;
        let current_from_future =
            PlanarMotion::between(&current.meta.global_from_ego, &model.meta.global_from_ego);
        let data = move_agents(
            &current.data,
            &model.data,
            &grid,
            &current_from_future,
            &agents,
            params.margin_m,
        );
        horizon.latents.push((
            ForecastMethod::ModelWithAgents,
            Arc::new(BevFeatures {
                data,
                ..BevFeatures::clone(&model)
            }),
        ));
    }
    Ok(moved)
}

struct MoveAgentsNode {
    params: MoveAgentsParams,
    latents: VecDeque<Arc<BevFeatures>>,
    detections: VecDeque<Arc<FrameDetections>>,
    pending: VecDeque<Forecast>,
    forecasts: u64,
    agents: u64,
    horizons_past_trajectories: u64,
    forecasts_without_agents: u64,
}

/// Whether a stream, in arrival order (scene by scene, each in time order), has gone past the
/// frame at `time_us` of `scene` without bringing it.
fn passed<'a>(mut items: impl Iterator<Item = (&'a str, i64)>, scene: &str, time_us: i64) -> bool {
    items.any(|(s, t)| s == scene && t > time_us)
}

impl MoveAgentsNode {
    /// The frames a track of `current`'s agents may reach: its scene's held detections before
    /// it, newest first, as many as a track holds (none unless `follow: track`).
    fn earlier(&self, current: &FrameDetections) -> Vec<&FrameDetections> {
        if self.params.follow != Follow::Track {
            return Vec::new();
        }
        let mut earlier: Vec<&FrameDetections> = self
            .detections
            .iter()
            .map(|d| d.as_ref())
            .filter(|d| {
                d.meta.scene_name == current.meta.scene_name
                    && d.meta.time_of_validity_us < current.meta.time_of_validity_us
            })
            .collect();
        earlier.sort_by_key(|d| std::cmp::Reverse(d.meta.time_of_validity_us));
        earlier.truncate(self.params.track.frames - 1);
        earlier
    }

    /// The time from which `scene`'s detections are still needed once its frame at `time_us`
    /// is settled: that frame's, or with `follow: track`, the earliest of the frames a later
    /// track may reach (the frames before it that a track of it would hold, and it).
    fn kept_detections_from(&self, scene: &str, time_us: i64) -> i64 {
        if self.params.follow != Follow::Track {
            return time_us;
        }
        let mut times: Vec<i64> = self
            .detections
            .iter()
            .filter(|d| d.meta.scene_name == scene && d.meta.time_of_validity_us <= time_us)
            .map(|d| d.meta.time_of_validity_us)
            .collect();
        times.sort_unstable_by(|a, b| b.cmp(a));
        // A track from the next frame holds `frames − 1` earlier ones: this one and those before.
        times
            .get(self.params.track.frames.saturating_sub(2))
            .copied()
            .unwrap_or(time_us)
            .min(time_us)
    }

    fn bounded<T>(queue: &mut VecDeque<T>, max: usize) {
        while queue.len() > max {
            queue.pop_front();
        }
    }

    /// Sends every pending forecast that can be settled, in order.
    fn flush(&mut self, closed: bool, out: &mut Outputs) -> Result<(), NodeError> {
        while let Some(forecast) = self.pending.front() {
            let token = &forecast.context.frame_token;
            let scene = forecast.context.scene_name.as_str();
            let time = forecast.context.time_of_validity_us;
            let latent = self.latents.iter().find(|l| &l.meta.frame_token == token);
            let detections = self
                .detections
                .iter()
                .find(|d| &d.meta.frame_token == token);
            let settled = match (latent, detections) {
                (Some(latent), Some(detections)) => {
                    Some(Some((Arc::clone(latent), Arc::clone(detections))))
                }
                _ if closed
                    || passed(
                        self.latents
                            .iter()
                            .map(|l| (l.meta.scene_name.as_str(), l.meta.time_of_validity_us)),
                        scene,
                        time,
                    ) && passed(
                        self.detections
                            .iter()
                            .map(|d| (d.meta.scene_name.as_str(), d.meta.time_of_validity_us)),
                        scene,
                        time,
                    ) =>
                {
                    Some(None)
                }
                _ => None,
            };
            let Some(found) = settled else { break };
            let Some(mut forecast) = self.pending.pop_front() else {
                break;
            };
            match found {
                Some((latent, detections)) => {
                    let earlier = self.earlier(&detections);
                    // A latent of another kind than the forecast's is a graph wired to two
                    // tokenizers: every frame would fail alike, so the run stops, naming both.
                    let moved =
                        with_agents(&mut forecast, &latent, &detections, &earlier, &self.params)
                            .map_err(NodeError::fatal)?;
                    self.agents += moved.agents;
                    self.horizons_past_trajectories += moved.horizons_past_trajectories;
                }
                None => self.forecasts_without_agents += 1,
            }
            // What lies before this frame of its scene is no longer needed, but for the
            // detections a track reaches back to.
            let scene = forecast.context.scene_name.clone();
            self.latents
                .retain(|l| l.meta.scene_name != scene || l.meta.time_of_validity_us >= time);
            let kept_from = self.kept_detections_from(&scene, time);
            self.detections
                .retain(|d| d.meta.scene_name != scene || d.meta.time_of_validity_us >= kept_from);
            self.forecasts += 1;
            out.set_time_of_validity(time);
            out.send(&FORECAST, forecast)?;
        }
        Ok(())
    }
}

impl Task for MoveAgentsNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let max = self.params.max_held;
        if inputs.message(LATENT.name).is_some() {
            self.latents.push_back(inputs.shared(&LATENT)?);
            Self::bounded(&mut self.latents, max);
        }
        if inputs.message(DETECTIONS.name).is_some() {
            self.detections.push_back(inputs.shared(&DETECTIONS)?);
            Self::bounded(&mut self.detections, max);
        }
        if inputs.message(FORECAST.name).is_some() {
            self.pending.push_back(inputs.get(&FORECAST)?.clone());
            if self.pending.len() > max {
                // Never dropped: the oldest goes on without agents.
                let oldest = self.pending.pop_front();
                if let Some(oldest) = oldest {
                    self.forecasts_without_agents += 1;
                    self.forecasts += 1;
                    out.set_time_of_validity(oldest.context.time_of_validity_us);
                    out.send(&FORECAST, oldest)?;
                }
            }
        }
        self.flush(false, out)
    }

    fn finish(&mut self, out: &mut Outputs) -> Result<(), NodeError> {
        self.flush(true, out)?;
        if self.forecasts_without_agents > 0 {
            tracing::warn!(
                forecasts = self.forecasts_without_agents,
                "forecasts whose frame brought no latent or detections: passed on without `model_with_agents`"
            );
        }
        Ok(())
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        figures.insert("forecasts".into(), self.forecasts as f64);
        figures.insert("agents_moved".into(), self.agents as f64);
        figures.insert(
            "horizons_past_trajectories".into(),
            self.horizons_past_trajectories as f64,
        );
        figures.insert(
            "forecasts_without_agents".into(),
            self.forecasts_without_agents as f64,
        );
        figures
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::task(
            "move_agents",
            "the forecast with the detected agents carried along their predicted trajectories: each horizon gains `model_with_agents`",
        )
        .input(FORECAST.spec())
        .input(DETECTIONS.spec())
        .input(LATENT.spec())
        .output(FORECAST.spec())
        .sync(SyncMode::Any),
        check,
        |params: MoveAgentsParams| {
            check(&params)?;
            Ok(Node::Task(Box::new(MoveAgentsNode {
                params,
                latents: VecDeque::new(),
                detections: VecDeque::new(),
                pending: VecDeque::new(),
                forecasts: 0,
                agents: 0,
                horizons_past_trajectories: 0,
                forecasts_without_agents: 0,
            })))
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevworld_types::forecast::ForecastHorizon;
    use bevworld_types::{BevGrid, FrameMeta, Pose, TrajectoryMode};
    use glam::DVec3;

    fn agent(name: &str, score: f64, positions: Vec<[f64; 2]>) -> DetectedAgent {
        DetectedAgent {
            detection_name: name.into(),
            score,
            centre: [-30.0, 10.0, 0.8],
            size: [1.9, 4.5, 1.6],
            yaw: 0.0,
            velocity: [0.0, 0.0],
            modes: vec![TrajectoryMode {
                probability: 1.0,
                positions,
            }],
        }
    }

    #[test]
    fn an_agent_goes_where_its_most_probable_mode_puts_it_and_turns_with_its_path() {
        // Straight on, 5 m a step: at the second step it is 10 m on, heading unchanged.
        let straight = agent(
            "car",
            0.9,
            (1..=6).map(|k| [-30.0 + 5.0 * k as f64, 10.0]).collect(),
        );
        let motion = agent_motion(&straight, 2, 0.5, Follow::Mode, 1.0).expect("moves");
        assert_eq!(motion.then.centre, [-20.0, 10.0]);
        assert!(motion.then.yaw.abs() < 1e-12);
        assert_eq!(motion.now.centre, [-30.0, 10.0]);
        // Past the mode's end, or standing: left to the model.
        assert!(agent_motion(&straight, 7, 0.5, Follow::Mode, 1.0).is_none());
        assert!(agent_motion(&straight, 0, 0.5, Follow::Mode, 1.0).is_none());
        let standing = agent("car", 0.9, vec![[-30.2, 10.0]; 6]);
        assert!(agent_motion(&standing, 3, 0.5, Follow::Mode, 1.0).is_none());
        // By its velocity, 4 m/s along +y: 6 m on at the third step, heading kept, and past
        // the modes' end too; standing still, nowhere.
        let mut driving = standing.clone();
        driving.velocity = [0.0, 4.0];
        let motion = agent_motion(&driving, 3, 0.5, Follow::Velocity, 1.0).expect("moves");
        assert_eq!(motion.then.centre, [-30.0, 16.0]);
        assert_eq!(motion.then.yaw, 0.0);
        assert!(agent_motion(&driving, 8, 0.5, Follow::Velocity, 1.0).is_some());
        assert!(agent_motion(&standing, 3, 0.5, Follow::Velocity, 1.0).is_none());
        // A left turn: first along +x, then along +y: a quarter turn by the second step.
        let turning = agent("car", 0.9, vec![[-25.0, 10.0], [-25.0, 15.0]]);
        let motion = agent_motion(&turning, 2, 0.5, Follow::Mode, 1.0).expect("moves");
        assert!((motion.then.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(motion.then.length, 4.5);
    }

    fn latent(data: Vec<f32>, x: f64) -> Arc<BevFeatures> {
        Arc::new(BevFeatures {
            meta: FrameMeta {
                sample_token: "s".into(),
                frame_token: "f".into(),
                scene_name: "a".into(),
                time_of_validity_us: 0,
                global_from_ego: Pose::from_translation(DVec3::new(x, 0.0, 0.0)),
                keyframe: true,
            },
            grid: BevGrid {
                x_range: [-80.0, 80.0],
                y_range: [-80.0, 80.0],
                resolution: 20.0,
                height: 8,
                width: 8,
            },
            channels: vec!["latent_0".into()],
            data,
            model: "tokenizer-tiny".into(),
            weights_hash: "abc".into(),
        })
    }

    #[test]
    fn the_forecast_gains_the_model_latent_with_the_confident_vehicles_carried() {
        // The current latent: a car (9) in row 4, column 2 (centre (−30, 10)). The model's
        // forecast at +1 s (the ego stood still) lost it: all zeros.
        let mut current = vec![0.0; 64];
        current[4 * 8 + 2] = 9.0;
        let current = latent(current, 0.0);
        let model = latent(vec![0.0; 64], 0.0);
        let mut forecast = Forecast {
            context: current.meta.clone(),
            actions_from: "log".into(),
            future_actions: Vec::new(),
            horizons: vec![ForecastHorizon {
                horizon_s: 1.0,
                frames_ahead: 2,
                latents: vec![(ForecastMethod::Model, model)],
                samples: Vec::new(),
            }],
            sampling_ms: 1.0,
        };
        // 20 m a step: at +1 s (step 2) in row 4, column 4, centre (10, 10).
        let path: Vec<[f64; 2]> = (1..=6).map(|k| [-30.0 + 20.0 * k as f64, 10.0]).collect();
        let detections = FrameDetections {
            meta: current.meta.clone(),
            agents: vec![
                agent("car", 0.9, path.clone()),
                // Too unsure, and not a vehicle: neither is moved.
                agent("car", 0.1, path.iter().map(|p| [p[0], -50.0]).collect()),
                agent(
                    "pedestrian",
                    0.9,
                    path.iter().map(|p| [p[0], 50.0]).collect(),
                ),
            ],
            interval_s: 0.5,
            model: "detector-tiny".into(),
            weights_hash: "d".into(),
        };
        let params = MoveAgentsParams {
            margin_m: 5.0,
            ..serde_json::from_str("{}").expect("defaults")
        };
        let moved = with_agents(&mut forecast, &current, &detections, &[], &params).expect("moved");
        assert_eq!(
            moved,
            Moved {
                agents: 1,
                horizons_past_trajectories: 0
            }
        );
        let with = forecast.horizons[0]
            .latent(ForecastMethod::ModelWithAgents)
            .expect("added");
        assert_eq!(with.data[4 * 8 + 4], 9.0);
        assert_eq!(with.data.iter().filter(|&&v| v != 0.0).count(), 1);
        // The model's own latent is untouched.
        let model = forecast.horizons[0]
            .latent(ForecastMethod::Model)
            .expect("model");
        assert!(model.data.iter().all(|&v| v == 0.0));
        // A latent of other weights is refused, naming both.
        let mut other = BevFeatures::clone(&current);
        other.weights_hash = "xyz".into();
        let error = with_agents(&mut forecast, &other, &detections, &[], &params).unwrap_err();
        assert!(error.contains("abc") && error.contains("xyz"), "{error}");
    }

    #[test]
    fn parameters_out_of_range_are_refused_by_name() {
        let defaults: MoveAgentsParams = serde_json::from_str("{}").expect("defaults");
        assert!(check(&defaults).is_ok());
        for (params, field) in [
            (
                MoveAgentsParams {
                    min_score: 1.5,
                    ..defaults.clone()
                },
                "min_score",
            ),
            (
                MoveAgentsParams {
                    min_move_m: f64::NAN,
                    ..defaults.clone()
                },
                "min_move_m",
            ),
            (
                MoveAgentsParams {
                    margin_m: -1.0,
                    ..defaults.clone()
                },
                "margin_m",
            ),
            (
                MoveAgentsParams {
                    classes: vec!["spaceship".into()],
                    ..defaults.clone()
                },
                "classes",
            ),
            (
                MoveAgentsParams {
                    max_held: 0,
                    ..defaults.clone()
                },
                "max_held",
            ),
            (
                MoveAgentsParams {
                    track: TrackParams {
                        frames: 1,
                        ..defaults.track
                    },
                    ..defaults.clone()
                },
                "track.frames",
            ),
            (
                MoveAgentsParams {
                    track: TrackParams {
                        max_speed_mps: 0.0,
                        ..defaults.track
                    },
                    ..defaults.clone()
                },
                "track.max_speed_mps",
            ),
            (
                MoveAgentsParams {
                    track: TrackParams {
                        gate_m: f64::INFINITY,
                        ..defaults.track
                    },
                    ..defaults.clone()
                },
                "track.gate_m",
            ),
            (
                MoveAgentsParams {
                    track: TrackParams {
                        min_speed_mps: -1.0,
                        ..defaults.track
                    },
                    ..defaults.clone()
                },
                "track.min_speed_mps",
            ),
        ] {
            let error = format!("{:?}", check(&params).expect_err(field));
            assert!(error.contains(field), "{field}: {error}");
        }
    }

    /// The scene "a" at `time_s`, the ego standing at the origin: its latent (a car, 9, in
    /// row 4, column `car_column`) and its detections (the car at `car_x`, y = 10).
    fn frame_at(time_s: f64, car_column: usize, car_x: f64) -> (Arc<BevFeatures>, FrameDetections) {
        let mut data = vec![0.0; 64];
        data[4 * 8 + car_column] = 9.0;
        let mut latent = BevFeatures::clone(&latent(data, 0.0));
        latent.meta.frame_token = format!("f{time_s}");
        latent.meta.time_of_validity_us = (time_s * 1e6).round() as i64;
        let mut car = agent("car", 0.9, Vec::new());
        car.centre = [car_x, 10.0, 0.8];
        let detections = FrameDetections {
            meta: latent.meta.clone(),
            agents: vec![car],
            interval_s: 0.5,
            model: "detector-tiny".into(),
            weights_hash: "d".into(),
        };
        (Arc::new(latent), detections)
    }

    fn forecast_of(current: &BevFeatures) -> Forecast {
        Forecast {
            context: current.meta.clone(),
            actions_from: "log".into(),
            future_actions: Vec::new(),
            horizons: vec![ForecastHorizon {
                horizon_s: 1.0,
                frames_ahead: 2,
                latents: vec![(ForecastMethod::Model, latent(vec![0.0; 64], 0.0))],
                samples: Vec::new(),
            }],
            sampling_ms: 1.0,
        }
    }

    #[test]
    fn a_tracked_car_goes_on_at_the_speed_of_its_detections_and_an_untracked_one_stays() {
        // The car at x = −60 half a second ago and at −50 now (row 4, column 1): 20 m/s along
        // +x. At +1 s it is at −30 (column 2). Its velocity head says it stands; no modes.
        let (_, before) = frame_at(0.0, 1, -60.0);
        let (current, now) = frame_at(0.5, 1, -50.0);
        let params = MoveAgentsParams {
            follow: Follow::Track,
            margin_m: 5.0,
            ..serde_json::from_str("{}").expect("defaults")
        };
        let mut forecast = forecast_of(&current);
        let moved = with_agents(&mut forecast, &current, &now, &[&before], &params).expect("moved");
        assert_eq!(moved.agents, 1);
        // Detected across the street, it is turned along its track.
        let mut across = now.clone();
        across.agents[0].yaw = std::f64::consts::FRAC_PI_2;
        let carried = agents_to_move(&across, &[&before], &params);
        assert_eq!(carried.len(), 1);
        assert!(carried[0].yaw.abs() < 1e-12, "{}", carried[0].yaw);
        assert!((carried[0].velocity[0] - 20.0).abs() < 1e-9);
        let with = forecast.horizons[0]
            .latent(ForecastMethod::ModelWithAgents)
            .expect("added");
        assert_eq!(with.data[4 * 8 + 2], 9.0);
        assert_eq!(with.data.iter().filter(|&&v| v != 0.0).count(), 1);
        // With no earlier frame there is no track: the car is left to the model; so it is by
        // its velocity head, which says it stands; and so is a track slower than the bar
        // (1 m in the half second: 2 m/s against 2.5), though it would move 2 m by +1 s.
        let (_, crawled) = frame_at(0.0, 1, -51.0);
        let slow = MoveAgentsParams {
            track: TrackParams {
                min_speed_mps: 2.5,
                ..params.track
            },
            ..params.clone()
        };
        for (follow, earlier, params) in [
            (Follow::Track, vec![], &params),
            (Follow::Velocity, vec![&before], &params),
            (Follow::Track, vec![&crawled], &slow),
        ] {
            let mut forecast = forecast_of(&current);
            let params = MoveAgentsParams {
                follow,
                ..params.clone()
            };
            let moved =
                with_agents(&mut forecast, &current, &now, &earlier, &params).expect("moved");
            assert_eq!(moved.agents, 0, "{follow:?}");
        }
        // The same crawl at the default bar (2 m/s) is carried.
        let mut forecast = forecast_of(&current);
        let moved =
            with_agents(&mut forecast, &current, &now, &[&crawled], &params).expect("moved");
        assert_eq!(moved.agents, 1);
    }

    #[test]
    fn the_node_keeps_the_detections_a_later_track_reaches_back_to() {
        let params = MoveAgentsParams {
            follow: Follow::Track,
            ..serde_json::from_str("{}").expect("defaults")
        };
        let mut node = MoveAgentsNode {
            params,
            latents: VecDeque::new(),
            detections: VecDeque::new(),
            pending: VecDeque::new(),
            forecasts: 0,
            agents: 0,
            horizons_past_trajectories: 0,
            forecasts_without_agents: 0,
        };
        let header = |seq| bevworld_graph::Header {
            seq,
            time_of_validity_us: 0,
            entered_graph: bevworld_graph::Instant::now(),
        };
        let mut out = Outputs::detached(&["forecast"]);
        // 10 m/s along +x, frames 0.5 s apart; a forecast from the second and third frames.
        let frames: Vec<_> = (0..3)
            .map(|k| frame_at(0.5 * k as f64, 1, -50.0 + 5.0 * k as f64))
            .collect();
        for (k, (latent, detections)) in frames.iter().enumerate() {
            let mut messages = vec![
                None,
                Some(bevworld_graph::Message::new(
                    header(k as u64),
                    detections.clone(),
                )),
                Some(bevworld_graph::Message::new(
                    header(k as u64),
                    BevFeatures::clone(latent),
                )),
            ];
            if k >= 1 {
                messages[0] = Some(bevworld_graph::Message::new(
                    header(k as u64),
                    forecast_of(latent),
                ));
            }
            let inputs = Inputs::from_messages(&["forecast", "detections", "latent"], messages);
            node.process(&inputs, &mut out).expect("processed");
            if k == 1 {
                // Settled at 0.5 s: its frame and the one before stay for the next track.
                let held: Vec<i64> = node
                    .detections
                    .iter()
                    .map(|d| d.meta.time_of_validity_us)
                    .collect();
                assert_eq!(held, vec![0, 500_000]);
            }
        }
        assert_eq!(node.forecasts, 2);
        // Each forecast moved its car: from a track of two frames, then of three.
        assert_eq!(node.agents, 2);
        let earlier = node.earlier(&frames[2].1);
        let times: Vec<i64> = earlier.iter().map(|d| d.meta.time_of_validity_us).collect();
        assert_eq!(times, vec![500_000]);
        // Without tracking, nothing before the settled frame is kept.
        node.params.follow = Follow::Velocity;
        assert_eq!(node.kept_detections_from("a", 1_000_000), 1_000_000);
        assert!(node.earlier(&frames[2].1).is_empty());
    }
}
