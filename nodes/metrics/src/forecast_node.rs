//! `forecast_metrics`: scores each rendered forecast against the logged future frame, per
//! horizon and method, and prints the table at the end of the run.
//!
//! - `chamfer`: the rendered sweep (cast along the future sweep's own rays: 4D-Occ's
//!   protocol) against that sweep's returns off the ego body, in its ego frame, within the ROI.
//!   A cloud left empty by the ROI is counted (`empty_clouds`) and kept out of the mean, never
//!   scored as a perfect 0.
//! - `psnr_db`, `ssim`: the cameras, at the rendered size.
//! - `latent_l1`: the mean absolute difference from the tokenizer's latent of the true future
//!   frame (the `oracle`), standardised per channel with the tokenizer's statistics.
//! - `copy_last`, `ego_warp`: the raw-point baselines on the same frames, as `eval baselines`
//!   computes them: the context sweep as it is, and moved by the known ego motion.
//!
//! - `agents`: when the logged frame carries the dataset's boxes, the agent-level scores of
//!   `agents.rs` (points on moving vehicles, on parked vehicles, the static rest), for every
//!   method and both raw baselines, pooled over contexts and per scene.
//!
//! - `model_draws`, `model_best_of_K`: when the rollout drew K > 1 samples, every draw's mean
//!   and the best of the first K' draws (`best_of.rs`): whole-scene Chamfer and the agent
//!   scores. The `model` row stays the point forecast, draw 0.
//!
//! Views without a logged future are counted and left out. With `json`, the table is written
//! in the shape `bevworld eval forecast --json` prints.

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;

use crate::agents::{AgentSums, SplitTruth, split_truth};
use crate::best_of::{DrawScore, best_chamfer, best_for_agents, best_of_counts};

use bevworld_graph::{
    Figures, Inputs, KindSpec, Models, Node, NodeError, Outputs, ParamError, Port, Registry, Task,
};
use bevworld_types::{
    BevFeatures, ForecastMethod, FutureView, LatentStats, LatentStatsFile, RenderedFuture,
    ScoreTable, SensorFrame,
};
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::chamfer::{Roi, chamfer_in_roi};
use crate::reconstruction_node::{score_images, score_lidar};

// The node's ports, each named once (`bevworld_graph::Port`).
const RENDERED: Port<RenderedFuture> = Port::new("rendered");
const TABLE: Port<ScoreTable> = Port::new("table");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ForecastMetricsParams {
    /// ROI preset for the Chamfer distance: `4docc` or `vidar`.
    #[serde(default = "default_roi")]
    pub roi: String,
    /// A bundle of the graph's `models:` section, whose tokenizer's latent statistics
    /// standardise the latent L1; absent, the latents are not scored.
    #[serde(default)]
    pub model: Option<String>,
    /// Also write the table as JSON here.
    #[serde(default)]
    pub json: Option<PathBuf>,
    /// Print the table at the end of the run.
    #[serde(default = "yes")]
    pub print: bool,
}

fn yes() -> bool {
    true
}

fn default_roi() -> String {
    "4docc".into()
}

/// Sums of one (horizon, method) cell.
#[derive(Clone, Debug, Default)]
struct Cell {
    chamfer: Sum,
    psnr_db: Sum,
    ssim: Sum,
    latent_l1: Sum,
    /// The Chamfer distance per scene, for its spread over scenes.
    chamfer_by_scene: BTreeMap<String, Sum>,
    /// The agent-level sums, pooled and per scene.
    agents: AgentSums,
    agents_by_scene: BTreeMap<String, AgentSums>,
}

#[derive(Clone, Copy, Debug, Default)]
struct Sum {
    total: f64,
    count: usize,
}

impl Sum {
    fn add(&mut self, value: f64) {
        self.total += value;
        self.count += 1;
    }
    fn mean(&self) -> Option<f64> {
        (self.count > 0).then(|| self.total / self.count as f64)
    }
}

impl Cell {
    fn add_agents(&mut self, scene: &str, sums: &AgentSums) {
        self.agents.add(sums);
        self.agents_by_scene
            .entry(scene.to_string())
            .or_default()
            .add(sums);
    }

    fn add_chamfer(&mut self, scene: &str, value: f64) {
        self.chamfer.add(value);
        self.chamfer_by_scene
            .entry(scene.to_string())
            .or_default()
            .add(value);
    }
}

/// A (context, horizon) group's latents, for the latent L1 against the oracle.
type LatentGroup = BTreeMap<ForecastMethod, Arc<BevFeatures>>;

pub struct ForecastMetrics {
    roi: Roi,
    /// The latent statistics and the file they came from.
    stats: Option<(LatentStats, PathBuf)>,
    json: Option<PathBuf>,
    print: bool,
    /// By (horizon in µs, frames ahead), then method name (with the raw baselines).
    cells: BTreeMap<(i64, usize), BTreeMap<String, Cell>>,
    latents: BTreeMap<(String, i64), LatentGroup>,
    contexts: std::collections::BTreeSet<String>,
    sampling_ms: Sum,
    /// Per context: its forecast's sampling time and the render time of its model views.
    latency_ms: BTreeMap<String, (f64, f64)>,
    without_truth: u64,
    empty_clouds: u64,
    /// The last logged frames split by their boxes, by frame token: every method of a
    /// horizon is scored against the same split.
    splits: VecDeque<(String, Arc<SplitTruth>)>,
    /// The model's draws of a (context, horizon) scored so far, with their numbers, until
    /// all K are in.
    draws: BTreeMap<(String, i64), Vec<(usize, DrawScore)>>,
}

/// How many split truths are kept: the methods of a context's horizons arrive together.
const SPLITS_KEPT: usize = 32;

fn points_moved(frame: &SensorFrame, to_from_ego: &bevworld_types::Pose) -> Vec<[f64; 3]> {
    frame
        .lidar
        .scene_ego_points()
        .into_iter()
        .map(|p| {
            to_from_ego
                .transform_point3(DVec3::new(p[0].into(), p[1].into(), p[2].into()))
                .to_array()
        })
        .collect()
}

impl ForecastMetrics {
    fn cell(&mut self, horizon_s: f64, frames_ahead: usize, method: &str) -> &mut Cell {
        self.cells
            .entry(((horizon_s * 1e6).round() as i64, frames_ahead))
            .or_default()
            .entry(method.to_string())
            .or_default()
    }

    /// Scores one rendered view into its cells.
    fn score(&mut self, rendered: &RenderedFuture) -> Result<(), NodeError> {
        let view = &rendered.view;
        let (horizon_s, ahead) = (view.horizon_s, view.frames_ahead);
        let Some(truth) = view.truth.clone() else {
            self.without_truth += 1;
            return Ok(());
        };
        let point_forecast = view.sample == 0;
        if view.method == ForecastMethod::Model && point_forecast {
            self.contexts.insert(view.context.frame_token.clone());
            self.sampling_ms.add(view.sampling_ms);
            let latency = self
                .latency_ms
                .entry(view.context.frame_token.clone())
                .or_insert((view.sampling_ms, 0.0));
            latency.1 += rendered.render_ms;
            // The raw-point baselines, once per (context, horizon), in the truth's ego frame.
            let gt = points_moved(&truth, &bevworld_types::Pose::IDENTITY);
            let copy_last = points_moved(&view.context, &bevworld_types::Pose::IDENTITY);
            let truth_from_context =
                truth.lidar.global_from_ego.inverse() * view.context.lidar.global_from_ego;
            let ego_warp = points_moved(&view.context, &truth_from_context);
            let scene = truth.scene_name.clone();
            if let Some(c) = self.chamfer(&copy_last, &gt) {
                self.cell(horizon_s, ahead, "copy_last")
                    .add_chamfer(&scene, c);
            }
            if let Some(c) = self.chamfer(&ego_warp, &gt) {
                self.cell(horizon_s, ahead, "ego_warp")
                    .add_chamfer(&scene, c);
            }
            if let Some(split) = self.split(&truth) {
                for (method, points) in [("copy_last", &copy_last), ("ego_warp", &ego_warp)] {
                    let sums = crate::agents::score(&split, points, &self.roi);
                    self.cell(horizon_s, ahead, method)
                        .add_agents(&scene, &sums);
                }
            }
        }
        let method = view.method.name();
        let drawn = view.method == ForecastMethod::Model && view.samples_in_forecast > 1;
        if let Some(lidar) = &rendered.lidar {
            let result = score_lidar(&truth, lidar, &self.roi);
            let chamfer = if result.pred_points == 0 || result.gt_points == 0 {
                self.empty_clouds += 1;
                None
            } else {
                Some(result.chamfer)
            };
            let agents = self.split(&truth).map(|split| {
                let forecast = crate::reconstruction_node::to_f64(lidar.ego_points());
                crate::agents::score(&split, &forecast, &self.roi)
            });
            let scene = truth.scene_name.as_str();
            if point_forecast {
                let cell = self.cell(horizon_s, ahead, method);
                if let Some(c) = chamfer {
                    cell.add_chamfer(scene, c);
                }
                if let Some(sums) = &agents {
                    cell.add_agents(scene, sums);
                }
            }
            if drawn {
                self.add_draw(view, scene, DrawScore { chamfer, agents });
            }
        }
        if !point_forecast {
            // A further draw is scored on its sweep only: the images and the latent are the
            // point forecast's.
            return Ok(());
        }
        if let Some(images) = &rendered.images {
            let (psnr_db, ssim) =
                score_images(&truth, images).map_err(|e| NodeError::item_from(&e))?;
            let cell = self.cell(horizon_s, ahead, method);
            cell.psnr_db.add(psnr_db);
            cell.ssim.add(ssim);
        }
        if self.stats.is_some() {
            let key = (
                view.context.frame_token.clone(),
                (horizon_s * 1e6).round() as i64,
            );
            self.latents
                .entry(key)
                .or_default()
                .insert(view.method, Arc::clone(&view.latent));
        }
        Ok(())
    }

    /// Holds one draw's scores; once a (context, horizon) has all K, adds every draw to
    /// `model_draws` and the best of the first K' to `model_best_of_K'`.
    fn add_draw(&mut self, view: &FutureView, scene: &str, score: DrawScore) {
        let key = (
            view.context.frame_token.clone(),
            (view.horizon_s * 1e6).round() as i64,
        );
        let held = self.draws.entry(key.clone()).or_default();
        held.push((view.sample, score));
        if held.len() < view.samples_in_forecast {
            return;
        }
        let mut numbered = self.draws.remove(&key).unwrap_or_default();
        numbered.sort_by_key(|(sample, _)| *sample);
        let draws: Vec<DrawScore> = numbered.into_iter().map(|(_, score)| score).collect();
        let (horizon_s, ahead) = (view.horizon_s, view.frames_ahead);
        for draw in &draws {
            let cell = self.cell(horizon_s, ahead, "model_draws");
            if let Some(c) = draw.chamfer {
                cell.add_chamfer(scene, c);
            }
            if let Some(sums) = &draw.agents {
                cell.add_agents(scene, sums);
            }
        }
        for count in best_of_counts(draws.len()) {
            let first = &draws[..count];
            let cell = self.cell(horizon_s, ahead, &format!("model_best_of_{count}"));
            if let Some(c) = best_chamfer(first) {
                cell.add_chamfer(scene, c);
            }
            if let Some(sums) = best_for_agents(first) {
                cell.add_agents(scene, sums);
            }
        }
    }

    /// The logged frame split by its boxes; `None` when the dataset annotates nothing there.
    fn split(&mut self, truth: &SensorFrame) -> Option<Arc<SplitTruth>> {
        if truth.boxes.is_empty() {
            return None;
        }
        if let Some((_, split)) = self.splits.iter().find(|(t, _)| *t == truth.frame_token) {
            return Some(Arc::clone(split));
        }
        let split = Arc::new(split_truth(truth, &self.roi));
        self.splits
            .push_back((truth.frame_token.clone(), Arc::clone(&split)));
        if self.splits.len() > SPLITS_KEPT {
            self.splits.pop_front();
        }
        Some(split)
    }

    fn chamfer(&mut self, pred: &[[f64; 3]], truth: &[[f64; 3]]) -> Option<f64> {
        let result = chamfer_in_roi(pred, truth, &self.roi);
        if result.pred_points == 0 || result.gt_points == 0 {
            self.empty_clouds += 1;
            return None;
        }
        Some(result.chamfer)
    }

    /// The table: per horizon, per method, the means.
    pub fn table(&self) -> serde_json::Value {
        let horizons: Vec<serde_json::Value> = self
            .cells
            .iter()
            .map(|(&(horizon_us, frames_ahead), methods)| {
                let mut row = serde_json::Map::new();
                row.insert("horizon_s".into(), (horizon_us as f64 * 1e-6).into());
                row.insert("frames_ahead".into(), frames_ahead.into());
                // Contexts scored at this horizon: a log's last frames have no truth this far.
                let scored = methods
                    .get("model")
                    .map_or(0, |cell| cell.psnr_db.count.max(cell.chamfer.count));
                row.insert("contexts".into(), scored.into());
                for (method, cell) in methods {
                    let mut scores = serde_json::Map::new();
                    for (name, sum) in [
                        ("chamfer", cell.chamfer),
                        ("psnr_db", cell.psnr_db),
                        ("ssim", cell.ssim),
                        ("latent_l1", cell.latent_l1),
                    ] {
                        if let Some(mean) = sum.mean() {
                            scores.insert(name.into(), mean.into());
                        }
                    }
                    let by_scene: BTreeMap<&String, f64> = cell
                        .chamfer_by_scene
                        .iter()
                        .filter_map(|(scene, sum)| Some((scene, sum.mean()?)))
                        .collect();
                    let per_scene: Vec<f64> = by_scene.values().copied().collect();
                    if let Some(spread) = crate::report_file::population_std(&per_scene) {
                        // Each scene's mean, for comparisons paired by scene.
                        scores.insert("chamfer_by_scene".into(), serde_json::json!(by_scene));
                        scores.insert("chamfer_scene_std".into(), spread.into());
                        scores.insert("scenes".into(), per_scene.len().into());
                    }
                    if let Some(agents) = agents_json(cell) {
                        scores.insert("agents".into(), agents);
                    }
                    row.insert(method.clone(), scores.into());
                }
                row.into()
            })
            .collect();
        let rollout: Vec<f64> = self.latency_ms.values().map(|(s, _)| *s).collect();
        let rendered: Vec<f64> = self.latency_ms.values().map(|(s, r)| s + r).collect();
        serde_json::json!({
            "contexts": self.contexts.len(),
            "ms_per_forecast": self.sampling_ms.mean(),
            // Per forecast: the rollout alone, and the rollout with the render of the model's
            // views at the requested horizons.
            "latency_ms": {
                "rollout_p50": percentile(&rollout, 0.50),
                "rollout_p99": percentile(&rollout, 0.99),
                "with_render_p50": percentile(&rendered, 0.50),
                "with_render_p99": percentile(&rendered, 0.99),
            },
            "views_without_truth": self.without_truth,
            "empty_clouds": self.empty_clouds,
            "horizons": horizons,
        })
    }
}

/// A cell's agent-level scores (`agents::agents_json`). `None` when no view was annotated.
fn agents_json(cell: &Cell) -> Option<serde_json::Value> {
    crate::agents::agents_json(&cell.agents, &cell.agents_by_scene)
}

/// The agent-level part of a forecast table as markdown: per class, the mean over scenes of
/// each scene's value (± the spread for the headline ones); the moving boxes' precision and
/// the displacement pooled over all views. Empty when nothing was annotated.
pub fn agents_markdown_of(table: &serde_json::Value) -> String {
    let mut text = String::new();
    let empty = Vec::new();
    for row in table["horizons"].as_array().unwrap_or(&empty) {
        let horizon = row["horizon_s"].as_f64().unwrap_or(f64::NAN);
        for method in TABLE_METHODS {
            let Some(agents) = row.get(method).and_then(|c| c.get("agents")) else {
                continue;
            };
            let show = |path: &[&str], digits: usize| shown_at(agents, path, digits);
            let scenes = |class: &str, metric: &str, digits: usize, spread: bool| {
                let mean = show(&[class, "over_scenes", metric, "mean"], digits);
                if spread {
                    format!(
                        "{mean} ± {}",
                        show(&[class, "over_scenes", metric, "std"], digits)
                    )
                } else {
                    mean
                }
            };
            text.push_str(&format!(
                "| +{horizon} s | {method} | {} | {} | {} | {} | {} | {} ({}) | {} / {} | {} |\n",
                scenes("moving_vehicles", "recall_0.5m", 2, false),
                scenes("moving_vehicles", "recall_1m", 2, true),
                scenes("moving_vehicles", "recall_0.5m_above_ground", 2, false),
                scenes("moving_vehicles", "chamfer_to_forecast", 2, true),
                show(&["moving_boxes", "precision_0.5m"], 2),
                show(&["moving_agents", "displacement_m"], 2),
                show(&["moving_agents", "missed"], 2),
                scenes("parked_vehicles", "recall_0.5m", 2, false),
                scenes("parked_vehicles", "recall_1m", 2, false),
                scenes("static", "chamfer_to_forecast", 3, true),
            ));
        }
    }
    if text.is_empty() {
        return text;
    }
    format!(
        "| horizon | method | moving: recall@0.5 m | moving: recall@1 m | moving: recall@0.5 m above ground | moving: Chamfer truth→forecast (m²) | moving: precision in their boxes | moving: displacement m (share missed) | parked: recall@0.5 / @1 m | static: Chamfer truth→forecast (m²) |\n|---|---|---|---|---|---|---|---|---|---|\n{text}"
    )
}

/// The moving vehicles' scores pooled over every true point of every scene (the JSON's
/// `moving_vehicles` figures), per horizon and method: where a few scenes hold few moving
/// cars, the mean over scenes weighs each of those scenes as much as a busy one, and this
/// table weighs each point once.
pub fn pooled_markdown_of(table: &serde_json::Value) -> String {
    let mut text = String::new();
    let empty = Vec::new();
    for row in table["horizons"].as_array().unwrap_or(&empty) {
        let horizon = row["horizon_s"].as_f64().unwrap_or(f64::NAN);
        for method in TABLE_METHODS {
            let Some(moving) = row
                .get(method)
                .and_then(|c| c.get("agents"))
                .and_then(|a| a.get("moving_vehicles"))
            else {
                continue;
            };
            let show = |key: &str, digits: usize| shown_at(moving, &[key], digits);
            text.push_str(&format!(
                "| +{horizon} s | {method} | {} | {} | {} | {} | {} |\n",
                show("points", 0),
                show("recall_0.5m", 2),
                show("recall_1m", 2),
                show("recall_0.5m_above_ground", 2),
                show("chamfer_to_forecast", 2),
            ));
        }
    }
    if text.is_empty() {
        return text;
    }
    format!(
        "| horizon | method | moving: true points | moving: recall@0.5 m | moving: recall@1 m | moving: recall@0.5 m above ground | moving: Chamfer truth→forecast (m²) |\n|---|---|---|---|---|---|---|\n{text}"
    )
}

/// The number at `path` inside `value`, with `digits` decimals; "—" where there is none.
fn shown_at(value: &serde_json::Value, path: &[&str], digits: usize) -> String {
    path.iter()
        .try_fold(value, |v, key| v.get(*key))
        .and_then(serde_json::Value::as_f64)
        .map_or("—".to_string(), |v| format!("{v:.digits$}"))
}

/// The header of `summary_row`'s table: whole-scene Chamfer and the agents' headline scores.
pub const SUMMARY_HEADER: &str = "| horizon | method | Chamfer (m²) | moving: recall@1 m | moving: recall@0.5 m above ground | moving: Chamfer truth→forecast (m²) | moving: precision in their boxes | parked: recall@0.5 m | static: Chamfer truth→forecast (m²) |\n|---|---|---|---|---|---|---|---|---|\n";

/// One method's cell of a forecast table (`ForecastMetrics::table`) as a row under
/// `SUMMARY_HEADER`, labelled `label`: means over scenes ± their spread.
pub fn summary_row(horizon_s: f64, label: &str, cell: &serde_json::Value) -> String {
    let show = |path: &[&str], digits: usize| shown_at(cell, path, digits);
    let scenes = |class: &str, metric: &str, digits: usize| {
        let at = |stat: &str| show(&["agents", class, "over_scenes", metric, stat], digits);
        format!("{} ± {}", at("mean"), at("std"))
    };
    format!(
        "| +{horizon_s} s | {label} | {} ± {} | {} | {} | {} | {} | {} | {} |\n",
        show(&["chamfer"], 3),
        show(&["chamfer_scene_std"], 3),
        scenes("moving_vehicles", "recall_1m", 2),
        scenes("moving_vehicles", "recall_0.5m_above_ground", 2),
        scenes("moving_vehicles", "chamfer_to_forecast", 2),
        show(&["agents", "moving_boxes", "precision_0.5m"], 2),
        scenes("parked_vehicles", "recall_0.5m", 2),
        scenes("static", "chamfer_to_forecast", 3),
    )
}

/// The rows of the model's draws (`model_draws`, `model_best_of_K`) beside the point
/// forecast and the two latent references, as markdown under `SUMMARY_HEADER`. Empty when
/// the forecasts had one draw.
pub fn draws_markdown_of(table: &serde_json::Value) -> String {
    let mut text = String::new();
    let empty = Vec::new();
    for row in table["horizons"].as_array().unwrap_or(&empty) {
        let horizon = row["horizon_s"].as_f64().unwrap_or(f64::NAN);
        let mut best_of: Vec<(usize, &str)> = row
            .as_object()
            .into_iter()
            .flat_map(|fields| fields.keys())
            .filter_map(|key| {
                let count = key.strip_prefix("model_best_of_")?.parse().ok()?;
                Some((count, key.as_str()))
            })
            .collect();
        if best_of.is_empty() {
            continue;
        }
        best_of.sort();
        let methods = std::iter::once("model")
            .chain(std::iter::once("model_draws"))
            .chain(best_of.iter().map(|(_, key)| *key))
            .chain(["latent_ego_warp", "oracle"]);
        for method in methods {
            if let Some(cell) = row.get(method) {
                text.push_str(&summary_row(horizon, method, cell));
            }
        }
    }
    if text.is_empty() {
        return text;
    }
    format!("{SUMMARY_HEADER}{text}")
}

/// The point forecasts of several runs of the same scenes side by side (`(label, table)`),
/// per horizon, then the first table's latent ego warp and oracle, under `SUMMARY_HEADER`.
pub fn compare_markdown_of(runs: &[(String, serde_json::Value)]) -> String {
    let mut text = String::from(SUMMARY_HEADER);
    let Some((_, first)) = runs.first() else {
        return String::new();
    };
    let empty = Vec::new();
    for (index, row) in first["horizons"]
        .as_array()
        .unwrap_or(&empty)
        .iter()
        .enumerate()
    {
        let horizon = row["horizon_s"].as_f64().unwrap_or(f64::NAN);
        for (label, table) in runs {
            let cell = &table["horizons"][index];
            if cell["horizon_s"].as_f64() == Some(horizon) {
                text.push_str(&summary_row(horizon, label, &cell["model"]));
            }
        }
        for method in ["latent_ego_warp", "oracle"] {
            if let Some(cell) = row.get(method) {
                text.push_str(&summary_row(horizon, method, cell));
            }
        }
    }
    text
}

/// The nearest-rank percentile `q` of `values` (NaN when there are none).
pub fn percentile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let rank = (q * sorted.len() as f64).ceil().max(1.0) as usize;
    sorted[rank.min(sorted.len()) - 1]
}

/// The methods of a forecast table, in the order they are shown.
pub const TABLE_METHODS: [&str; 8] = [
    "model",
    "model_with_agents",
    "latent_copy_last",
    "latent_ego_warp",
    "latent_box_warp",
    "oracle",
    "copy_last",
    "ego_warp",
];

/// A forecast table (`ForecastMetrics::table`, or `eval forecast --json`) as markdown.
pub fn markdown_of(table: &serde_json::Value) -> String {
    let mut text = String::from(
        "| horizon | method | Chamfer (m²) | PSNR (dB) | SSIM | latent L1 |\n|---|---|---|---|---|---|\n",
    );
    let empty = Vec::new();
    for row in table["horizons"].as_array().unwrap_or(&empty) {
        let horizon = row["horizon_s"].as_f64().unwrap_or(f64::NAN);
        for method in TABLE_METHODS {
            let Some(cell) = row.get(method) else {
                continue;
            };
            let show = |name: &str, digits: usize| {
                cell.get(name)
                    .and_then(serde_json::Value::as_f64)
                    .map_or("—".to_string(), |v| format!("{v:.digits$}"))
            };
            // The Chamfer distance with its spread over the scenes, where there were several.
            let chamfer = match cell
                .get("chamfer_scene_std")
                .and_then(serde_json::Value::as_f64)
            {
                Some(spread) => format!("{} ± {spread:.3}", show("chamfer", 3)),
                None => show("chamfer", 3),
            };
            text.push_str(&format!(
                "| +{horizon} s | {method} | {chamfer} | {} | {} | {} |\n",
                show("psnr_db", 2),
                show("ssim", 3),
                show("latent_l1", 3),
            ));
        }
    }
    text
}

impl Task for ForecastMetrics {
    fn process(&mut self, inputs: &Inputs, _: &mut Outputs) -> Result<(), NodeError> {
        self.score(inputs.get(&RENDERED)?)
    }

    fn finish(&mut self, out: &mut Outputs) -> Result<(), NodeError> {
        if let Some((stats, path)) = self.stats.clone() {
            let groups = std::mem::take(&mut self.latents);
            for ((_, horizon_us), group) in groups {
                let Some(oracle) = group.get(&ForecastMethod::Oracle) else {
                    continue;
                };
                // Statistics of another latent would shift every score, silently.
                if oracle.channels.len() != stats.mean.len() {
                    return Err(NodeError::fatal(format!(
                        "{}: statistics of {} channels, but the latents scored have {}",
                        path.display(),
                        stats.mean.len(),
                        oracle.channels.len()
                    )));
                }
                let mut truth = oracle.data.clone();
                stats.standardize(&mut truth);
                for (method, latent) in &group {
                    let mut values = latent.data.clone();
                    stats.standardize(&mut values);
                    let l1 = bevworld_types::mean_abs_difference(&values, &truth);
                    // Frames ahead are the same for every method of a horizon.
                    let ahead = self
                        .cells
                        .keys()
                        .find(|(h, _)| *h == horizon_us)
                        .map_or(0, |(_, a)| *a);
                    self.cell(horizon_us as f64 * 1e-6, ahead, method.name())
                        .latent_l1
                        .add(l1);
                }
            }
        }
        if self.print && self.cells.is_empty() {
            println!(
                "forecast_metrics: nothing scored: {} rendered views had no logged future frame (a forecast of a manoeuvre, or a log that ends within the horizon)",
                self.without_truth
            );
        } else if self.print {
            let table = self.table();
            println!(
                "\nForecast scores, mean over {} contexts:\n\n{}",
                self.contexts.len(),
                markdown_of(&table)
            );
            let agents = agents_markdown_of(&table);
            if !agents.is_empty() {
                println!("\nThe agents, from the dataset's boxes (means over scenes):\n\n{agents}");
            }
            let draws = draws_markdown_of(&table);
            if !draws.is_empty() {
                println!(
                    "\nThe model's draws: each draw's mean, and the best of the first K:\n\n{draws}"
                );
            }
        }
        if let Some(path) = &self.json {
            let text = serde_json::to_string_pretty(&self.table())
                .map_err(|e| NodeError::fatal(format!("{}: {e}", path.display())))?;
            crate::report_file::write_report(path, &text)?;
        }
        if out.is_connected(&TABLE) {
            out.send(&TABLE, ScoreTable(self.table()))?;
        }
        Ok(())
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        figures.insert("contexts".into(), self.contexts.len() as f64);
        figures.insert("views_without_truth".into(), self.without_truth as f64);
        figures.insert("empty_clouds".into(), self.empty_clouds as f64);
        for (&(horizon_us, _), cells) in &self.cells {
            for (method, cell) in cells {
                if let Some(c) = cell.chamfer.mean() {
                    figures.insert(format!("chamfer_{method}_{}s", horizon_us as f64 * 1e-6), c);
                }
            }
        }
        figures
    }

    fn nothing_made(&self) -> Option<String> {
        self.cells.is_empty().then(|| {
            format!(
                "nothing scored: {} rendered views had no logged future frame (a forecast of a manoeuvre, or a log that ends within the horizon)",
                self.without_truth
            )
        })
    }
}

/// The bundle's latent statistics, with the file they came from.
fn latent_stats(bundle: &serde_json::Value) -> Result<(LatentStats, PathBuf), ParamError> {
    let path = bevworld_types::ModelBundle::from_json(bundle)
        .map_err(|error| ParamError::field("model", error.to_string()))?
        .tokenizer
        .and_then(|tokenizer| tokenizer.latent_stats_path())
        .ok_or_else(|| {
            ParamError::field("model", "the bundle's tokenizer has no latent statistics")
        })?;
    LatentStatsFile::load(&path)
        .map(|file| (file.stats, path))
        .map_err(|error| ParamError::field("model", error.to_string()))
}

fn roi_of(params: &ForecastMetricsParams) -> Result<Roi, ParamError> {
    Roi::preset(&params.roi).ok_or_else(|| {
        ParamError::field("roi", format!("unknown preset '{}'", params.roi))
            .with_accepted("4docc, vidar")
    })
}

fn build(params: &ForecastMetricsParams, models: &Models) -> Result<ForecastMetrics, ParamError> {
    let roi = roi_of(params)?;
    let stats = params
        .model
        .as_ref()
        .map(|name| {
            models
                .load(name, latent_stats)
                .map(|shared| (*shared).clone())
        })
        .transpose()?;
    Ok(ForecastMetrics {
        roi,
        stats,
        json: params.json.clone(),
        print: params.print,
        cells: BTreeMap::new(),
        latents: BTreeMap::new(),
        contexts: Default::default(),
        sampling_ms: Sum::default(),
        latency_ms: BTreeMap::new(),
        without_truth: 0,
        empty_clouds: 0,
        splits: VecDeque::new(),
        draws: BTreeMap::new(),
    })
}

pub fn register(registry: &mut Registry) {
    registry.register_with_models(
        KindSpec::task(
            "forecast_metrics",
            "Chamfer, PSNR, SSIM and latent L1 of rendered forecasts per horizon and method, beside the raw-point baselines; the table on `table` at the end",
        )
        .input(RENDERED.spec())
        .output(TABLE.spec()),
        |params: &ForecastMetricsParams, models: &Models| {
            roi_of(params)?;
            match &params.model {
                Some(name) => models.require(name, &["tokenizer"]).map(|_| ()),
                None => Ok(()),
            }
        },
        |params: ForecastMetricsParams, models: &Models| {
            Ok(Node::Task(Box::new(build(&params, models)?)))
        },
    );
}

#[cfg(test)]
mod tests {
    use super::{ForecastMetricsParams, build, percentile, pooled_markdown_of};
    use crate::reconstruction_node::score_lidar;
    use bevworld_types::{
        BevFeatures, ForecastMethod, FutureView, ObjectBox, Pose, RenderedFuture, SensorFrame,
    };
    use glam::DVec3;
    use std::sync::Arc;

    #[test]
    fn the_table_gives_each_scenes_mean_and_the_spread_of_those_means_by_hand() {
        let params = ForecastMetricsParams {
            roi: "4docc".into(),
            model: None,
            json: None,
            print: false,
        };
        let mut metrics = build(&params, &bevworld_graph::Models::none()).expect("params");
        // Scene a: 1 and 3 (mean 2); scene b: 4 (mean 4). Over contexts: 8/3.
        for (scene, value) in [("a", 1.0), ("a", 3.0), ("b", 4.0)] {
            metrics.cell(1.0, 2, "model").add_chamfer(scene, value);
        }
        let table = metrics.table();
        let model = &table["horizons"][0]["model"];
        assert_eq!(model["chamfer_by_scene"]["a"], 2.0, "{table}");
        assert_eq!(model["chamfer_by_scene"]["b"], 4.0);
        assert!((model["chamfer"].as_f64().expect("mean") - 8.0 / 3.0).abs() < 1e-12);
        // The population spread of {2, 4}.
        assert_eq!(model["chamfer_scene_std"], 1.0);
        assert_eq!(model["scenes"], 2);
        // The printed table shows that spread; a single scene has none to show.
        let text = super::markdown_of(&table);
        assert!(text.contains("| +1 s | model | 2.667 ± 1.000 |"), "{text}");
        let mut one = build(&params, &bevworld_graph::Models::none()).expect("params");
        one.cell(1.0, 2, "model").add_chamfer("a", 1.0);
        let text = super::markdown_of(&one.table());
        assert!(text.contains("| +1 s | model | 1.000 | — |"), "{text}");
    }

    fn cloud(points: &[[f32; 3]]) -> bevworld_types::PointCloud {
        bevworld_types::PointCloud {
            points: points
                .iter()
                .map(|&[x, y, z]| bevworld_types::LidarPoint {
                    x,
                    y,
                    z,
                    intensity: 0.0,
                    ring: 0,
                })
                .collect(),
            ego_from_lidar: Pose::IDENTITY,
            timestamp_us: 0,
            global_from_ego: Pose::IDENTITY,
            dropped_non_finite: 0,
            source_file: String::new(),
        }
    }

    fn frame(token: &str, points: &[[f32; 3]], boxes: Vec<ObjectBox>) -> Arc<SensorFrame> {
        Arc::new(SensorFrame {
            time_of_validity_us: 0,
            sample_token: token.into(),
            frame_token: token.into(),
            scene_name: "scene".into(),
            index_in_scene: 0,
            keyframe: true,
            global_from_ego: Pose::IDENTITY,
            cameras: Vec::new(),
            lidar: Arc::new(cloud(points)),
            action: None,
            boxes,
        })
    }

    const CAR: [[f32; 3]; 4] = [
        [9.0, 0.0, 1.0],
        [10.0, 0.0, 1.0],
        [11.0, 0.0, 1.0],
        [10.0, 0.5, 1.2],
    ];
    const ROAD: [[f32; 3]; 4] = [
        [30.0, 0.0, 0.0],
        [32.0, 0.0, 0.0],
        [34.0, 0.0, 0.0],
        [20.0, -5.0, 0.0],
    ];

    /// The model's draw `sample` of `samples`, rendered as `points`, against a truth of a
    /// car driving at 5 m/s (4 returns) and the road (4 returns).
    fn draw(sample: usize, samples: usize, points: &[[f32; 3]]) -> RenderedFuture {
        let moving_car = ObjectBox {
            instance_token: "car".into(),
            category: "vehicle.car".into(),
            global_from_box: Pose::from_translation(DVec3::new(10.0, 0.0, 0.75)),
            size: [2.0, 4.0, 1.5],
            velocity: Some([5.0, 0.0]),
            attributes: Vec::new(),
            num_pts: 4,
        };
        let truth = frame("future", &[CAR, ROAD].concat(), vec![moving_car]);
        let context = frame("context", &ROAD, Vec::new());
        let latent = Arc::new(BevFeatures {
            meta: bevworld_types::FrameMeta {
                sample_token: "future".into(),
                frame_token: "future".into(),
                scene_name: "scene".into(),
                time_of_validity_us: 0,
                global_from_ego: Pose::IDENTITY,
                keyframe: false,
            },
            grid: bevworld_types::BevGrid {
                x_range: [-1.0, 1.0],
                y_range: [-1.0, 1.0],
                resolution: 2.0,
                height: 1,
                width: 1,
            },
            channels: vec!["c".into()],
            data: vec![0.0],
            model: "test".into(),
            weights_hash: "none".into(),
        });
        RenderedFuture {
            view: Arc::new(FutureView {
                context,
                horizon_s: 1.0,
                frames_ahead: 2,
                horizons_in_forecast: 1,
                method: ForecastMethod::Model,
                sample,
                samples_in_forecast: samples,
                latent,
                rays: Arc::clone(&truth),
                truth: Some(truth),
                sampling_ms: 1.0,
            }),
            images: None,
            lidar: Some(cloud(points)),
            render_ms: 1.0,
        }
    }

    #[test]
    fn the_best_of_k_takes_the_smallest_chamfer_and_the_draw_that_keeps_the_moving_car() {
        let params = ForecastMetricsParams {
            roi: "4docc".into(),
            model: None,
            json: None,
            print: false,
        };
        // Draw 0 (the point forecast) erases the car; draw 1 keeps it but moves the road 2 m;
        // draw 2 puts one return 2.5 m beside the car.
        let draws = [
            ROAD.to_vec(),
            [
                CAR.to_vec(),
                ROAD.iter().map(|p| [p[0], p[1] + 2.0, p[2]]).collect(),
            ]
            .concat(),
            [ROAD.to_vec(), vec![[10.0, 2.5, 1.0]]].concat(),
        ];
        let mut metrics = build(&params, &bevworld_graph::Models::none()).expect("params");
        let roi = crate::chamfer::Roi::preset("4docc").expect("roi");
        let mut chamfers = Vec::new();
        // Arriving out of order changes nothing: draws are taken by their number.
        for sample in [0, 2, 1] {
            let rendered = draw(sample, 3, &draws[sample]);
            let truth = rendered.view.truth.clone().expect("truth");
            let lidar = rendered.lidar.as_ref().expect("sweep");
            chamfers.push((sample, score_lidar(&truth, lidar, &roi).chamfer));
            metrics.score(&rendered).expect("scored");
        }
        chamfers.sort_by_key(|(sample, _)| *sample);
        let chamfer: Vec<f64> = chamfers.into_iter().map(|(_, c)| c).collect();
        let table = metrics.table();
        let row = &table["horizons"][0];
        let value = |method: &str, path: &[&str]| {
            path.iter()
                .try_fold(&row[method], |v, key| v.get(*key))
                .and_then(serde_json::Value::as_f64)
                .unwrap_or_else(|| panic!("{method} {path:?} in {row}"))
        };
        assert_eq!(row["contexts"], 1, "draws are no further contexts");
        assert_eq!(
            value("model", &["chamfer"]),
            chamfer[0],
            "the point forecast"
        );
        let mean = chamfer.iter().sum::<f64>() / 3.0;
        assert!((value("model_draws", &["chamfer"]) - mean).abs() < 1e-12);
        let smallest = chamfer.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(smallest < chamfer[0], "{chamfer:?}");
        assert_eq!(value("model_best_of_3", &["chamfer"]), smallest);
        let moving = ["agents", "moving_vehicles", "recall_1m"];
        assert_eq!(
            value("model", &moving),
            0.0,
            "the point forecast erased the car"
        );
        assert_eq!(
            value("model_best_of_3", &moving),
            1.0,
            "draw 1 keeps all four returns"
        );
        assert!(
            (value("model_draws", &moving) - 4.0 / 12.0).abs() < 1e-12,
            "4 of 12, pooled"
        );
        assert!(
            row.get("copy_last").is_some(),
            "the raw baselines once, with draw 0"
        );
        assert!(
            metrics.draws.is_empty(),
            "nothing held once all draws are in"
        );

        // One draw: no best-of rows.
        let mut single = build(&params, &bevworld_graph::Models::none()).expect("params");
        single.score(&draw(0, 1, &draws[0])).expect("scored");
        let table = single.table();
        let row = table["horizons"][0].as_object().expect("row");
        assert!(row.keys().all(|k| !k.starts_with("model_")), "{row:?}");
    }

    #[test]
    fn the_pooled_table_shows_each_methods_moving_vehicle_figures_as_the_json_holds_them() {
        let table = serde_json::json!({"horizons": [{
            "horizon_s": 1.0,
            "model": {"agents": {"moving_vehicles": {
                "points": 200, "recall_0.5m": 0.25, "recall_1m": 0.5,
                "recall_0.5m_above_ground": 0.125, "chamfer_to_forecast": 3.5}}},
            "latent_box_warp": {"agents": {"moving_vehicles": {
                "points": 200, "recall_0.5m": 0.5, "recall_1m": 0.75,
                "recall_0.5m_above_ground": null, "chamfer_to_forecast": 1.25}}},
            "oracle": {"chamfer": 0.6}
        }]});
        let text = pooled_markdown_of(&table);
        assert!(
            text.contains("| +1 s | model | 200 | 0.25 | 0.50 | 0.12 | 3.50 |"),
            "{text}"
        );
        assert!(
            text.contains("| +1 s | latent_box_warp | 200 | 0.50 | 0.75 | — | 1.25 |"),
            "{text}"
        );
        assert!(!text.contains("oracle"), "no agents, no row: {text}");
        assert!(pooled_markdown_of(&serde_json::json!({"horizons": []})).is_empty());
    }

    #[test]
    fn runs_compared_side_by_side_show_each_runs_point_forecast_per_horizon() {
        let params = ForecastMetricsParams {
            roi: "4docc".into(),
            model: None,
            json: None,
            print: false,
        };
        let table = |points: &[[f32; 3]]| {
            let mut metrics = build(&params, &bevworld_graph::Models::none()).expect("params");
            metrics.score(&draw(0, 1, points)).expect("scored");
            metrics.table()
        };
        let erased = table(&ROAD);
        let kept = table(&[CAR, ROAD].concat());
        let text = super::compare_markdown_of(&[("erased".into(), erased), ("kept".into(), kept)]);
        let rows: Vec<&str> = text.lines().skip(2).collect();
        assert_eq!(
            rows.len(),
            2,
            "two runs, no ego warp or oracle was scored: {text}"
        );
        assert!(rows[0].starts_with("| +1 s | erased | "), "{text}");
        // The car erased: none of its 4 returns within 1 m; kept exactly: all of them. One
        // scene has no spread.
        assert!(rows[0].contains("| 0.00 ± — |"), "{text}");
        assert!(
            rows[1].starts_with("| +1 s | kept | 0.000 ± — | 1.00 ± — |"),
            "{text}"
        );
        assert!(super::compare_markdown_of(&[]).is_empty());
    }

    #[test]
    fn percentiles_are_nearest_rank() {
        let values: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        assert_eq!(percentile(&values, 0.50), 50.0);
        assert_eq!(percentile(&values, 0.99), 99.0);
        assert_eq!(percentile(&values, 1.0), 100.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
        assert!(percentile(&[], 0.5).is_nan());
    }
}
