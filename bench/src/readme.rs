//! The README's results table, generated from the figures in `bench/results/*.json`. Each
//! figure exists once, in those files; the README holds this table between two markers, a
//! test (below) fails when the two disagree, and
//! `cargo run --release -p bevworld-bench --bin readme_results -- --write` rewrites it.
//! A target's verdict (met or missed) is computed here from the figure, never typed.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde_json::Value;

/// The line above the generated table.
pub const BEGIN: &str = "<!-- results: generated from bench/results/*.json by `cargo run --release -p bevworld-bench --bin readme_results -- --write`; edit the JSON, not this table -->";
/// The line below it.
pub const END: &str = "<!-- end of generated results -->";

#[derive(Debug, thiserror::Error)]
pub enum ReadmeError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("{path}: no figure at `{pointer}`")]
    Missing { path: PathBuf, pointer: String },
    #[error("{path}: {message}")]
    Markers { path: PathBuf, message: String },
}

/// The result files of one folder, each read once.
struct Figures {
    dir: PathBuf,
    files: HashMap<String, Value>,
}

impl Figures {
    fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_path_buf(),
            files: HashMap::new(),
        }
    }

    fn path(&self, file: &str) -> PathBuf {
        self.dir.join(format!("{file}.json"))
    }

    fn file(&mut self, file: &str) -> Result<&Value, ReadmeError> {
        if !self.files.contains_key(file) {
            let path = self.path(file);
            let bytes = std::fs::read(&path).map_err(|e| ReadmeError::File {
                path: path.clone(),
                message: e.to_string(),
            })?;
            let value = serde_json::from_slice(&bytes).map_err(|e| ReadmeError::File {
                path: path.clone(),
                message: e.to_string(),
            })?;
            self.files.insert(file.to_string(), value);
        }
        self.files.get(file).ok_or_else(|| ReadmeError::Missing {
            path: self.path(file),
            pointer: String::new(),
        })
    }

    /// The value at a JSON pointer (`/test/psnr_db`).
    fn value(&mut self, file: &str, pointer: &str) -> Result<Value, ReadmeError> {
        let path = self.path(file);
        self.file(file)?
            .pointer(pointer)
            .cloned()
            .ok_or_else(|| ReadmeError::Missing {
                path,
                pointer: pointer.to_string(),
            })
    }

    fn number(&mut self, file: &str, pointer: &str) -> Result<f64, ReadmeError> {
        let path = self.path(file);
        self.value(file, pointer)?
            .as_f64()
            .ok_or_else(|| ReadmeError::Missing {
                path,
                pointer: format!("{pointer} (a number)"),
            })
    }

    fn text(&mut self, file: &str, pointer: &str) -> Result<String, ReadmeError> {
        let path = self.path(file);
        self.value(file, pointer)?
            .as_str()
            .map(str::to_string)
            .ok_or_else(|| ReadmeError::Missing {
                path,
                pointer: format!("{pointer} (a text)"),
            })
    }

    fn count(&mut self, file: &str, pointer: &str) -> Result<usize, ReadmeError> {
        let path = self.path(file);
        let value = self.value(file, pointer)?;
        value
            .as_u64()
            .map(|n| n as usize)
            .or_else(|| value.as_array().map(Vec::len))
            .ok_or_else(|| ReadmeError::Missing {
                path,
                pointer: format!("{pointer} (a count)"),
            })
    }

    /// The index of the forecast table's row for `horizon_s`.
    fn horizon(&mut self, file: &str, horizon_s: f64) -> Result<String, ReadmeError> {
        let rows = self.count(file, "/horizons")?;
        for row in 0..rows {
            if (self.number(file, &format!("/horizons/{row}/horizon_s"))? - horizon_s).abs() < 1e-9
            {
                return Ok(format!("/horizons/{row}"));
            }
        }
        Err(ReadmeError::Missing {
            path: self.path(file),
            pointer: format!("/horizons/*/horizon_s = {horizon_s}"),
        })
    }

    /// One method's figure at 0.5, 1 and 3 s, as `a / b / c`.
    fn per_horizon(
        &mut self,
        file: &str,
        method_and_figure: &str,
        digits: usize,
    ) -> Result<String, ReadmeError> {
        let mut cells = Vec::new();
        for horizon in [0.5, 1.0, 3.0] {
            let row = self.horizon(file, horizon)?;
            let value = self.number(file, &format!("{row}/{method_and_figure}"))?;
            cells.push(format!("{value:.digits$}"));
        }
        Ok(cells.join(" / "))
    }
}

/// `n` and a noun, plural when `n` is not 1.
fn counted(n: usize, noun: &str) -> String {
    if n == 1 {
        format!("{n} {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

fn verdict(met: bool) -> &'static str {
    if met { "met" } else { "**missed**" }
}

/// A row: what was measured, the figure, and the page with the details.
type Row = (String, String, &'static str);

fn tokenizer(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "tokenizer-test-tokenizer-tiny";
    let psnr = f.number(file, "/test/psnr_db")?;
    let chamfer = f.number(file, "/test/chamfer_m2")?;
    Ok((
        format!(
            "Tiny tokenizer, held-out test scenes ({} scenes, {} keyframes), mean ± spread over scenes",
            f.count(file, "/test/scenes")?,
            f.count(file, "/test/frames")?
        ),
        format!(
            "{psnr:.2} ± {:.2} dB PSNR, {:.3} SSIM, {chamfer:.3} ± {:.3} m² Chamfer; targets 24 dB ({}) and 0.5 m² ({})",
            f.number(file, "/test/scene_std/psnr_db")?,
            f.number(file, "/test/ssim")?,
            f.number(file, "/test/scene_std/chamfer_m2")?,
            verdict(psnr >= 24.0),
            verdict(chamfer <= 0.5),
        ),
        "[tokenizer-training.md](bench/results/tokenizer-training.md)",
    ))
}

fn world_model(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "world-model-test";
    // Future frames are 0.5 s apart: 0.5, 1 and 3 s are frames 1, 2 and 6.
    let at = |f: &mut Figures, method: &str| -> Result<(String, f64, f64), ReadmeError> {
        let mut cells = Vec::new();
        for frame in [0, 1, 5] {
            cells.push(format!(
                "{:.3}",
                f.number(file, &format!("/mean/{method}/{frame}"))?
            ));
        }
        Ok((
            cells.join(" / "),
            f.number(file, &format!("/mean/{method}/5"))?,
            f.number(file, &format!("/spread/{method}/5"))?,
        ))
    };
    let (model, model_3s, spread_3s) = at(f, "world_model")?;
    let (warp, warp_3s, _) = at(f, "ego_warp")?;
    let (copy, _, _) = at(f, "copy_last")?;
    let ratio = model_3s / warp_3s;
    Ok((
        format!(
            "Tiny world model, held-out test scenes ({} scenes, {} windows, {}), standardised latent L1",
            f.count(file, "/scenes")?,
            f.count(file, "/windows")?,
            counted(f.count(file, "/sampler_steps")?, "DDIM step")
        ),
        format!(
            "{model} at 0.5 / 1 / 3 s (± {spread_3s:.3} over scenes at 3 s), against ego-warp {warp} and copy-last {copy}; {ratio:.3}× ego-warp at 3 s (target 0.85×: {})",
            verdict(ratio <= 0.85)
        ),
        "[world-model-training.md](bench/results/world-model-training.md)",
    ))
}

fn forecast(f: &mut Figures, file: &str, what: &str) -> Result<Row, ReadmeError> {
    let model = f.per_horizon(file, "model/chamfer", 3)?;
    let warp = f.per_horizon(file, "latent_ego_warp/chamfer", 3)?;
    let raw_warp = f.per_horizon(file, "ego_warp/chamfer", 3)?;
    let copy = f.per_horizon(file, "copy_last/chamfer", 3)?;
    let oracle = f.per_horizon(file, "oracle/chamfer", 3)?;
    Ok((
        format!(
            "{what} ({} contexts, {}), LiDAR Chamfer",
            f.count(file, "/contexts")?,
            counted(f.count(file, "/steps")?, "DDIM step")
        ),
        format!(
            "{model} m² at 0.5 / 1 / 3 s, against `latent_ego_warp` {warp}, raw `ego_warp` {raw_warp}, `copy_last` {copy} and the tokenizer's floor (`oracle`) {oracle}; {:.0} ms per forecast",
            f.number(file, "/ms_per_forecast")?
        ),
        "[forecast.md](bench/results/forecast.md)",
    ))
}

fn agents(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "forecast-test";
    let recall = |f: &mut Figures, horizon: f64, method: &str, class: &str, at: &str| {
        let row = f.horizon(file, horizon)?;
        f.number(file, &format!("{row}/{method}/agents/{class}/recall_{at}"))
    };
    let moving = |f: &mut Figures, method: &str| -> Result<String, ReadmeError> {
        Ok(format!(
            "{:.2} / {:.2}",
            recall(f, 1.0, method, "moving_vehicles", "1m")?,
            recall(f, 3.0, method, "moving_vehicles", "1m")?
        ))
    };
    let (model, warp, oracle) = (
        moving(f, "model")?,
        moving(f, "latent_ego_warp")?,
        moving(f, "oracle")?,
    );
    let parked = |f: &mut Figures, method: &str| recall(f, 1.0, method, "parked_vehicles", "0.5m");
    Ok((
        "The agents in those forecasts (the true sweep split by the dataset's boxes)".into(),
        format!(
            "moving vehicles, recall@1 m at 1 / 3 s: {model} against `latent_ego_warp` {warp} and the tokenizer's floor {oracle}; parked vehicles, recall@0.5 m at 1 s: {:.2} against the raw ego warp's {:.2} (floor {:.2})",
            parked(f, "model")?,
            parked(f, "ego_warp")?,
            parked(f, "oracle")?
        ),
        "[forecast.md](bench/results/forecast.md)",
    ))
}

/// The tokenizer's floor on vehicles (its render of the true sweep, `eval tokenizer`), shipped
/// and with the vehicle fine-tune, on the world model's test scenes.
fn tokenizer_floor(f: &mut Figures) -> Result<Row, ReadmeError> {
    let (shipped, vehicles) = (
        "tokenizer-floor-test-shipped",
        "tokenizer-floor-test-vehicles",
    );
    let recall = |f: &mut Figures, file: &str, class: &str, at: &str| {
        f.number(
            file,
            &format!("/agents/{class}/over_scenes/recall_{at}/mean"),
        )
    };
    Ok((
        format!(
            "The tokenizer's floor on vehicles: its render of the true sweep, test scenes ({} keyframes)",
            f.count(shipped, "/frames")?
        ),
        format!(
            "parked vehicles within 0.5 m: {:.2} shipped, {:.2} with a quarter of the LiDAR rays on vehicles (a fine-tune, not shipped); moving vehicles within 1 m: {:.2} and {:.2}; PSNR {:.2} and {:.2} dB",
            recall(f, shipped, "parked_vehicles", "0.5m")?,
            recall(f, vehicles, "parked_vehicles", "0.5m")?,
            recall(f, shipped, "moving_vehicles", "1m")?,
            recall(f, vehicles, "moving_vehicles", "1m")?,
            f.number(shipped, "/psnr_db")?,
            f.number(vehicles, "/psnr_db")?,
        ),
        "[tokenizer-vehicles.md](bench/results/tokenizer-vehicles.md)",
    ))
}

/// Cars moved as rigid latent patches on the vehicle pair's forecast, on the world model's
/// test scenes: by their true future boxes (`latent_box_warp` on the model, a bound) and by
/// the weighted detector's velocity (`model_with_agents`, the agent layer).
fn agents_moved(f: &mut Figures) -> Result<Row, ReadmeError> {
    let (bound, layer) = (
        "agents-bound-test-vehicles-on-model",
        "agents-test-vehicles-moving-velocity",
    );
    let moving = "agents/moving_vehicles/over_scenes/recall_1m/mean";
    let pair = |f: &mut Figures, file: &str, method: &str| -> Result<String, ReadmeError> {
        let mut cells = Vec::new();
        for horizon in [1.0, 3.0] {
            let row = f.horizon(file, horizon)?;
            cells.push(format!(
                "{:.2}",
                f.number(file, &format!("{row}/{method}/{moving}"))?
            ));
        }
        Ok(cells.join(" / "))
    };
    Ok((
        format!(
            "Cars carried as rigid latent patches on the forecast (vehicle tokenizer, not shipped), test scenes ({} contexts)",
            f.count(layer, "/contexts")?
        ),
        format!(
            "moving vehicles within 1 m at 1 / 3 s: {} carried to their true future boxes (a bound), {} by a detector's velocity (the agent layer), {} the forecast alone, {} the latent ego warp (floor {})",
            pair(f, bound, "latent_box_warp")?,
            pair(f, layer, "model_with_agents")?,
            pair(f, layer, "model")?,
            pair(f, layer, "latent_ego_warp")?,
            pair(f, layer, "oracle")?,
        ),
        "[agents.md](bench/results/agents.md)",
    ))
}

/// An action-control run (`eval control --json`): `scenes` says which branched scenes.
fn control(
    f: &mut Figures,
    file: &'static str,
    scenes: &str,
    page: &'static str,
) -> Result<Row, ReadmeError> {
    let accuracy = f.number(file, "/accuracy")?;
    Ok((
        format!(
            "Action control, {scenes} ({} contexts, {} manoeuvres)",
            f.count(file, "/contexts")?,
            f.count(file, "/manoeuvres")?
        ),
        format!(
            "{:.0}% of {} pairs closest to their own truth at {} s, swap ratio {:.2} (target 90%: {})",
            100.0 * accuracy,
            f.count(file, "/pairs")?,
            f.number(file, "/horizon_s")?,
            f.number(file, "/swap_ratio")?,
            verdict(accuracy >= 0.9)
        ),
        page,
    ))
}

fn devkit(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "nuscenes-devkit";
    Ok((
        format!(
            "The synthetic world in the official {}",
            f.text(file, "/devkit")?
        ),
        format!(
            "loads as a nuScenes folder does; its `points_in_box` finds each box's recorded `num_lidar_pts` in {} of {} boxes",
            f.count(file, "/num_lidar_pts_equal_to_points_in_box")?,
            f.count(file, "/boxes")?
        ),
        "[nuscenes-devkit.md](bench/results/nuscenes-devkit.md)",
    ))
}

fn detection_metrics(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "detection-devkit-pipeline";
    let difference = f.number(file, "/largest_difference")?;
    Ok((
        format!(
            "`eval detector` against the official {} on a synthetic set",
            f.text(file, "/devkit")?
        ),
        format!(
            "NDS {:.4} ours, {:.4} the devkit's; largest difference in mAP, NDS and the errors {difference:.1e} over {} keyframes (target ≤ 1e-9: {})",
            f.number(file, "/our_scores/nd_score")?,
            f.number(file, "/devkit_scores/nd_score")?,
            f.count(file, "/set/samples")?,
            verdict(difference <= 1e-9)
        ),
        "[detection-metrics.md](bench/results/detection-metrics.md)",
    ))
}

/// The first arm of `downstream.json` that `wanted` accepts (`what` names it in the error).
fn downstream_arm<'a>(
    arms: &'a Value,
    path: &Path,
    what: &str,
    wanted: impl Fn(&Value) -> bool,
) -> Result<&'a Value, ReadmeError> {
    arms.as_array()
        .into_iter()
        .flatten()
        .find(|a| wanted(a))
        .ok_or_else(|| ReadmeError::Missing {
            path: path.to_path_buf(),
            pointer: format!("/arms ({what})"),
        })
}

/// A figure of one arm.
fn arm_figure(arm: &Value, path: &Path, pointer: &str) -> Result<f64, ReadmeError> {
    arm.pointer(pointer)
        .and_then(Value::as_f64)
        .ok_or_else(|| ReadmeError::Missing {
            path: path.to_path_buf(),
            pointer: format!("/arms/…{pointer}"),
        })
}

/// The detection and motion heads on frozen features: NDS per input and frames, and the
/// issue's targets computed from them.
fn downstream(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "downstream";
    let arms = f.value(file, "/arms")?;
    let path = f.path(file);
    let arm = |input: &str, frames: u64| {
        downstream_arm(
            &arms,
            &path,
            &format!("frozen {input}, {frames} frames"),
            |a| {
                a["input"] == input
                    && a["frames"] == frames
                    && a["init"] == "frozen"
                    && a["table"] != "pretrain"
            },
        )
    };
    let figure = |arm: &Value, pointer: &str| arm_figure(arm, &path, pointer);
    let mut cells = Vec::new();
    let mut best_tokenizer: f64 = 0.0;
    let mut best_stats: f64 = 0.0;
    let mut two_frames_better = true;
    let mut motion_beats_constant = true;
    for input in ["bev_stats", "latent", "feature"] {
        let (one, two) = (arm(input, 1)?, arm(input, 2)?);
        let (nds_1, nds_2) = (figure(one, "/nds")?, figure(two, "/nds")?);
        cells.push(format!("{input} {nds_1:.3} / {nds_2:.3}"));
        let best = nds_1.max(nds_2);
        if input == "bev_stats" {
            best_stats = best;
        } else {
            best_tokenizer = best_tokenizer.max(best);
        }
        two_frames_better &= figure(two, "/tp_errors/vel_err")?
            < figure(one, "/tp_errors/vel_err")?
            && figure(two, "/motion/min_ade")? < figure(one, "/motion/min_ade")?;
        for a in [one, two] {
            motion_beats_constant &= figure(a, "/motion/min_ade")?
                < figure(a, "/motion/constant_velocity_ade")?
                && figure(a, "/motion/min_fde")? < figure(a, "/motion/constant_velocity_fde")?;
        }
    }
    let gain = best_tokenizer / best_stats - 1.0;
    let latent_two = arm("latent", 2)?;
    Ok((
        format!(
            "Detection and motion heads on frozen features, held-out test scenes ({} keyframes, {} steps per arm)",
            figure(latent_two, "/keyframes")?,
            figure(latent_two, "/steps")?
        ),
        format!(
            "NDS one / two frames: {}; the tokenizer's best over the pillar statistics' {:+.0}% (target +20%: {}); two frames better in mAVE and minADE on every input: {}; minADE {:.2} m against constant velocity's {:.2} m (latent, two frames; the motion head beats it on every arm: {})",
            cells.join(", "),
            100.0 * gain,
            verdict(gain >= 0.2),
            verdict(two_frames_better),
            figure(latent_two, "/motion/min_ade")?,
            figure(latent_two, "/motion/constant_velocity_ade")?,
            verdict(motion_beats_constant),
        ),
        "[downstream.md](bench/results/downstream.md)",
    ))
}

/// The paper's pretraining comparison at our scale: the encoder trained with the heads from
/// the tokenizer's weights against from scratch, on the fused feature, one and two frames.
fn pretraining(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "downstream";
    let arms = f.value(file, "/arms")?;
    let path = f.path(file);
    let arm = |init: &str, frames: u64| {
        downstream_arm(
            &arms,
            &path,
            &format!("pretrain {init}, {frames} frames"),
            |a| a["table"] == "pretrain" && a["init"] == init && a["frames"] == frames,
        )
    };
    let figure = |arm: &Value, pointer: &str| arm_figure(arm, &path, pointer);
    let mut cells = Vec::new();
    let mut pays = true;
    for frames in [1, 2] {
        let (scratch, tokenizer, frozen) = (
            arm("scratch", frames)?,
            arm("tokenizer", frames)?,
            arm("frozen", frames)?,
        );
        let (nds_0, nds, map_0, map) = (
            figure(scratch, "/nds")?,
            figure(tokenizer, "/nds")?,
            figure(scratch, "/map")?,
            figure(tokenizer, "/map")?,
        );
        pays &= nds >= 1.1 * nds_0 && map >= 1.1 * map_0;
        cells.push(format!(
            "{frames} frame(s): scratch {nds_0:.3}, tokenizer {nds:.3} ({:+.0}% NDS, {:+.0}% mAP), frozen {:.3}",
            100.0 * (nds / nds_0 - 1.0),
            100.0 * (map / map_0 - 1.0),
            figure(frozen, "/nds")?,
        ));
    }
    let one = arm("tokenizer", 1)?;
    Ok((
        format!(
            "The paper's pretraining comparison: the encoder trained with the heads, held-out test scenes ({} keyframes, {} steps per arm)",
            figure(one, "/keyframes")?,
            figure(one, "/steps")?
        ),
        format!(
            "NDS {}; the tokenizer's weights beat scratch by ≥ 10% NDS and mAP in both modes: {}",
            cells.join("; "),
            verdict(pays)
        ),
        "[downstream.md](bench/results/downstream.md)",
    ))
}

/// The latent detector on the world model's forecast latents at +1 s and +3 s.
fn forecast_detection(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "forecast-detection";
    let mut cells = Vec::new();
    let mut met = false;
    for (k, horizon) in [(0, "1"), (1, "3")] {
        let map =
            |f: &mut Figures, method: &str| f.number(file, &format!("/horizons/{k}/{method}/map"));
        let (forecast, warp, truth) = (
            map(f, "forecast")?,
            map(f, "latent_ego_warp")?,
            map(f, "true_latent")?,
        );
        if k == 0 {
            met = forecast >= 0.8 * truth && forecast > warp;
        }
        cells.push(format!(
            "+{horizon} s: forecast {forecast:.3}, `latent_ego_warp` {warp:.3}, the true future latent {truth:.3}"
        ));
    }
    let measured_on = f
        .text(file, "/measured_on")
        .map(|on| format!(", measured on {on}"))
        .unwrap_or_default();
    Ok((
        format!(
            "The latent detector on the world model's forecasts, held-out test scenes ({} forecasts{measured_on}), mAP",
            f.count(file, "/windows")?
        ),
        format!(
            "{}; at +1 s at least 0.8× the true latent's and above the ego warp's: {}",
            cells.join("; "),
            verdict(met)
        ),
        "[downstream.md](bench/results/downstream.md)",
    ))
}

fn lidar_depth(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "lidar_depth-synth-val";
    let last = f.count(file, "/by_range")?.saturating_sub(1);
    Ok((
        "Rendered LiDAR depth, by range (validation scenes)".into(),
        format!(
            "mean error {:.2} m at {} m to {:.1} m at {} m",
            f.number(file, "/by_range/0/mean_abs_error_m")?,
            f.text(file, "/by_range/0/range_m")?,
            f.number(file, &format!("/by_range/{last}/mean_abs_error_m"))?,
            f.text(file, &format!("/by_range/{last}/range_m"))?
        ),
        "[lidar_depth-synth-val.md](bench/results/lidar_depth-synth-val.md)",
    ))
}

fn inference(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "tokenizer";
    Ok((
        "Tokenizer inference (tiny, real keyframe, 2 cores)".into(),
        format!(
            "encoder {:.0} ms with its input preparation, voxel lift {:.0} ms, dense render {:.0} ms, with empty-space skipping {:.0} ms",
            f.number(file, "/encoder_ms_p50")?,
            f.number(file, "/lift_ms_p50")?,
            f.number(file, "/render_dense_ms_p50")?,
            f.number(file, "/render_skipping/0/ms_p50")?
        ),
        "[tokenizer.md](bench/results/tokenizer.md)",
    ))
}

fn vs_pytorch(f: &mut Figures, kinds: &[&str]) -> Result<Row, ReadmeError> {
    let mut parts = Vec::new();
    for kind in kinds {
        let file = format!("vs-pytorch-{kind}");
        let file = file.as_str();
        let mut pairs = Vec::new();
        let mut behind = Vec::new();
        for (name, ours, eager) in [
            ("encoder", "/ours/2/encoder_ms", "/torch/eager/2/encoder_ms"),
            ("lift", "/ours/2/lift_ms", "/torch/eager/2/lift_ms"),
            (
                "dense render",
                "/ours/2/render_dense_ms",
                "/torch/eager/2/render_dense_ms",
            ),
            (
                "world-model pass",
                "/ours/world_model/2",
                "/torch/eager/2/world_model_ms",
            ),
        ] {
            let (ours, eager) = (f.number(file, ours)?, f.number(file, eager)?);
            pairs.push(format!("{name} {ours:.1} / {eager:.1} ms"));
            if ours > eager {
                behind.push(name);
            }
        }
        let verdict = if behind.is_empty() {
            "parity met".to_string()
        } else {
            format!("parity **missed** for the {}", behind.join(", "))
        };
        // A record without its commit was measured before the world model's packed attention.
        let era = if f.file(file)?.get("commit").is_some() {
            ""
        } else {
            " (measured before the packed attention)"
        };
        parts.push(format!(
            "{}{era}: {}; {verdict}",
            f.text(file, "/machine/cpu")?,
            pairs.join(", ")
        ));
    }
    Ok((
        "Beside PyTorch eager on the same 2 cores (same weights, outputs checked equal first), ours / eager, 2 threads".into(),
        parts.join(". "),
        "[vs-pytorch.md](bench/results/vs-pytorch.md)",
    ))
}

fn runtime(f: &mut Figures) -> Result<Row, ReadmeError> {
    Ok((
        "Runtime".into(),
        format!(
            "{:.2} M small messages/s through 5 nodes; a hop {:.0} µs p50",
            f.number("runtime", "/small/msgs_per_s")? / 1e6,
            f.number("runtime", "/small/paced_hop_p50_us")?
        ),
        "[runtime.md](bench/results/runtime.md)",
    ))
}

fn sensors(f: &mut Figures) -> Result<Row, ReadmeError> {
    Ok((
        "Sensor replay".into(),
        format!(
            "nuScenes frames (6 JPEGs + sweep) at {:.1} Hz",
            f.number("sensors", "/nuscenes_graph_hz")?
        ),
        "[sensors.md](bench/results/sensors.md)",
    ))
}

fn pillarize(f: &mut Figures) -> Result<Row, ReadmeError> {
    Ok((
        "Pillarization".into(),
        format!(
            "{:.2} ms per nuScenes sweep, one core",
            f.number("pillarize", "/nuscenes-sample/sparse_us_p50")? / 1e3
        ),
        "[pillarize.md](bench/results/pillarize.md)",
    ))
}

fn speed_vs_error(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "speed-vs-error";
    let last = f.count(file, "/steps")?.saturating_sub(1);
    let point = |f: &mut Figures, i: usize| -> Result<String, ReadmeError> {
        Ok(format!(
            "{}: {:.0} ms per forecast, Chamfer {:.2} / {:.2} m² at 1 / 3 s",
            counted(f.count(file, &format!("/steps/{i}/steps"))?, "DDIM step"),
            f.number(file, &format!("/steps/{i}/latency_ms/rollout_p50"))?,
            f.number(file, &format!("/steps/{i}/chamfer_1s"))?,
            f.number(file, &format!("/steps/{i}/chamfer_3s"))?
        ))
    };
    let (first, most) = (point(f, 0)?, point(f, last)?);
    let measured_on = f
        .text(file, "/measured_on")
        .map(|on| format!("; measured on {on}"))
        .unwrap_or_default();
    Ok((
        format!(
            "Speed against error, held-out scenes ({} contexts{measured_on})",
            f.count(file, "/steps/0/contexts")?
        ),
        format!("{first}; {most}"),
        "[speed-vs-error.md](bench/results/speed-vs-error.md)",
    ))
}

fn binary_size(f: &mut Figures) -> Result<Row, ReadmeError> {
    Ok((
        "What a user installs (`cargo build --profile dist`)".into(),
        format!(
            "a {:.0} MB binary ({}), against {:.0} MB from `--release` with line tables",
            f.number("binary-size", "/dist_bytes")? / 1e6,
            f.text("binary-size", "/backends")?,
            f.number("binary-size", "/release_bytes")? / 1e6
        ),
        "[binary-size.md](bench/results/binary-size.md)",
    ))
}

fn nuscenes_fit(f: &mut Figures) -> Result<Row, ReadmeError> {
    // The fit's validation rows in its metrics log; the last is the shipped figure.
    let path = f.dir.join("tokenizer-fit-nuscenes-metrics.csv");
    let failed = |message: String| ReadmeError::File {
        path: path.clone(),
        message,
    };
    let text = std::fs::read_to_string(&path).map_err(|e| failed(e.to_string()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| failed("empty".into()))?
        .split(',')
        .collect();
    let column = |name: &str| {
        header
            .iter()
            .position(|c| *c == name)
            .ok_or_else(|| failed(format!("no column `{name}`")))
    };
    let (phase, step) = (column("phase")?, column("step")?);
    let (psnr, ssim, chamfer) = (column("psnr_db")?, column("ssim")?, column("chamfer_m2")?);
    let last = lines
        .map(|line| line.split(',').collect::<Vec<_>>())
        .rfind(|cells| cells.get(phase) == Some(&"val"))
        .ok_or_else(|| failed("no validation row".into()))?;
    let number = |i: usize| -> Result<f64, ReadmeError> {
        last.get(i)
            .and_then(|cell| cell.parse::<f64>().ok())
            .ok_or_else(|| failed(format!("the last validation row has no `{}`", header[i])))
    };
    let (p, c) = (number(psnr)?, number(chamfer)?);
    Ok((
        "One real nuScenes keyframe, a tiny tokenizer fitted to it".into(),
        format!(
            "{p:.2} dB, {:.3} SSIM, {c:.3} m² after {} steps; targets 25 dB ({}) and 0.2 m² ({})",
            number(ssim)?,
            number(step)?,
            verdict(p >= 25.0),
            verdict(c <= 0.2)
        ),
        "[tokenizer-training.md](bench/results/tokenizer-training.md)",
    ))
}

fn long_rollout(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "long-rollout";
    let interval = f.number(file, "/interval_s")?;
    let methods = f.value(file, "/methods")?;
    let index = |name: &str| {
        methods
            .as_array()
            .and_then(|m| m.iter().position(|v| v == name))
            .ok_or_else(|| ReadmeError::Missing {
                path: f.path(file),
                pointer: format!("/methods (`{name}`)"),
            })
    };
    let (model, warp) = (index("model")?, index("latent_ego_warp")?);
    let mut cells = |method: usize| -> Result<String, ReadmeError> {
        let mut cells = Vec::new();
        for seconds in [0.5, 3.0, 10.0, 20.0] {
            let frame = (seconds / interval).round() as usize - 1;
            cells.push(format!(
                "{:.2}",
                f.number(file, &format!("/mean_l1/{method}/{frame}"))?
            ));
        }
        Ok(cells.join(" / "))
    };
    let (ours, theirs) = (cells(model)?, cells(warp)?);
    let measured_on = f
        .text(file, "/measured_on")
        .map(|on| format!(" (measured on {on})"))
        .unwrap_or_default();
    Ok((
        format!("A 20 s autoregressive rollout, held-out scenes{measured_on}"),
        format!(
            "latent L1 {ours} at +0.5 / 3 / 10 / 20 s, against the chained `latent_ego_warp` {theirs}"
        ),
        "[long-rollout.md](bench/results/long-rollout.md)",
    ))
}

fn memory(f: &mut Figures) -> Result<Row, ReadmeError> {
    let file = "memory";
    let size = |f: &mut Figures, name: &str| -> Result<String, ReadmeError> {
        for i in 0..f.count(file, "")? {
            if f.text(file, &format!("/{i}/size"))? == name {
                return Ok(format!("/{i}"));
            }
        }
        Err(ReadmeError::Missing {
            path: f.path(file),
            pointer: format!("/*/size = {name}"),
        })
    };
    let (tiny, paper) = (size(f, "tiny")?, size(f, "paper")?);
    Ok((
        "World model memory".into(),
        format!(
            "one forecast peaks at {:.0} MiB (tiny) and {:.1} GiB (paper size); a tiny training step at {:.0} MiB",
            f.number(file, &format!("{tiny}/forecast_peak_mib"))?,
            f.number(file, &format!("{paper}/forecast_peak_mib"))? / 1024.0,
            f.number(file, &format!("{tiny}/training_step_peak_mib"))?
        ),
        "[memory.md](bench/results/memory.md)",
    ))
}

/// The README's results table from the result files in `dir`.
pub fn results_table(dir: &Path) -> Result<String, ReadmeError> {
    let mut f = Figures::new(dir);
    let rows = [
        tokenizer(&mut f)?,
        nuscenes_fit(&mut f)?,
        world_model(&mut f)?,
        forecast(
            &mut f,
            "forecast-test",
            "Forecasts rendered in the graph, held-out test scenes",
        )?,
        forecast(
            &mut f,
            "forecast-demo",
            "The same on the demo scene of the first command",
        )?,
        agents(&mut f)?,
        tokenizer_floor(&mut f)?,
        agents_moved(&mut f)?,
        control(
            &mut f,
            "control-test",
            "branched held-out scenes",
            "[forecast.md](bench/results/forecast.md)",
        )?,
        control(
            &mut f,
            "control6-fresh-stop",
            "branched scenes no run had seen, `stop` among the manoeuvres",
            "[world-model-training.md](bench/results/world-model-training.md)",
        )?,
        devkit(&mut f)?,
        detection_metrics(&mut f)?,
        downstream(&mut f)?,
        pretraining(&mut f)?,
        forecast_detection(&mut f)?,
        lidar_depth(&mut f)?,
        inference(&mut f)?,
        vs_pytorch(&mut f, &["amd-epyc-avx512", "intel-xeon-avx512"])?,
        runtime(&mut f)?,
        sensors(&mut f)?,
        pillarize(&mut f)?,
        speed_vs_error(&mut f)?,
        long_rollout(&mut f)?,
        memory(&mut f)?,
        binary_size(&mut f)?,
    ];
    let mut table = vec![
        "| what | figure | details |".to_string(),
        "|---|---|---|".to_string(),
    ];
    for (what, figure, details) in rows {
        table.push(format!("| {what} | {figure} | {details} |"));
    }
    Ok(table.join("\n"))
}

/// `readme` with the text between the markers replaced by `table`.
pub fn with_table(readme: &str, table: &str, path: &Path) -> Result<String, ReadmeError> {
    let markers = |message: &str| ReadmeError::Markers {
        path: path.to_path_buf(),
        message: message.to_string(),
    };
    let start = readme
        .find(BEGIN)
        .ok_or_else(|| markers("no line that begins the generated results"))?;
    let end = readme
        .find(END)
        .ok_or_else(|| markers("no line that ends the generated results"))?;
    if end < start {
        return Err(markers("the results' end comes before their beginning"));
    }
    Ok(format!(
        "{}{BEGIN}\n{table}\n{}",
        &readme[..start],
        &readme[end..]
    ))
}

/// The workspace's README.
pub fn readme_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_readme_quotes_the_figures_of_the_result_files() {
        let path = readme_path();
        let readme = std::fs::read_to_string(&path).expect("README.md");
        let table = results_table(&crate::results_dir()).expect("every figure the table quotes");
        let expected = with_table(&readme, &table, &path).expect("markers");
        assert!(
            readme == expected,
            "README.md's results differ from bench/results/*.json: run \
             `cargo run --release -p bevworld-bench --bin readme_results -- --write`"
        );
    }

    #[test]
    fn a_missing_figure_names_its_file_and_place() {
        let dir = tempfile::tempdir().expect("dir");
        std::fs::write(
            dir.path().join("tokenizer-test-tokenizer-tiny.json"),
            "{\"test\": {}}",
        )
        .expect("write");
        let error = results_table(dir.path()).expect_err("no figures");
        let text = error.to_string();
        assert!(
            text.contains("tokenizer-test-tokenizer-tiny.json") && text.contains("/test/psnr_db"),
            "{text}"
        );
    }

    #[test]
    fn a_readme_without_markers_is_refused() {
        let error =
            with_table("# readme\n", "| t |", Path::new("README.md")).expect_err("no markers");
        assert!(error.to_string().contains("README.md"), "{error}");
    }
}
