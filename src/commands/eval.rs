//! `bevworld eval`: the Chamfer distance between two clouds, and the two forecasting baselines
//! every world model must beat.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use bevworld_metrics::{InceptionExtractor, Roi, chamfer_in_roi};
use bevworld_sensors::lidar_file::{LidarLayout, NonFinitePolicy, decode_points};
use bevworld_sensors::{Dataset, DatasetFormat, DatasetOptions};
use bevworld_types::{PointCloud, Pose};
use clap::{Args, Subcommand, ValueEnum};
use glam::DVec3;

#[derive(Subcommand)]
pub enum EvalCommand {
    /// Chamfer distance between a predicted and a ground-truth cloud (x, y, z only).
    Chamfer(ChamferArgs),
    /// Chamfer distance of the copy_last and ego_warp forecasts at several horizons.
    Baselines(BaselinesArgs),
    /// FID between two folders of images, with user-supplied InceptionV3 weights.
    Fid(FidArgs),
    /// The world model's forecasts on held-out synthetic scenes: the standardised latent L1
    /// per horizon beside copy-last and ego-warp, mean and spread over scenes.
    WorldModel(WorldModelEvalArgs),
    /// Forecasts rendered and scored on every context of a dataset, per horizon, beside the
    /// latent baselines, the tokenizer's floor (`oracle`) and the raw-point baselines: runs
    /// the forecast graph with the log's own future actions.
    Forecast(ForecastEvalArgs),
    /// Whether forecasts follow their actions: on a branched synthetic dataset, each
    /// manoeuvre's forecast against every manoeuvre's ground truth.
    Control(crate::commands::control::ControlEvalArgs),
    /// The tokenizer's reconstructions of every keyframe of a dataset: camera PSNR and SSIM
    /// and LiDAR Chamfer, each scene's mean and the spread over scenes; runs the reconstruct
    /// graph.
    Tokenizer(crate::commands::reconstruction_eval::TokenizerEvalArgs),
    /// A detector's boxes (`results_nusc.json`) against a dataset's annotations, with the
    /// nuScenes detection metrics as the official devkit computes them: per class AP and
    /// true-positive errors, mAP and NDS.
    Detector(crate::commands::detector_eval::DetectorEvalArgs),
}

#[derive(Args)]
pub struct ForecastEvalArgs {
    /// The dataset (nuScenes layout, e.g. a `bevworld synth` folder).
    #[arg(long)]
    pub data: PathBuf,
    /// The forecast graph to run (its `rollout`, `views`, `files` and `scores` nodes).
    #[arg(long, default_value = "configs/graphs/forecast.yaml")]
    pub graph: PathBuf,
    /// DDIM steps (default: the graph's).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Draws of the model per forecast, K (default: the graph's, one). Beside the point
    /// forecast (draw 0), the table gains each draw's mean and the best of the first 4, 8, …
    /// and K draws. Each draw is a sampling run and a render: with `--set sensors=[lidar]`
    /// only the sweeps, which the Chamfer and the agent scores read, are rendered.
    #[arg(long)]
    pub samples: Option<usize>,
    /// Horizons in seconds, e.g. 0.5,1,3 (default: the graph's).
    #[arg(long, value_delimiter = ',')]
    pub horizons: Vec<f64>,
    #[arg(long, value_enum, default_value = "4docc")]
    pub roi: RoiName,
    /// Where the rendered forecasts are written.
    #[arg(long, default_value = "out/eval-forecast")]
    pub out: PathBuf,
    /// Draw the Chamfer distance against the horizon, one line per method.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Print one JSON object: contexts, steps, ms_per_forecast and per horizon each method's
    /// chamfer, psnr_db, ssim and latent_l1.
    #[arg(long)]
    pub json: bool,
    /// Further `node.key=value` overrides of the graph, as `run --set`, applied after the
    /// command's own: e.g. `rollout.shrink=null` samples without the residual shrink.
    #[arg(long = "set", value_name = "TARGET=VALUE")]
    pub set: Vec<String>,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Split {
    /// The validation scenes, which training was tuned on.
    Val,
    /// The test scenes, touched only for a reported figure.
    Test,
}

#[derive(Args)]
pub struct WorldModelEvalArgs {
    /// The training config the weights were made with (model, tokenizer, caches).
    #[arg(long, default_value = "configs/models/train-world-model-tiny.yaml")]
    pub config: PathBuf,
    #[arg(long, default_value = "nodes/world_model/weights/world-model-tiny.bpk")]
    pub weights: PathBuf,
    /// The model config of the weights (default: the training config's `model`); an
    /// ablation run's own is RUN/model-config.yaml.
    #[arg(long)]
    pub model: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "val")]
    pub split: Split,
    /// DDIM steps (default: the config's validation sampler's).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Noise seed of the sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Keep every n-th window of each scene.
    #[arg(long, default_value_t = 1)]
    pub stride: usize,
    /// Print one JSON object with the per-horizon means, spreads and per-scene scores.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args)]
pub struct FidArgs {
    /// Folder of generated images (.png, .jpg).
    #[arg(long)]
    pub pred: PathBuf,
    /// Folder of reference images.
    #[arg(long)]
    pub gt: PathBuf,
    /// pytorch-fid's pt_inception-2015-12-05-6726825d.pth, or a .safetensors copy. Without it
    /// there is no FID: the command says so and fails.
    #[arg(long)]
    pub inception: Option<PathBuf>,
    /// Print one JSON object: {"fid", "pred_images", "gt_images"}.
    #[arg(long)]
    pub json: bool,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum RoiName {
    /// |x|, |y| <= 70 m, |z| <= 4.5 m (4D-Occ, Copilot4D).
    #[value(name = "4docc")]
    FourDOcc,
    /// [-51.2, 51.2] x [-51.2, 51.2] x [-5, 3] m (ViDAR).
    Vidar,
}

impl RoiName {
    fn roi(self) -> Roi {
        match self {
            RoiName::FourDOcc => Roi::FOUR_D_OCC,
            RoiName::Vidar => Roi::VIDAR,
        }
    }

    /// The preset's name in a graph's parameters.
    pub fn preset(self) -> &'static str {
        match self {
            RoiName::FourDOcc => "4docc",
            RoiName::Vidar => "vidar",
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum CloudFormat {
    /// PLY with x, y, z properties.
    Ply,
    /// nuScenes .pcd.bin, float32 x 5.
    Nuscenes,
    /// KITTI .bin, float32 x 4.
    Kitti,
}

#[derive(Args)]
pub struct ChamferArgs {
    #[arg(long)]
    pub pred: PathBuf,
    #[arg(long)]
    pub gt: PathBuf,
    #[arg(long, value_enum, default_value = "4docc")]
    pub roi: RoiName,
    /// Override the format chosen from the file extension.
    #[arg(long, value_enum)]
    pub format: Option<CloudFormat>,
    /// Print one JSON object: {"chamfer", "pred_points", "gt_points"} (counts after the ROI).
    #[arg(long)]
    pub json: bool,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum BaselineFormat {
    Kitti,
    Nuscenes,
    Synth,
}

#[derive(Args)]
pub struct BaselinesArgs {
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long, value_enum)]
    pub format: BaselineFormat,
    /// Horizons in frames ahead of each scene's first frame, e.g. 1,3,5.
    #[arg(long, value_delimiter = ',', default_value = "1,3,5")]
    pub horizons: Vec<usize>,
    #[arg(long, value_enum, default_value = "4docc")]
    pub roi: RoiName,
    /// Count horizons in 12 Hz sweeps instead of 2 Hz keyframes (nuScenes layout).
    #[arg(long)]
    pub sweeps: bool,
    /// Print a JSON list of {method, horizon_frames, chamfer}.
    #[arg(long)]
    pub json: bool,
}

pub fn run(command: &EvalCommand) -> Result<ExitCode> {
    match command {
        EvalCommand::Chamfer(args) => chamfer_command(args),
        EvalCommand::Forecast(args) => forecast_command(args),
        EvalCommand::Control(args) => crate::commands::control::run(args),
        EvalCommand::Baselines(args) => baselines_command(args),
        EvalCommand::Fid(args) => fid_command(args),
        EvalCommand::WorldModel(args) => world_model(args),
        EvalCommand::Tokenizer(args) => crate::commands::reconstruction_eval::run(args),
        EvalCommand::Detector(args) => crate::commands::detector_eval::run(args),
    }
}

/// The images of a folder, sorted by name.
fn read_images(dir: &Path) -> Result<Vec<image::RgbImage>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading image folder {}", dir.display()))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|path| {
            matches!(
                path.extension()
                    .and_then(|e| e.to_str())
                    .map(str::to_ascii_lowercase)
                    .as_deref(),
                Some("png" | "jpg" | "jpeg")
            )
        })
        .collect();
    paths.sort();
    if paths.len() < 2 {
        bail!(
            "{}: FID needs at least 2 images (.png, .jpg), found {}",
            dir.display(),
            paths.len()
        );
    }
    paths
        .iter()
        .map(|path| {
            Ok(image::open(path)
                .with_context(|| format!("decoding image {}", path.display()))?
                .to_rgb8())
        })
        .collect()
}

fn fid_command(args: &FidArgs) -> Result<ExitCode> {
    let (_, device) = bevworld_device::from_env()?;
    // The weights are checked first: without them nothing else is worth reading.
    let extractor = InceptionExtractor::from_weights(args.inception.as_deref(), device)?;
    let pred = read_images(&args.pred)?;
    let gt = read_images(&args.gt)?;
    let fid = extractor.fid(&pred, &gt)?;
    if args.json {
        println!(
            "{}",
            serde_json::json!({"fid": fid, "pred_images": pred.len(), "gt_images": gt.len()})
        );
    } else {
        println!(
            "FID {fid:.4} ({} generated vs {} reference images, InceptionV3 pool3)",
            pred.len(),
            gt.len()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Reads a cloud's x, y, z by format (from the extension unless given).
pub fn read_cloud(path: &Path, format: Option<CloudFormat>) -> Result<Vec<[f64; 3]>> {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let format = match format {
        Some(format) => format,
        None if name.ends_with(".ply") => CloudFormat::Ply,
        None if name.ends_with(".pcd.bin") => CloudFormat::Nuscenes,
        None if name.ends_with(".bin") => CloudFormat::Kitti,
        None => bail!(
            "{}: cannot tell the format from the extension (.ply, .pcd.bin, .bin); pass --format",
            path.display()
        ),
    };
    match format {
        CloudFormat::Ply => Ok(bevworld_sinks::ply::read_ply(path)?
            .iter()
            .map(|p| [f64::from(p.x), f64::from(p.y), f64::from(p.z)])
            .collect()),
        CloudFormat::Nuscenes | CloudFormat::Kitti => {
            let layout = if matches!(format, CloudFormat::Nuscenes) {
                LidarLayout::NuScenes
            } else {
                LidarLayout::Kitti
            };
            let bytes =
                std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
            let (points, _) = decode_points(&bytes, layout, NonFinitePolicy::Drop, path)?;
            Ok(points
                .iter()
                .map(|p| [f64::from(p.x), f64::from(p.y), f64::from(p.z)])
                .collect())
        }
    }
}

fn chamfer_command(args: &ChamferArgs) -> Result<ExitCode> {
    let pred = read_cloud(&args.pred, args.format).context("--pred")?;
    let gt = read_cloud(&args.gt, args.format).context("--gt")?;
    let result = chamfer_in_roi(&pred, &gt, &args.roi.roi());
    // An empty cloud has no Chamfer distance: 0 would score predicting nothing as perfect.
    // Reported as empty, and the command fails, as the graph's metrics count such clouds.
    if result.pred_points == 0 || result.gt_points == 0 {
        let empty = match (result.pred_points, result.gt_points) {
            (0, 0) => "both",
            (0, _) => "pred",
            _ => "gt",
        };
        if args.json {
            println!(
                "{}",
                serde_json::json!({"chamfer": null, "empty": empty, "pred_points": result.pred_points, "gt_points": result.gt_points})
            );
        }
        bail!(
            "no Chamfer distance: {} predicted and {} ground-truth points in the ROI ({}); an empty cloud is not a perfect match",
            result.pred_points,
            result.gt_points,
            args.roi.preset()
        );
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({"chamfer": result.chamfer, "pred_points": result.pred_points, "gt_points": result.gt_points})
        );
    } else {
        println!(
            "chamfer {:.6} m^2 ({} predicted, {} ground-truth points in the ROI)",
            result.chamfer, result.pred_points, result.gt_points
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// A sweep's points moved by `target_from_lidar`.
fn moved(cloud: &PointCloud, target_from_lidar: &Pose) -> Vec<[f64; 3]> {
    cloud
        .points
        .iter()
        .map(|p| {
            target_from_lidar
                .transform_point3(DVec3::new(p.x.into(), p.y.into(), p.z.into()))
                .to_array()
        })
        .collect()
}

fn baselines_command(args: &BaselinesArgs) -> Result<ExitCode> {
    if args.horizons.is_empty() || args.horizons.contains(&0) {
        bail!("--horizons must be frame counts >= 1, e.g. 1,3,5");
    }
    let format = match args.format {
        BaselineFormat::Kitti => DatasetFormat::Kitti,
        BaselineFormat::Nuscenes => DatasetFormat::Nuscenes,
        BaselineFormat::Synth => DatasetFormat::Synth,
    };
    let options = DatasetOptions {
        format,
        sweeps: args.sweeps,
        skip_images: true,
        ..Default::default()
    };
    let dataset = Dataset::open(&args.data, &options)
        .with_context(|| format!("opening {}", args.data.display()))?;
    // Frames grouped by scene, in order.
    let names = dataset
        .scene_names()
        .into_iter()
        .map(str::to_string)
        .collect::<Vec<_>>();
    let mut scenes: Vec<(String, Vec<usize>)> = Vec::new();
    for (index, name) in names.iter().enumerate() {
        match scenes.last_mut() {
            Some((last, frames)) if last == name => frames.push(index),
            _ => scenes.push((name.clone(), vec![index])),
        }
    }
    let roi = args.roi.roi();
    let mut rows = Vec::new();
    for &horizon in &args.horizons {
        let (mut copy_sum, mut warp_sum, mut count) = (0.0, 0.0, 0usize);
        for (_, frames) in &scenes {
            let Some(&target_index) = frames.get(horizon) else {
                continue;
            };
            let first = dataset.read(frames[0]).context("reading the first frame")?;
            let target = dataset
                .read(target_index)
                .context("reading the target frame")?;
            // Evaluated in the target sweep's LiDAR frame, as 4D-Occ does.
            let gt: Vec<[f64; 3]> = moved(&target.lidar, &Pose::IDENTITY);
            let copy_last = moved(&first.lidar, &Pose::IDENTITY);
            let global_from_target_lidar =
                target.lidar.global_from_ego * target.lidar.ego_from_lidar;
            let global_from_first_lidar = first.lidar.global_from_ego * first.lidar.ego_from_lidar;
            let ego_warp = moved(
                &first.lidar,
                &(global_from_target_lidar.inverse() * global_from_first_lidar),
            );
            copy_sum += chamfer_in_roi(&copy_last, &gt, &roi).chamfer;
            warp_sum += chamfer_in_roi(&ego_warp, &gt, &roi).chamfer;
            count += 1;
        }
        if count == 0 {
            bail!(
                "no scene in {} has a frame {horizon} frames after its first ({} scene(s), longest {} frames)",
                args.data.display(),
                scenes.len(),
                scenes.iter().map(|(_, f)| f.len()).max().unwrap_or(0)
            );
        }
        rows.push(("copy_last", horizon, copy_sum / count as f64, count));
        rows.push(("ego_warp", horizon, warp_sum / count as f64, count));
    }
    if args.json {
        let list: Vec<serde_json::Value> = rows.iter().map(|(method, horizon, chamfer, _)| serde_json::json!({"method": method, "horizon_frames": horizon, "chamfer": chamfer})).collect();
        println!("{}", serde_json::Value::Array(list));
    } else {
        println!(
            "{:<10} {:>8} {:>14} {:>7}",
            "method", "horizon", "chamfer m^2", "scenes"
        );
        for (method, horizon, chamfer, count) in rows {
            println!("{method:<10} {horizon:>8} {chamfer:>14.4} {count:>7}");
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn world_model(args: &WorldModelEvalArgs) -> Result<ExitCode> {
    use bevworld_world_model_train::{TrainWorldModelConfig, evaluate};
    let config = TrainWorldModelConfig::from_yaml_file(&args.config)?;
    let cache = match args.split {
        Split::Val => config.val.clone(),
        Split::Test => config
            .test
            .clone()
            .with_context(|| format!("{} names no `test` cache", args.config.display()))?,
    };
    super::latent_cache::ensure(&cache, &config.tokenizer_model, &config.tokenizer_weights)?;
    let mut sampler = config.validation.sampler.clone();
    if let Some(steps) = args.steps {
        sampler.steps = steps;
    }
    sampler.seed = args.seed;
    let (_, device) = bevworld_device::from_env()?;
    let threads = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
    let model_config = bevworld_world_model::WorldModelConfig::from_yaml_file(
        args.model.as_ref().unwrap_or(&config.model),
    )?;
    let evaluation = evaluate(
        &config,
        &model_config,
        &args.weights,
        &cache,
        &sampler,
        args.stride,
        threads,
        &device,
    )?;
    if args.json {
        let scores = |s: &bevworld_world_model_train::HorizonScores| serde_json::json!({"world_model": s.forecast, "ego_warp": s.ego_warp, "copy_last": s.copy_last});
        let scenes: Vec<serde_json::Value> = evaluation
            .scenes
            .iter()
            .map(|(name, s)| serde_json::json!({"scene": name, "scores": scores(s)}))
            .collect();
        println!(
            "{}",
            serde_json::json!({
                "windows": evaluation.windows,
                "sampler_steps": sampler.steps,
                "mean": scores(&evaluation.mean),
                "spread": scores(&evaluation.spread),
                "scenes": scenes,
            })
        );
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{} windows of {} scenes, DDIM {} steps; standardised latent L1, mean ± spread over scenes",
        evaluation.windows,
        evaluation.scenes.len(),
        sampler.steps
    );
    println!(
        "{}",
        evaluation
            .mean
            .markdown(Some(&evaluation.spread), model_config.frame_interval_s)
    );
    Ok(ExitCode::SUCCESS)
}

/// Refuses a picture's path before any work: a folder, a missing folder, or a name that is
/// not `.png` would fail only after the whole evaluation.
pub fn check_picture_path(flag: &str, path: &Path) -> Result<()> {
    if path.is_dir() {
        return Err(super::refuse(format!(
            "{flag} {}: is a folder; give a file name ending in .png",
            path.display()
        )));
    }
    if path
        .extension()
        .is_none_or(|e| !e.eq_ignore_ascii_case("png"))
    {
        return Err(super::refuse(format!(
            "{flag} {}: pictures are written as PNG; give a file name ending in .png",
            path.display()
        )));
    }
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty())
        && !parent.is_dir()
    {
        return Err(super::refuse(format!(
            "{flag} {}: the folder {} does not exist",
            path.display(),
            parent.display()
        )));
    }
    Ok(())
}

fn forecast_command(args: &ForecastEvalArgs) -> Result<ExitCode> {
    if !args.data.is_dir() {
        return Err(super::refuse(format!(
            "--data {}: no such folder",
            args.data.display()
        )));
    }
    if let Some(path) = &args.plot {
        check_picture_path("--plot", path)?;
    }
    let roi = args.roi.preset();
    // By the names the graph exposes (`contracts::EVAL_FORECAST`), never its node ids.
    let mut set = vec![
        format!("data={}", args.data.display()),
        format!("out={}", args.out.display()),
        format!("scores_json={}", args.out.join("scores.json").display()),
        format!("roi={roi}"),
        "print_scores=false".into(),
        "actions=log".into(),
        "log_future=true".into(),
    ];
    if let Some(steps) = args.steps {
        set.push(format!("steps={steps}"));
    }
    if let Some(samples) = args.samples {
        set.push(format!("samples={samples}"));
    }
    if !args.horizons.is_empty() {
        let list: Vec<String> = args.horizons.iter().map(f64::to_string).collect();
        set.push(format!("horizons=[{}]", list.join(",")));
    }
    set.extend(args.set.iter().cloned());
    let contract = &super::contracts::EVAL_FORECAST;
    let mut graph = super::graph_run::build_bound(&args.graph, contract, &set)?;
    let scores = graph
        .collect::<bevworld_types::ScoreTable>("scores")
        .map_err(super::Refused::Graph)?;
    let sampler: Vec<(&str, serde_json::Value)> = ["steps", "samples", "shrink"]
        .into_iter()
        .map(|key| {
            (
                key,
                graph.spec.exposed_param(key).cloned().unwrap_or_default(),
            )
        })
        .collect();
    super::graph_run::run_built(graph)?;
    let mut table = scores
        .take()
        .pop()
        .map(|table| table.0.clone())
        .with_context(|| format!("{}: the scores sent no table", args.graph.display()))?;
    for (key, value) in sampler {
        table[key] = value;
    }
    if table["contexts"].as_u64() == Some(0) {
        bail!(
            "no context of {} has a logged future as long as the horizons: a context needs the model's history (one frame more than its condition frames) and the whole forecast after it",
            args.data.display()
        );
    }
    if let Some(path) = &args.plot {
        plot_forecast(path, &table)?;
    }
    if args.json {
        println!("{}", serde_json::to_string(&table)?);
    } else {
        let shrink = match &table["shrink"] {
            serde_json::Value::Object(s) => format!(
                ", residual shrink tau {} fading to 0 at {} s",
                s.get("tau").unwrap_or(&serde_json::Value::Null),
                s.get("fade_s").unwrap_or(&serde_json::Value::Null)
            ),
            _ => String::new(),
        };
        println!(
            "{} contexts, {} DDIM step(s){shrink}, {:.0} ms per forecast\n\n{}",
            table["contexts"],
            table["steps"],
            table["ms_per_forecast"].as_f64().unwrap_or(f64::NAN),
            bevworld_metrics::forecast_node::markdown_of(&table)
        );
        let agents = bevworld_metrics::forecast_node::agents_markdown_of(&table);
        if !agents.is_empty() {
            println!("The agents, from the dataset's boxes (means over scenes):\n\n{agents}");
        }
        let draws = bevworld_metrics::forecast_node::draws_markdown_of(&table);
        if !draws.is_empty() {
            println!(
                "The model's {} draws: each draw's mean, and the best of the first K (Chamfer: the smallest; agents: the draw that recalls most moving-vehicle points):\n\n{draws}",
                table["samples"]
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Chamfer against horizon, one line per method.
fn plot_forecast(path: &Path, table: &serde_json::Value) -> Result<()> {
    let empty = Vec::new();
    let rows = table["horizons"].as_array().unwrap_or(&empty);
    let lines: Vec<(&str, Vec<(f64, f64)>)> = bevworld_metrics::forecast_node::TABLE_METHODS
        .iter()
        .map(|&method| {
            let points = rows
                .iter()
                .filter_map(|row| {
                    Some((
                        row["horizon_s"].as_f64()?,
                        row.get(method)?.get("chamfer")?.as_f64()?,
                    ))
                })
                .collect();
            (method, points)
        })
        .collect();
    let panel = bevworld_plot::Panel {
        title: "LiDAR Chamfer (m²) against horizon (s)",
        x_label: "horizon (s)",
        log_y: true,
        series: lines
            .iter()
            .map(|(label, points)| bevworld_plot::Series { label, points })
            .collect(),
    };
    bevworld_plot::panels_png(path, &[panel]).with_context(|| format!("drawing {}", path.display()))
}
