//! `bevworld eval control`: does a forecast follow the action it was given? On a branched
//! synthetic dataset (`bevworld synth --branch-at B --manoeuvres …`), every group of branches
//! shares its past and differs after B, so each manoeuvre has its own ground truth, which no
//! real log has.
//!
//! For each group, the context is the last keyframe where every branch's ego is still at the
//! same pose (the last at or before B). From it, the forecast graph forecasts each manoeuvre
//! and renders its LiDAR sweep at the horizon (along the rig at the predicted pose). A pair
//! (context, manoeuvre a) counts as right when that forecast is closer, in Chamfer distance
//! (4D-Occ ROI, each sweep in its own ego frame: what the car would see), to a's true sweep
//! than to every other manoeuvre's. The swap ratio is the mean of
//! `chamfer(forecast_a, truth_b) / chamfer(forecast_a, truth_a)` over b ≠ a.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use bevworld_metrics::{Roi, chamfer_in_roi};
use bevworld_sensors::{Dataset, DatasetFormat, DatasetOptions};
use bevworld_types::{Manoeuvre, SensorFrame};
use clap::Args;

#[derive(Args)]
pub struct ControlEvalArgs {
    /// A branched dataset (`bevworld synth --branch-at`).
    #[arg(long)]
    pub data: PathBuf,
    /// The forecast graph whose nodes (`source`, `history`, `rollout`, `views`, `render`,
    /// `files`, `scores`) make each forecast.
    #[arg(long, default_value = "configs/graphs/forecast.yaml")]
    pub graph: PathBuf,
    /// The horizon the forecasts are compared at, seconds.
    #[arg(long, default_value_t = 3.0, allow_negative_numbers = true)]
    pub horizon: f64,
    /// DDIM steps (default: the graph's).
    #[arg(long)]
    pub steps: Option<usize>,
    /// What forecasts: `model`, or the baseline `latent_ego_warp` (the current latent moved by
    /// each manoeuvre's motion), to see how much of the control the ego motion alone gives.
    #[arg(long, default_value = "model")]
    pub method: String,
    /// Where the forecasts are written.
    #[arg(long, default_value = "out/eval-control")]
    pub out: PathBuf,
    /// One context's forecasts, one per manoeuvre, side by side from above.
    #[arg(long)]
    pub picture: Option<PathBuf>,
    /// Print one JSON object: {"accuracy", "pairs", "swap_ratio", "manoeuvres": [...]}.
    #[arg(long)]
    pub json: bool,
}

/// One manoeuvre's forecast sweep and its true sweep, for the picture.
type Panel = (Manoeuvre, Vec<[f64; 3]>, Vec<[f64; 3]>);

/// The branches of one scene: (manoeuvre, scene name, its frame indices in order).
type Group = Vec<(Manoeuvre, String, Vec<usize>)>;

/// Scenes named `<scene>-<manoeuvre>`, grouped by `<scene>`.
fn groups(dataset: &Dataset) -> BTreeMap<String, Group> {
    let mut frames: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (index, name) in dataset.scene_names().into_iter().enumerate() {
        frames.entry(name.to_string()).or_default().push(index);
    }
    let mut groups: BTreeMap<String, Group> = BTreeMap::new();
    for (name, indices) in frames {
        if let Some((base, suffix)) = name.rsplit_once('-')
            && let Some(manoeuvre) = Manoeuvre::parse(suffix)
        {
            groups
                .entry(base.to_string())
                .or_default()
                .push((manoeuvre, name, indices));
        }
    }
    groups
}

fn points(frame: &SensorFrame) -> Vec<[f64; 3]> {
    frame
        .lidar
        .scene_ego_points()
        .into_iter()
        .map(|p| [p[0].into(), p[1].into(), p[2].into()])
        .collect()
}

/// One group's context and each branch's true sweep at the horizon.
struct SharedContext {
    /// Index of the context keyframe within each branch.
    index: usize,
    truths: Vec<Vec<[f64; 3]>>,
}

fn context(
    dataset: &Dataset,
    group: &Group,
    ahead: usize,
    history: usize,
) -> Result<Option<SharedContext>> {
    let length = group.iter().map(|(_, _, f)| f.len()).min().unwrap_or(0);
    let mut shared = None;
    for k in 0..length {
        let poses: Vec<_> = group
            .iter()
            .map(|(_, _, f)| dataset.read(f[k]).map(|frame| frame.global_from_ego))
            .collect::<Result<_, _>>()?;
        let same = poses
            .iter()
            .all(|p| (p.translation - poses[0].translation).length() < 1e-6);
        if !same {
            break;
        }
        shared = Some(k);
    }
    let Some(index) = shared else {
        return Ok(None);
    };
    if index < history || index + ahead >= length {
        return Ok(None);
    }
    let truths = group
        .iter()
        .map(|(_, _, f)| dataset.read(f[index + ahead]).map(|frame| points(&frame)))
        .collect::<Result<_, _>>()?;
    Ok(Some(SharedContext { index, truths }))
}

pub fn run(args: &ControlEvalArgs) -> Result<ExitCode> {
    // The model's own facts: its frame interval, how far it forecasts, its condition frames.
    let model = crate::commands::graph_run::world_model_of(&args.graph)?;
    let interval = model.frame_interval_s;
    let ahead = (args.horizon / interval).round();
    if !(ahead >= 1.0
        && ahead <= model.future_frames as f64
        && (ahead * interval - args.horizon).abs() <= 1e-9)
    {
        return Err(crate::commands::refuse(format!(
            "--horizon {}: forecasts are compared at a horizon after the context, one of the world model's future frames: a multiple of its {interval} s frame interval from {interval} s on, to {} s",
            args.horizon,
            interval * model.future_frames as f64
        )));
    }
    let ahead = ahead as usize;
    if let Some(path) = &args.picture {
        crate::commands::eval::check_picture_path("--picture", path)?;
    }
    let options = DatasetOptions {
        format: DatasetFormat::Synth,
        skip_images: true,
        ..Default::default()
    };
    let dataset = Dataset::open(&args.data, &options)
        .with_context(|| format!("opening {}", args.data.display()))?;
    let groups = groups(&dataset);
    if groups.is_empty() {
        bail!(
            "{} has no branched scenes (named <scene>-<manoeuvre>): make one with `bevworld synth --branch-at B`",
            args.data.display()
        );
    }
    // Frames read before the context frame: its other condition frames, and one before them
    // for the first action; as many as the model's condition frames.
    let history = model.context_frames;
    let roi = Roi::FOUR_D_OCC;
    let mut rows: BTreeMap<Manoeuvre, (usize, usize, f64, usize)> = BTreeMap::new();
    let mut picture: Option<Vec<Panel>> = None;
    let mut contexts = 0;
    // Per group: forecast manoeuvre -> true manoeuvre -> Chamfer.
    let mut matrices = serde_json::Map::new();
    for (base, group) in &groups {
        let Some(context) = context(&dataset, group, ahead, history)? else {
            eprintln!(
                "{base}: no context with {history} frames before it and {} s after it shared by every branch; skipped",
                args.horizon
            );
            continue;
        };
        contexts += 1;
        let (_, first_scene, _) = &group[0];
        let mut forecasts = Vec::new();
        for (manoeuvre, _, _) in group {
            let out = args.out.join(base).join(manoeuvre.name());
            if out.exists() {
                std::fs::remove_dir_all(&out)
                    .with_context(|| format!("clearing {}", out.display()))?;
            }
            let mut set = vec![
                format!("source.data={}", args.data.display()),
                format!("source.scenes=[{first_scene}]"),
                format!("source.start={}", context.index - history),
                format!("source.max_frames={}", history + 1),
                "history.log_future=false".into(),
                format!("rollout.actions={}", manoeuvre.name()),
                format!("rollout.horizons=[{}]", args.horizon),
                format!("views.methods=[{}]", args.method),
                format!("files.method={}", args.method),
                "render.sensors=[lidar]".into(),
                format!("files.out={}", out.display()),
                format!("scores.json={}", out.join("scores.json").display()),
                "scores.print=false".into(),
            ];
            if let Some(steps) = args.steps {
                set.push(format!("rollout.steps={steps}"));
            }
            crate::commands::graph_run::run_graph(&args.graph, &set)
                .with_context(|| format!("forecasting {base} under {}", manoeuvre.name()))?;
            let ply = std::fs::read_dir(&out)?
                .filter_map(Result::ok)
                .map(|e| {
                    e.path()
                        .join(format!("+{}s", args.horizon))
                        .join("LIDAR_TOP.ply")
                })
                .find(|p| p.is_file())
                .with_context(|| format!("{}: the forecast wrote no sweep", out.display()))?;
            let cloud: Vec<[f64; 3]> = bevworld_sinks::ply::read_ply(&ply)?
                .iter()
                .map(|p| [p.x.into(), p.y.into(), p.z.into()])
                .collect();
            forecasts.push(cloud);
        }
        let mut matrix = serde_json::Map::new();
        for (a, (manoeuvre, _, _)) in group.iter().enumerate() {
            let distances: Vec<f64> = context
                .truths
                .iter()
                .map(|truth| chamfer_in_roi(&forecasts[a], truth, &roi).chamfer)
                .collect();
            matrix.insert(
                manoeuvre.name().into(),
                group
                    .iter()
                    .zip(&distances)
                    .map(|((m, _, _), d)| (m.name().to_string(), serde_json::json!(d)))
                    .collect::<serde_json::Map<_, _>>()
                    .into(),
            );
            let own = distances[a];
            let right = distances
                .iter()
                .enumerate()
                .all(|(b, d)| b == a || *d > own);
            let row = rows.entry(*manoeuvre).or_default();
            row.0 += usize::from(right);
            row.1 += 1;
            for (b, d) in distances.iter().enumerate() {
                if b != a && own > 0.0 {
                    row.2 += d / own;
                    row.3 += 1;
                }
            }
        }
        matrices.insert(base.clone(), matrix.into());
        if picture.is_none() {
            picture = Some(
                group
                    .iter()
                    .zip(&forecasts)
                    .zip(&context.truths)
                    .map(|(((m, _, _), f), t)| (*m, f.clone(), t.clone()))
                    .collect(),
            );
        }
    }
    if contexts == 0 {
        bail!(
            "no group of branches in {} has a shared context with {history} frames before it and {} s of every branch after it",
            args.data.display(),
            args.horizon
        );
    }
    let pairs: usize = rows.values().map(|r| r.1).sum();
    let right: usize = rows.values().map(|r| r.0).sum();
    let (ratio_sum, ratio_count) = rows.values().fold((0.0, 0), |(s, n), r| (s + r.2, n + r.3));
    let accuracy = right as f64 / pairs.max(1) as f64;
    let swap_ratio = ratio_sum / ratio_count.max(1) as f64;
    let manoeuvres: Vec<serde_json::Value> = rows
        .iter()
        .map(|(m, r)| {
            serde_json::json!({"manoeuvre": m.name(), "pairs": r.1, "accuracy": r.0 as f64 / r.1.max(1) as f64,
                "swap_ratio": r.2 / r.3.max(1) as f64})
        })
        .collect();
    if let (Some(path), Some(picture)) = (&args.picture, &picture) {
        draw(path, picture, args.horizon)?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({"accuracy": accuracy, "pairs": pairs, "swap_ratio": swap_ratio, "contexts": contexts, "horizon_s": args.horizon, "method": args.method, "manoeuvres": manoeuvres, "distances": matrices})
        );
    } else {
        println!("| manoeuvre | pairs | accuracy | swap ratio |\n|---|---|---|---|");
        for (m, r) in &rows {
            println!(
                "| {} | {} | {:.0}% | {:.2} |",
                m.name(),
                r.1,
                100.0 * r.0 as f64 / r.1.max(1) as f64,
                r.2 / r.3.max(1) as f64
            );
        }
        println!(
            "\n{contexts} contexts, {pairs} pairs at +{} s: accuracy {:.0}%, swap ratio {swap_ratio:.2}",
            args.horizon,
            100.0 * accuracy
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The manoeuvres' forecasts (orange) over their true sweeps (grey), side by side.
fn draw(path: &Path, picture: &[Panel], horizon: f64) -> Result<()> {
    let size = 360;
    let flat = |points: &[[f64; 3]]| -> Vec<[f32; 2]> {
        points.iter().map(|p| [p[0] as f32, p[1] as f32]).collect()
    };
    let mut canvas = image::RgbImage::new(size * picture.len() as u32, size);
    for (i, (manoeuvre, forecast, truth)) in picture.iter().enumerate() {
        let (forecast, truth) = (flat(forecast), flat(truth));
        let panel = bevworld_plot::top_down(
            size,
            40.0,
            &format!("{} +{horizon} s", manoeuvre.name()),
            &[
                bevworld_plot::Cloud {
                    label: "truth",
                    points: &truth,
                    colour: [150, 150, 150],
                },
                bevworld_plot::Cloud {
                    label: "forecast",
                    points: &forecast,
                    colour: [230, 120, 20],
                },
            ],
        );
        image::imageops::replace(&mut canvas, &panel, i64::from(size) * i as i64, 0);
    }
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)?;
    }
    Ok(bevworld_plot::save_png(path, &canvas)?)
}
