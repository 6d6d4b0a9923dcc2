//! `bevworld eval tokenizer`: the reconstruct graph over every keyframe of a dataset, its
//! scores summed up per scene and over scenes, so that a tokenizer can be reported on a seed
//! range it was never tuned on, with the spread that says how far the figure moves with the
//! scene.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::Args;

use crate::commands::eval::RoiName;

#[derive(Args)]
pub struct TokenizerEvalArgs {
    /// The dataset (nuScenes layout, e.g. a `bevworld synth` folder).
    #[arg(long)]
    pub data: PathBuf,
    /// The reconstruction graph to run: its `source`, `encode`, `render` and `metrics` nodes
    /// and its sinks `inputs`, `reconstructions`, `pairs`, `input_sweep` and
    /// `rendered_sweep`.
    #[arg(long, default_value = "configs/graphs/reconstruct.yaml")]
    pub graph: PathBuf,
    /// Tokenizer weights for the encoder and the renderer alike, e.g. a run's
    /// `tokenizer.bpk` (default: the graph's, the shipped weights).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "4docc")]
    pub roi: RoiName,
    /// Where the inputs, reconstructions, `metrics.csv` (one row per keyframe) and
    /// `summary.json` are written.
    #[arg(long, default_value = "out/eval-tokenizer")]
    pub out: PathBuf,
    /// Print the summary as one JSON object: the means over keyframes (`psnr_db`, `ssim`,
    /// `chamfer_m2`), their spread over scenes (`scene_std`), each scene's means, and the
    /// rendered sweeps' agent-level scores against the annotated vehicles (`agents`).
    #[arg(long)]
    pub json: bool,
    /// Further `node.key=value` overrides of the graph, as `run --set`, applied after the
    /// command's own: e.g. `source.max_frames=8`.
    #[arg(long = "set", value_name = "TARGET=VALUE")]
    pub set: Vec<String>,
}

pub fn run(args: &TokenizerEvalArgs) -> Result<ExitCode> {
    if !args.data.is_dir() {
        bail!("--data {}: no such folder", args.data.display());
    }
    if let Some(weights) = &args.weights
        && !weights.is_file()
    {
        bail!("--weights {}: no such file", weights.display());
    }
    // By the names the graph exposes (`contracts::EVAL_TOKENIZER`), never its node ids.
    let contract = &super::contracts::EVAL_TOKENIZER;
    let mut set = vec![
        format!("data={}", args.data.display()),
        format!("metrics_csv={}", args.out.join("metrics.csv").display()),
        format!("roi={}", args.roi.preset()),
        format!("out={}", args.out.display()),
    ];
    if let Some(weights) = &args.weights {
        let bundle = super::graph_run::bundle_name(&args.graph, contract)?;
        set.push(format!(
            "models.{bundle}.tokenizer.weights={}",
            weights.display()
        ));
    }
    set.extend(args.set.iter().cloned());
    let validated = super::graph_run::validate_bound(&args.graph, contract, &set)?;
    let weights = super::graph_run::bundle_of(&validated)?
        .1
        .tokenizer
        .map(|tokenizer| tokenizer.weights);
    let mut graph = validated.build().map_err(super::Refused::Graph)?;
    let summary = graph
        .collect::<bevworld_types::ScoreTable>("summary")
        .map_err(super::Refused::Graph)?;
    super::graph_run::run_built(graph)?;
    let mut table = summary
        .take()
        .pop()
        .map(|table| table.0.clone())
        .with_context(|| format!("{}: the metrics sent no summary", args.graph.display()))?;
    if table["frames"].as_u64() == Some(0) {
        bail!("no keyframe of {} was scored", args.data.display());
    }
    table["weights"] = weights.map_or(serde_json::Value::Null, serde_json::Value::String);
    // The summary file, as before: the table with the weights it was measured on.
    let summary_path = args.out.join("summary.json");
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    bevworld_graph::io::write_atomic_now(
        &summary_path,
        serde_json::to_string_pretty(&table)?.as_bytes(),
    )
    .with_context(|| format!("writing {}", summary_path.display()))?;
    if args.json {
        println!("{}", serde_json::to_string(&table)?);
        return Ok(ExitCode::SUCCESS);
    }
    println!("{}", markdown_of(&table));
    Ok(ExitCode::SUCCESS)
}

/// The summary as a Markdown table: one row per scene, then the mean over keyframes ± the
/// spread of the scenes' means.
fn markdown_of(table: &serde_json::Value) -> String {
    let number = |value: &serde_json::Value, digits: usize| {
        value
            .as_f64()
            .map_or("—".to_string(), |v| format!("{v:.digits$}"))
    };
    let empty = Vec::new();
    let scenes = table["scenes"].as_array().unwrap_or(&empty);
    let mut text = format!(
        "{} keyframes of {} scene(s), weights {}; {} empty cloud(s) left out of the Chamfer\n\n",
        table["frames"],
        scenes.len(),
        table["weights"].as_str().unwrap_or("?"),
        table["empty_clouds"],
    );
    text.push_str(
        "| scene | keyframes | PSNR (dB) | SSIM | Chamfer (m²) |\n|---|---|---|---|---|\n",
    );
    for scene in scenes {
        text.push_str(&format!(
            "| {} | {} | {} | {} | {} |\n",
            scene["scene"].as_str().unwrap_or("?"),
            scene["frames"],
            number(&scene["psnr_db"], 2),
            number(&scene["ssim"], 3),
            number(&scene["chamfer_m2"], 3),
        ));
    }
    let with_spread = |name: &str, digits: usize| {
        let mean = number(&table[name], digits);
        match table["scene_std"][name].as_f64() {
            Some(spread) => format!("{mean} ± {spread:.digits$}"),
            None => mean,
        }
    };
    text.push_str(&format!(
        "| mean ± spread over scenes | {} | {} | {} | {} |",
        table["frames"],
        with_spread("psnr_db", 2),
        with_spread("ssim", 3),
        with_spread("chamfer_m2", 3),
    ));
    text.push_str(&agents_markdown_of(&table["agents"]));
    text
}

/// The rendered sweeps' agent-level scores (the tokenizer's floor on vehicles), one row per
/// class: the mean over scenes of each scene's pooled value ± their spread. Empty when the
/// dataset has no annotations.
fn agents_markdown_of(agents: &serde_json::Value) -> String {
    if agents.is_null() {
        return String::new();
    }
    let cell = |class: &str, name: &str, digits: usize| {
        let figure = &agents[class]["over_scenes"][name];
        match (figure["mean"].as_f64(), figure["std"].as_f64()) {
            (Some(mean), Some(spread)) => format!("{mean:.digits$} ± {spread:.digits$}"),
            (Some(mean), None) => format!("{mean:.digits$}"),
            _ => "—".to_string(),
        }
    };
    let mut text = String::from(
        "\n\nThe rendered sweeps against the annotated vehicles (mean ± spread over scenes)\n\n\
         | class | true points | recall@0.5 m | recall@1 m | recall@0.5 m above ground | Chamfer truth→render (m²) |\n\
         |---|---|---|---|---|---|",
    );
    for class in ["moving_vehicles", "parked_vehicles", "static"] {
        if agents[class].is_null() {
            continue;
        }
        text.push_str(&format!(
            "\n| {class} | {} | {} | {} | {} | {} |",
            agents[class]["points"],
            cell(class, "recall_0.5m", 2),
            cell(class, "recall_1m", 2),
            cell(class, "recall_0.5m_above_ground", 2),
            cell(class, "chamfer_to_forecast", 3),
        ));
    }
    text
}
