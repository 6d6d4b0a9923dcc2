//! `bevworld synth`: writes the synthetic driving world as a nuScenes-layout dataset.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use bevworld_sensors::source::parse_size;
use bevworld_sensors::synth::render::LidarSpec;
use bevworld_sensors::synth::{Branch, ImageEncoding, SynthConfig, generate};
use bevworld_types::Manoeuvre;
use clap::Args;

use crate::commands::refuse;

#[derive(Args)]
pub struct SynthArgs {
    /// Output folder (created; must not already hold a dataset).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of scenes; scene k uses seed SEED + k.
    #[arg(long, default_value_t = 1)]
    pub scenes: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Scene length in seconds (12 Hz sensor ticks, keyframes at 2 Hz).
    #[arg(long, allow_negative_numbers = true, default_value_t = 4.0)]
    pub seconds: f64,
    /// Camera image size WxH.
    #[arg(long, default_value = "400x224")]
    pub camera_size: String,
    /// LiDAR azimuth resolution in degrees.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.4)]
    pub azimuth_step: f64,
    /// LiDAR range noise standard deviation, m.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0)]
    pub range_noise: f64,
    /// Probability that a LiDAR return is dropped.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0)]
    pub ray_drop: f64,
    /// Moving vehicles per scene (at most 200).
    #[arg(long, default_value_t = 14)]
    pub agents: usize,
    /// Pedestrians per scene, on the sidewalks (at most 200; 0 leaves a seed's scenes as they
    /// were before pedestrians existed).
    #[arg(long, default_value_t = 0)]
    pub pedestrians: usize,
    /// Cyclists per scene, on the roads (at most 200).
    #[arg(long, default_value_t = 0)]
    pub cyclists: usize,
    /// Write JPEG at this quality (1 to 100) instead of lossless PNG.
    #[arg(long)]
    pub jpeg: Option<u8>,
    /// Replace an existing dataset in OUT.
    #[arg(long)]
    pub overwrite: bool,
    /// Branch every scene at this time (seconds): instead of the scene, one scene per
    /// manoeuvre, named `<scene>-<manoeuvre>`, identical up to here. The scene must have a
    /// keyframe after it.
    #[arg(long, allow_negative_numbers = true)]
    pub branch_at: Option<f64>,
    /// The manoeuvres of `--branch-at`: keep, left, right, faster, slower, stop
    /// (`--maneuvers` is the same flag).
    #[arg(
        long,
        alias = "maneuvers",
        value_delimiter = ',',
        default_value = "keep,left,right,faster,slower",
        requires = "branch_at"
    )]
    pub manoeuvres: Vec<String>,
}

pub fn run(args: &SynthArgs) -> Result<ExitCode> {
    let (camera_width, camera_height) = parse_size(&args.camera_size).context("--camera-size")?;
    if !(args.azimuth_step > 0.01 && args.azimuth_step <= 10.0) {
        return Err(refuse(format!(
            "--azimuth-step {}: must be in (0.01, 10] degrees",
            args.azimuth_step
        )));
    }
    if !(0.0..=1.0).contains(&args.ray_drop) || !(args.range_noise >= 0.0) {
        return Err(refuse(format!(
            "--ray-drop {} must be in [0, 1] and --range-noise {} >= 0",
            args.ray_drop, args.range_noise
        )));
    }
    // Never into another dataset: its samples/ and sweeps/ would be mixed with ours, and
    // --overwrite would replace files that are not ours to replace.
    if let Ok(entries) = std::fs::read_dir(&args.out) {
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().to_string();
            let foreign_tables =
                name.starts_with("v1.0-") && name != bevworld_sensors::synth::VERSION;
            if foreign_tables || name == "velodyne" {
                bail!(
                    "{} holds another dataset ({name}); write the synthetic world into a folder of its own",
                    args.out.display()
                );
            }
        }
    }
    let tables = args.out.join(bevworld_sensors::synth::VERSION);
    if tables.exists() && !args.overwrite {
        bail!(
            "{} already holds a dataset; pass --overwrite to replace it",
            args.out.display()
        );
    }
    let mut lidar = LidarSpec::nuscenes_like(args.azimuth_step);
    lidar.range_noise = args.range_noise;
    lidar.drop_probability = args.ray_drop;
    let config = SynthConfig {
        seed: args.seed,
        scenes: args.scenes,
        seconds: args.seconds,
        camera_width,
        camera_height,
        lidar,
        agents: args.agents,
        pedestrians: args.pedestrians,
        cyclists: args.cyclists,
        image_encoding: args
            .jpeg
            .map_or(ImageEncoding::Png, |quality| ImageEncoding::Jpeg {
                quality,
            }),
        branch: match args.branch_at {
            None => None,
            Some(at_s) => Some(Branch {
                at_s,
                manoeuvres: args
                    .manoeuvres
                    .iter()
                    .map(|name| {
                        Manoeuvre::parse(name).with_context(|| {
                            format!(
                                "--manoeuvres: unknown manoeuvre '{name}' (known: keep, left, right, faster, slower, stop)"
                            )
                        })
                    })
                    .collect::<Result<_>>()?,
            }),
        },
        ..Default::default()
    };
    // The library refuses what it cannot generate; say it here in the flags' words, before
    // anything is written.
    let problems = config.problems();
    if !problems.is_empty() {
        return Err(refuse(format!(
            "{} (flags: --scenes, --seed, --seconds, --camera-size, --agents, --pedestrians, --cyclists, --jpeg, --branch-at, --manoeuvres)",
            problems.join("; ")
        )));
    }
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} synth [{bar:30}] {pos}/{len} frames, {per_sec}, eta {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let summary = generate(&args.out, &config, |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("generating into {}", args.out.display()))?;
    bar.finish_and_clear();
    println!(
        "wrote {} scene(s), {} frames ({} keyframes), {} LiDAR points to {} in {:.1} s: {:.2} frames/s",
        summary.scenes,
        summary.frames,
        summary.keyframes,
        summary.lidar_points,
        args.out.display(),
        summary.seconds,
        summary.frames_per_second()
    );
    Ok(ExitCode::SUCCESS)
}
