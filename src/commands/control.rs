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
use bevworld_types::{Manoeuvre, RenderedFuture, SensorFrame};
use clap::Args;

#[derive(Args)]
pub struct ControlEvalArgs {
    /// A branched dataset (`bevworld synth --branch-at`).
    #[arg(long)]
    pub data: PathBuf,
    /// The forecast graph that makes each forecast: it must expose the names this command
    /// binds to (`bevworld check` lists them).
    #[arg(long, default_value = "configs/graphs/forecast.yaml")]
    pub graph: PathBuf,
    /// The horizon the forecasts are compared at, seconds.
    #[arg(long, default_value_t = 3.0, allow_negative_numbers = true)]
    pub horizon: f64,
    /// DDIM steps (default: the graph's).
    #[arg(long)]
    pub steps: Option<usize>,
    /// What forecasts: `model`, or the baseline `latent_ego_warp` (the current latent moved by
    /// each manoeuvre's motion), to see how much of the control the ego motion alone gives, or
    /// `oracle` (the tokenizer's latent of each branch's true future frame, rendered along its
    /// rays): how far the tokenizer alone can tell the branches apart, the floor of the others.
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
    /// Further `node.key=value` overrides of the graph, as `run --set`, applied after the
    /// command's own: e.g. `models.tiny.world_model.weights=runs/x/world-model-tiny.bpk`
    /// scores other weights.
    #[arg(long = "set", value_name = "TARGET=VALUE")]
    pub set: Vec<String>,
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

/// Per manoeuvre: pairs right, pairs, and the sum and count of the swap ratios.
#[derive(Default)]
struct Tally {
    right: usize,
    pairs: usize,
    ratio_sum: f64,
    ratios: usize,
}

pub fn run(args: &ControlEvalArgs) -> Result<ExitCode> {
    let contract = &super::contracts::EVAL_CONTROL;
    // The model's own facts: its frame interval, how far it forecasts, its condition frames.
    let model = super::graph_run::world_model_of(&args.graph, contract, &args.set)?;
    let ahead = frames_ahead(args.horizon, &model)?;
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
    let mut tallies: BTreeMap<Manoeuvre, Tally> = BTreeMap::new();
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
        let forecasts = forecast_group(args, &dataset, base, group, &context, (history, ahead))?;
        matrices.insert(
            base.clone(),
            score_group(group, &forecasts, &context, &mut tallies).into(),
        );
        if picture.is_none() {
            picture = Some(
                group
                    .iter()
                    .zip(forecasts)
                    .zip(&context.truths)
                    .map(|(((m, _, _), f), t)| (*m, f, t.clone()))
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
    if let (Some(path), Some(picture)) = (&args.picture, &picture) {
        draw(path, picture, args.horizon)?;
    }
    report(args, &tallies, contexts, matrices);
    Ok(ExitCode::SUCCESS)
}

/// The future frame `horizon` seconds after the context: one of the model's, or refused.
fn frames_ahead(horizon: f64, model: &bevworld_world_model::WorldModelConfig) -> Result<usize> {
    let interval = model.frame_interval_s;
    let ahead = (horizon / interval).round();
    if !(ahead >= 1.0
        && ahead <= model.future_frames as f64
        && (ahead * interval - horizon).abs() <= 1e-9)
    {
        return Err(crate::commands::refuse(format!(
            "--horizon {horizon}: forecasts are compared at a horizon after the context, one of the world model's future frames: a multiple of its {interval} s frame interval from {interval} s on, to {} s",
            interval * model.future_frames as f64
        )));
    }
    Ok(ahead as usize)
}

/// The forecast sweep of one group's shared context under each of its manoeuvres, in the ego
/// frame: the forecast graph run once per manoeuvre, bound by its exposed names
/// (`contracts::EVAL_CONTROL`), the sweep collected in-process from its `rendered` output (the
/// graph still writes its files under `--out`).
fn forecast_group(
    args: &ControlEvalArgs,
    dataset: &Dataset,
    base: &str,
    group: &Group,
    context: &SharedContext,
    (history, ahead): (usize, usize),
) -> Result<Vec<Vec<[f64; 3]>>> {
    let (_, first_scene, first_frames) = &group[0];
    // Views of other contexts (the oracle reads on to the horizon) are not this group's.
    let context_time = dataset
        .read(first_frames[context.index])?
        .time_of_validity_us;
    let oracle = args.method == "oracle";
    let mut forecasts = Vec::new();
    for (manoeuvre, scene, _) in group {
        let out = args.out.join(base).join(manoeuvre.name());
        if out.exists() {
            std::fs::remove_dir_all(&out).with_context(|| format!("clearing {}", out.display()))?;
        }
        // A forecast starts from the shared past and is given the manoeuvre; the oracle reads
        // the branch itself on to the horizon and encodes its true frame there.
        let (source_scene, frames, log_future, actions) = if oracle {
            (scene, history + 1 + ahead, true, "log")
        } else {
            (first_scene, history + 1, false, manoeuvre.name())
        };
        let mut set = vec![
            format!("data={}", args.data.display()),
            format!("scenes=[{source_scene}]"),
            format!("start={}", context.index - history),
            format!("max_frames={frames}"),
            format!("log_future={log_future}"),
            format!("actions={actions}"),
            format!("horizons=[{}]", args.horizon),
            format!("methods=[{}]", args.method),
            format!("written_method={}", args.method),
            "sensors=[lidar]".into(),
            format!("out={}", out.display()),
            format!("scores_json={}", out.join("scores.json").display()),
            "print_scores=false".into(),
        ];
        if let Some(steps) = args.steps {
            set.push(format!("steps={steps}"));
        }
        set.extend(args.set.iter().cloned());
        let forecasting = || format!("forecasting {base} under {}", manoeuvre.name());
        let mut graph =
            super::graph_run::build_bound(&args.graph, &super::contracts::EVAL_CONTROL, &set)
                .with_context(forecasting)?;
        let rendered = graph
            .collect::<RenderedFuture>("rendered")
            .map_err(super::Refused::Graph)?;
        super::graph_run::run_built(graph).with_context(forecasting)?;
        let sweep = rendered
            .take()
            .into_iter()
            .filter(|r| {
                r.view.method.name() == args.method
                    && r.view.sample == 0
                    && r.view.context.time_of_validity_us == context_time
            })
            .find_map(|r| r.lidar.as_ref().map(|cloud| cloud.ego_returns()))
            .with_context(|| format!("{}: the forecast rendered no sweep", forecasting()))?;
        forecasts.push(
            sweep
                .iter()
                .map(|p| [p.x.into(), p.y.into(), p.z.into()])
                .collect(),
        );
    }
    Ok(forecasts)
}

/// Scores one group: each manoeuvre's forecast against every branch's truth, into the tallies;
/// returns the Chamfer matrix (forecast manoeuvre -> true manoeuvre -> m²).
fn score_group(
    group: &Group,
    forecasts: &[Vec<[f64; 3]>],
    context: &SharedContext,
    tallies: &mut BTreeMap<Manoeuvre, Tally>,
) -> serde_json::Map<String, serde_json::Value> {
    let roi = Roi::FOUR_D_OCC;
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
        let tally = tallies.entry(*manoeuvre).or_default();
        tally.right += usize::from(
            distances
                .iter()
                .enumerate()
                .all(|(b, d)| b == a || *d > own),
        );
        tally.pairs += 1;
        for (b, d) in distances.iter().enumerate() {
            if b != a && own > 0.0 {
                tally.ratio_sum += d / own;
                tally.ratios += 1;
            }
        }
    }
    matrix
}

/// Prints the accuracy and swap ratio per manoeuvre and over all, as a table or one JSON object.
fn report(
    args: &ControlEvalArgs,
    tallies: &BTreeMap<Manoeuvre, Tally>,
    contexts: usize,
    matrices: serde_json::Map<String, serde_json::Value>,
) {
    let pairs: usize = tallies.values().map(|t| t.pairs).sum();
    let right: usize = tallies.values().map(|t| t.right).sum();
    let (ratio_sum, ratios) = tallies
        .values()
        .fold((0.0, 0), |(s, n), t| (s + t.ratio_sum, n + t.ratios));
    let accuracy = right as f64 / pairs.max(1) as f64;
    let swap_ratio = ratio_sum / ratios.max(1) as f64;
    let of = |t: &Tally| {
        (
            t.right as f64 / t.pairs.max(1) as f64,
            t.ratio_sum / t.ratios.max(1) as f64,
        )
    };
    if args.json {
        let manoeuvres: Vec<serde_json::Value> = tallies
            .iter()
            .map(|(m, t)| {
                let (accuracy, swap_ratio) = of(t);
                serde_json::json!({"manoeuvre": m.name(), "pairs": t.pairs, "accuracy": accuracy, "swap_ratio": swap_ratio})
            })
            .collect();
        println!(
            "{}",
            serde_json::json!({"accuracy": accuracy, "pairs": pairs, "swap_ratio": swap_ratio, "contexts": contexts, "horizon_s": args.horizon, "method": args.method, "manoeuvres": manoeuvres, "distances": matrices})
        );
        return;
    }
    println!("| manoeuvre | pairs | accuracy | swap ratio |\n|---|---|---|---|");
    for (m, t) in tallies {
        let (accuracy, swap_ratio) = of(t);
        println!(
            "| {} | {} | {:.0}% | {swap_ratio:.2} |",
            m.name(),
            t.pairs,
            100.0 * accuracy
        );
    }
    println!(
        "\n{contexts} contexts, {pairs} pairs at +{} s: accuracy {:.0}%, swap ratio {swap_ratio:.2}",
        args.horizon,
        100.0 * accuracy
    );
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
