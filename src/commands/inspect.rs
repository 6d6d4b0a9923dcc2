//! `bevworld inspect`: LiDAR points drawn on each camera image, devkit-exact.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use bevworld_sensors::inspect::{draw_points, project_cloud, to_csv};
use bevworld_sensors::{Dataset, DatasetOptions};
use clap::Args;

#[derive(Args)]
pub struct InspectArgs {
    /// Dataset root (nuScenes layout, synthetic included).
    #[arg(long)]
    pub data: PathBuf,
    /// Table folder, e.g. v1.0-mini (found automatically when unique).
    #[arg(long)]
    pub version: Option<String>,
    /// Sample token of the keyframe to inspect.
    #[arg(long, conflicts_with = "index")]
    pub sample: Option<String>,
    /// Index of the keyframe to inspect (default 0).
    #[arg(long)]
    pub index: Option<usize>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Depth at which the colour scale saturates, m.
    #[arg(long, default_value_t = 50.0)]
    pub max_depth: f64,
}

pub fn run(args: &InspectArgs) -> Result<ExitCode> {
    let options = DatasetOptions {
        version: args.version.clone(),
        ..Default::default()
    };
    let dataset = Dataset::open(&args.data, &options)
        .with_context(|| format!("opening {}", args.data.display()))?;
    let index = match (&args.sample, args.index) {
        (Some(token), _) => dataset
            .index_of_sample(token)
            .with_context(|| format!("no keyframe with sample token '{token}'"))?,
        (None, index) => index.unwrap_or(0),
    };
    if index >= dataset.len() {
        bail!(
            "--index {index} is out of range: the dataset has {} frames",
            dataset.len()
        );
    }
    let frame = dataset
        .read(index)
        .with_context(|| format!("reading frame {index}"))?;
    if frame.cameras.is_empty() {
        bail!("frame {index} has no cameras (a LiDAR-only dataset cannot be inspected)");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    for camera in &frame.cameras {
        let points = project_cloud(&frame.lidar, camera);
        let name = camera.channel.name();
        let png = args.out.join(format!("{name}.png"));
        bevworld_plot::save_png(&png, &draw_points(&camera.image, &points, args.max_depth))?;
        let csv = args.out.join(format!("{name}.csv"));
        bevworld_graph::io::write_atomic_now(&csv, to_csv(&points).as_bytes())
            .with_context(|| format!("writing {}", csv.display()))?;
        println!("{name}: {} points -> {}", points.len(), png.display());
    }
    Ok(ExitCode::SUCCESS)
}
