//! `latent_history`: keeps, for the scene being replayed, the last latents at the model's
//! stride, and once it holds enough emits one `LatentWindow` per new frame: the model's
//! condition frames with the ego's motion into each (which takes one frame more), and, with
//! `log_future`, the logged poses of the frames that follow (the window then waits for them).
//!
//! - **Stride.** By default a frame is kept once the model's `frame_interval_s` (less the
//!   `tolerance`) has passed since the last kept one: every keyframe of a 2 Hz source, every
//!   6th sweep at 12 Hz, and still 2 Hz when a live graph drops frames. With `every: k`, every
//!   k-th frame of a scene is kept instead. Kept frames closer than the model's interval
//!   allows are refused (the model would be fed another frame rate than it learnt); later ones,
//!   short of a gap, are kept and counted (`late_frames`).
//! - **Resets.** A new scene, or two kept frames further apart than `gap_factor` intervals,
//!   empties the buffer (counted in the metrics: `resets_scene`, `resets_gap`).
//! - **The end of a log.** With `log_future`, the last frames of a scene still get their
//!   windows when the scene ends, with as much logged future as there is.
//! - **Bounded.** The buffer never holds more than context + 1 (+ future) latents.
//! - **Refusals.** A latent from another tokenizer than the rollout's weights pair with, or of
//!   another shape, is refused, naming both.

use std::collections::VecDeque;
use std::sync::Arc;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Models, Node, NodeError, Outputs, ParamError, Port, Registry, Task,
};
use bevworld_types::{BevFeatures, EgoAction, LatentWindow, LoggedPose};
use serde::{Deserialize, Serialize};

use crate::nodes::model_params::WorldModelParams;

// The node's ports, each named once (`bevworld_graph::Port`).
const LATENT: Port<BevFeatures> = Port::new("latent");
const WINDOW: Port<LatentWindow> = Port::new("window");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LatentHistoryParams {
    /// The bundle of the graph's `models:` section whose world model the history feeds.
    #[serde(flatten)]
    pub model: WorldModelParams,
    /// Keep every `every`-th frame of a scene; absent: keep frames the model's interval apart.
    #[serde(default)]
    pub every: Option<usize>,
    /// Wait for the model's future frames and attach their logged poses (replay of a log).
    #[serde(default)]
    pub log_future: bool,
    /// Kept frames further apart than this many intervals start a new history.
    #[serde(default = "default_gap_factor")]
    pub gap_factor: f64,
    /// How far, as a fraction of the interval, kept frames may lie from it.
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
}

fn default_gap_factor() -> f64 {
    1.5
}
fn default_tolerance() -> f64 {
    0.2
}

/// What the buffer needs to know of the model and its weights.
#[derive(Clone, Debug, PartialEq)]
pub struct HistoryShape {
    pub context: usize,
    /// Future frames whose poses are attached (0 in live use).
    pub future: usize,
    pub interval_s: f64,
    pub latent_shape: [usize; 3],
    /// The tokenizer (config name, weights digest) the rollout's weights pair with.
    pub tokenizer: (String, String),
}

/// The buffer itself, without the graph: what the node runs and the tests drive.
pub struct LatentHistory {
    shape: HistoryShape,
    every: Option<usize>,
    gap_factor: f64,
    tolerance: f64,
    scene: Option<String>,
    seen_in_scene: usize,
    kept: VecDeque<Arc<BevFeatures>>,
    /// The time of the last window's current frame, so that a flush owes only later ones.
    emitted_through: Option<i64>,
    /// When the next frame is due, keeping by time.
    next_target_us: Option<i64>,
    pub resets_scene: u64,
    pub resets_gap: u64,
    /// Kept frames that came later than the interval's tolerance (but before a gap).
    pub late_frames: u64,
    pub windows: u64,
    /// Latents taken, and the most frames at the model's stride any one run of a scene held:
    /// what a history that never filled says of its input.
    pub latents: u64,
    pub longest_run: usize,
}

impl LatentHistory {
    pub fn new(shape: HistoryShape, every: Option<usize>, gap_factor: f64, tolerance: f64) -> Self {
        Self {
            shape,
            every: every.map(|k| k.max(1)),
            gap_factor,
            tolerance,
            scene: None,
            seen_in_scene: 0,
            kept: VecDeque::new(),
            emitted_through: None,
            next_target_us: None,
            resets_scene: 0,
            resets_gap: 0,
            late_frames: 0,
            windows: 0,
            latents: 0,
            longest_run: 0,
        }
    }

    /// Why no window was made, when none was: the frames a window needs against the most
    /// that any scene gave in a row at the model's stride.
    pub fn why_no_window(&self) -> Option<String> {
        if self.windows > 0 || self.latents == 0 {
            return None;
        }
        let interval = self.shape.interval_s;
        let needed = self.shape.context + 1;
        Some(format!(
            "it took {} latent(s), and the most any scene gave in a row {interval} s apart (the world model's stride) was {}; a forecast needs {needed}: the model's {} condition frames and the one before them, for the motion into the oldest",
            self.latents, self.longest_run, self.shape.context
        ))
    }

    /// How early a frame may come and still take its slot.
    fn slack_us(&self) -> i64 {
        (0.5 * self.tolerance * self.shape.interval_s * 1e6).round() as i64
    }

    /// Most latents it ever holds.
    pub fn capacity(&self) -> usize {
        self.shape.context + 1 + self.shape.future
    }

    pub fn len(&self) -> usize {
        self.kept.len()
    }

    pub fn is_empty(&self) -> bool {
        self.kept.is_empty()
    }

    fn check(&self, latent: &BevFeatures) -> Result<(), String> {
        let (model, hash) = &self.shape.tokenizer;
        if &latent.model != model || &latent.weights_hash != hash {
            return Err(format!(
                "the latent of frame {} comes from tokenizer '{}' with weights {}, but the world model's weights pair with '{model}' with weights {hash}: encode with the tokenizer the world model was trained on",
                latent.meta.frame_token, latent.model, latent.weights_hash
            ));
        }
        let [c, h, w] = self.shape.latent_shape;
        if latent.channels.len() != c
            || (latent.grid.height, latent.grid.width) != (h, w)
            || latent.data.len() != c * h * w
        {
            return Err(format!(
                "the latent of frame {} is {} x {} x {}, the world model reads {c} x {h} x {w}",
                latent.meta.frame_token,
                latent.channels.len(),
                latent.grid.height,
                latent.grid.width
            ));
        }
        Ok(())
    }

    /// The window whose current frame is `kept[current]`: the condition frames before it (and
    /// one more, for the motion into the oldest), and the logged future after it, as far as it
    /// is held (up to `future` frames).
    fn window_at(&self, current: usize) -> LatentWindow {
        let frames: Vec<&Arc<BevFeatures>> = self.kept.iter().collect();
        let first = current + 1 - self.shape.context;
        let action = |a: &BevFeatures, b: &BevFeatures| {
            EgoAction::between(
                &a.meta.global_from_ego,
                a.meta.time_of_validity_us,
                &b.meta.global_from_ego,
                b.meta.time_of_validity_us,
            )
            .unwrap_or_default()
        };
        let future_end = (current + 1 + self.shape.future).min(frames.len());
        LatentWindow {
            context: frames[first..=current]
                .iter()
                .map(|f| Arc::clone(f))
                .collect(),
            context_actions: (first..=current)
                .map(|k| action(frames[k - 1], frames[k]))
                .collect(),
            logged_future: frames[current + 1..future_end]
                .iter()
                .map(|f| LoggedPose {
                    time_of_validity_us: f.meta.time_of_validity_us,
                    global_from_ego: f.meta.global_from_ego,
                })
                .collect(),
            stride_s: self.shape.interval_s,
        }
    }

    fn emit(&mut self, current: usize, windows: &mut Vec<LatentWindow>) {
        let window = self.window_at(current);
        self.emitted_through = window.current().map(|c| c.meta.time_of_validity_us);
        self.windows += 1;
        windows.push(window);
    }

    /// The windows still owed before the buffer is emptied (a new scene, a gap, the end of
    /// the stream): with `log_future`, the last frames' windows, whose logged future is cut
    /// short by the end of the log.
    pub fn flush(&mut self) -> Vec<LatentWindow> {
        let mut windows = Vec::new();
        for current in self.shape.context..self.kept.len() {
            let time = self.kept[current].meta.time_of_validity_us;
            if self.emitted_through.is_none_or(|t| time > t) {
                self.emit(current, &mut windows);
            }
        }
        self.kept.clear();
        self.emitted_through = None;
        self.next_target_us = None;
        windows
    }

    /// Takes one latent; returns the windows it completes.
    pub fn push(&mut self, latent: Arc<BevFeatures>) -> Result<Vec<LatentWindow>, String> {
        self.check(&latent)?;
        self.latents += 1;
        let mut windows = Vec::new();
        if self.scene.as_deref() != Some(latent.meta.scene_name.as_str()) {
            if self.scene.is_some() {
                self.resets_scene += 1;
            }
            windows = self.flush();
            self.scene = Some(latent.meta.scene_name.clone());
            self.seen_in_scene = 0;
        }
        let seen = self.seen_in_scene;
        self.seen_in_scene += 1;
        let skipped = match (self.every, self.kept.back()) {
            (Some(every), _) => !seen.is_multiple_of(every),
            (None, _) => self
                .next_target_us
                .is_some_and(|target| latent.meta.time_of_validity_us < target - self.slack_us()),
        };
        if skipped {
            return Ok(windows);
        }
        if let Some(last) = self.kept.back() {
            let dt_s =
                (latent.meta.time_of_validity_us - last.meta.time_of_validity_us) as f64 * 1e-6;
            let interval = self.shape.interval_s;
            if dt_s > self.gap_factor * interval {
                self.resets_gap += 1;
                windows.extend(self.flush());
            } else if dt_s > (1.0 + self.tolerance) * interval {
                // Late (a live graph dropped the frame on time): kept, its action carries dt.
                self.late_frames += 1;
            } else if dt_s < (1.0 - self.tolerance) * interval {
                return Err(format!(
                    "frames {} and {} are {dt_s:.3} s apart, but the world model steps {interval} s: set `every` so that kept frames are {interval} s apart (every: 1 on keyframes, every: 6 on 12 Hz sweeps)",
                    last.meta.frame_token, latent.meta.frame_token
                ));
            }
        }
        // The next frame is due one interval after this one's slot, so that a frame a little
        // late (the one on time dropped) does not shift every later one; a frame later than
        // the tolerance starts the count again from itself.
        let time = latent.meta.time_of_validity_us;
        let interval_us = (self.shape.interval_s * 1e6).round() as i64;
        self.next_target_us = Some(match self.next_target_us {
            Some(target)
                if (time - target).abs() <= (self.tolerance * interval_us as f64) as i64 =>
            {
                target + interval_us
            }
            _ => time + interval_us,
        });
        self.kept.push_back(latent);
        while self.kept.len() > self.capacity() {
            self.kept.pop_front();
        }
        self.longest_run = self.longest_run.max(self.kept.len());
        if self.kept.len() == self.capacity() {
            self.emit(self.shape.context, &mut windows);
        }
        Ok(windows)
    }
}

pub struct LatentHistoryNode {
    history: LatentHistory,
}

impl Task for LatentHistoryNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let latent = inputs.shared(&LATENT)?;
        for window in self.history.push(latent).map_err(NodeError::item)? {
            out.set_time_of_validity(window.current().map_or(0, |c| c.meta.time_of_validity_us));
            out.send(&WINDOW, window)?;
        }
        Ok(())
    }

    fn finish(&mut self, out: &mut Outputs) -> Result<(), NodeError> {
        for window in self.history.flush() {
            out.set_time_of_validity(window.current().map_or(0, |c| c.meta.time_of_validity_us));
            out.send(&WINDOW, window)?;
        }
        Ok(())
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        figures.insert("windows".into(), self.history.windows as f64);
        figures.insert("resets_scene".into(), self.history.resets_scene as f64);
        figures.insert("resets_gap".into(), self.history.resets_gap as f64);
        figures.insert("late_frames".into(), self.history.late_frames as f64);
        figures.insert("capacity".into(), self.history.capacity() as f64);
        figures
    }

    fn nothing_made(&self) -> Option<String> {
        self.history.why_no_window()
    }
}

fn check(params: &LatentHistoryParams, models: &Models) -> Result<HistoryShape, ParamError> {
    if params.every == Some(0) {
        return Err(
            ParamError::field("every", "must be at least 1").with_accepted("an integer >= 1")
        );
    }
    if !(params.gap_factor.is_finite() && params.gap_factor > 1.0) {
        return Err(ParamError::field(
            "gap_factor",
            format!("{} must be a number > 1", params.gap_factor),
        ));
    }
    if !(params.tolerance.is_finite() && params.tolerance > 0.0 && params.tolerance < 0.5) {
        return Err(ParamError::field(
            "tolerance",
            format!("{} must lie in (0, 0.5)", params.tolerance),
        ));
    }
    let (config, meta) = params.model.check(models)?;
    Ok(HistoryShape {
        context: config.context_frames,
        future: if params.log_future {
            config.future_frames
        } else {
            0
        },
        interval_s: config.frame_interval_s,
        latent_shape: [
            config.latent_channels,
            config.latent_size[0],
            config.latent_size[1],
        ],
        tokenizer: (meta.tokenizer_model, meta.tokenizer_weights_hash),
    })
}

pub fn register(registry: &mut Registry) {
    registry.register_with_models(
        KindSpec::task(
            "latent_history",
            "the last latents of the scene at the world model's stride; one window per new frame once full",
        )
        .input(LATENT.spec())
        .output(WINDOW.spec()),
        |params: &LatentHistoryParams, models: &Models| check(params, models).map(|_| ()),
        |params: LatentHistoryParams, models: &Models| {
            let shape = check(&params, models)?;
            Ok(Node::Task(Box::new(LatentHistoryNode {
                history: LatentHistory::new(shape, params.every, params.gap_factor, params.tolerance),
            })))
        },
    );
}
