//! `bevworld tokenizer`: tools around the trained tokenizer.
//!
//! `stats` encodes every frame of a dataset and writes the latent's per-channel mean and
//! standard deviation beside the weights, where the world model reads them.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use bevworld_pillarize::{Limits, Pillarizer, ego_points_into};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_tokenizer::{FrameInputs, TokenizerConfig, load_weights, weights_digest};
use bevworld_types::{LatentStatsAccumulator, LatentStatsFile, stats_path_for};
use clap::{Args, Subcommand};

#[derive(Subcommand)]
pub enum TokenizerCommand {
    /// Per-channel mean and standard deviation of the latent over a dataset, written beside
    /// the weights as <weights>.stats.json.
    Stats(StatsArgs),
}

#[derive(Args)]
pub struct StatsArgs {
    /// Model config.
    #[arg(long, default_value = "configs/models/tokenizer-tiny.yaml")]
    pub config: PathBuf,
    /// Trained weights (burnpack).
    #[arg(long)]
    pub weights: PathBuf,
    /// Dataset root (nuScenes layout, synthetic included, or KITTI odometry).
    #[arg(long)]
    pub data: PathBuf,
    /// Use at most this many keyframes.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Output file (default: the weights path with extension .stats.json).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an existing statistics file (the shipped one describes the shipped weights
    /// over their whole training set; a run over a few frames must not silently replace it).
    #[arg(long)]
    pub overwrite: bool,
}

pub fn run(command: &TokenizerCommand) -> Result<ExitCode> {
    match command {
        TokenizerCommand::Stats(args) => stats(args),
    }
}

fn stats(args: &StatsArgs) -> Result<ExitCode> {
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| stats_path_for(&args.weights));
    if out.exists() && !args.overwrite {
        bail!(
            "{} already exists; pass --overwrite to replace it, or --out to write elsewhere",
            out.display()
        );
    }
    let config = TokenizerConfig::from_yaml_file(&args.config)?;
    let (_, device) = bevworld_device::from_env()?;
    let model = load_weights(&config, &args.weights, &device)?;
    let weights_hash = weights_digest(&args.weights)?;
    let dataset = Dataset::open(&args.data, &DatasetOptions::default())
        .with_context(|| format!("opening {}", args.data.display()))?;
    let frames = args.max_frames.unwrap_or(usize::MAX).min(dataset.len());
    if frames == 0 {
        bail!("{} holds no frames", args.data.display());
    }
    let inputs = FrameInputs::new(&config);
    let mut pillarizer = Pillarizer::new(inputs.pillar_grid(), Limits::default());
    let mut points = Vec::new();
    let mut accumulator = LatentStatsAccumulator::default();
    let progress = indicatif::ProgressBar::new(frames as u64);
    for index in 0..frames {
        let frame = dataset
            .read(index)
            .with_context(|| format!("reading frame {index} of {}", args.data.display()))?;
        ego_points_into(&frame.lidar, &mut points);
        let pillars = pillarizer.run(&points);
        let input = inputs.encoder_input(&frame, &pillars, &device)?;
        let latent = model
            .encode(input)
            .latent
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("reading the latent back: {e:?}"))?;
        if latent.iter().any(|v| !v.is_finite()) {
            bail!(
                "frame {index} ({}) encodes to non-finite values",
                frame.frame_token
            );
        }
        accumulator
            .add(&latent, config.latent_channels)
            .map_err(anyhow::Error::msg)?;
        progress.inc(1);
    }
    progress.finish_and_clear();
    let stats = accumulator.finish()?;
    let file = LatentStatsFile {
        model: config.name.clone(),
        weights_hash,
        data: args.data.display().to_string(),
        stats,
    };
    file.save(&out)?;
    println!(
        "latent statistics over {} frames -> {}\n  mean {:?}\n  std  {:?}",
        file.stats.frames,
        out.display(),
        file.stats.mean,
        file.stats.std
    );
    Ok(ExitCode::SUCCESS)
}
