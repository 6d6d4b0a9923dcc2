//! Shared benchmark helpers: timing summaries, tables and result files; plots are
//! `bevworld_plot`'s.
//!
//! Benchmarks print a table, and write `bench/results/<name>.md`, `.json` and `.svg`. Timings
//! live here, never in test assertions.

/// The allocator the `bevworld` binary runs with, so that benchmarks time what users run
/// (see `src/main.rs`). A library's global allocator applies to every binary that links it.
/// Model benchmarks also call `bevworld_device::keep_freed_memory()` first, as the binary does.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::path::PathBuf;

/// Where results go: `bench/results/`, from any working directory.
pub fn results_dir() -> PathBuf {
    let dir = manifest_dir().join("results");
    let _ = std::fs::create_dir_all(&dir);
    dir
}

/// A one-line description of this machine, recorded with every result.
pub fn machine() -> String {
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| {
            text.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!("{cores} cores, {model}")
}

/// Nearest-rank percentile, the one the forecast metrics report.
pub use bevworld_metrics::forecast_node::percentile;

/// PSNR in dB of two images with values in [0, 1]; infinite when they are equal.
pub fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse = a
        .iter()
        .zip(b)
        .map(|(x, y)| f64::from(x - y).powi(2))
        .sum::<f64>()
        / a.len().max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (1.0 / mse).log10()
    }
}

/// The tiny training config's held-out synthetic set under the repository `root`, made on
/// first use.
pub fn held_out_synthetic_set(root: &std::path::Path) -> PathBuf {
    let (train, _) = bevworld_tokenizer_train::TrainConfig::from_yaml_file(
        &root.join("configs/models/train-tokenizer-tiny.yaml"),
    )
    .expect("training config");
    let mut set = train.data.val.clone();
    set.dir = root.join(&set.dir);
    set.ensure().expect("held-out synthetic set");
    set.dir
}

/// A Markdown table.
pub fn markdown_table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut out = format!(
        "| {} |\n|{}|\n",
        header.join(" | "),
        header.iter().map(|_| "---").collect::<Vec<_>>().join("|")
    );
    for row in rows {
        out.push_str(&format!("| {} |\n", row.join(" | ")));
    }
    out
}

/// Writes `<name>.md` (with the command that reproduces it) and `<name>.json`.
pub fn write_results(
    name: &str,
    title: &str,
    command: &str,
    table: &str,
    notes: &str,
    json: &serde_json::Value,
) {
    let dir = results_dir();
    let markdown = format!(
        "# {title}\n\nMachine: {}\n\nReproduce: `{command}`\n\n{table}\n{notes}\n",
        machine()
    );
    let _ = std::fs::write(dir.join(format!("{name}.md")), markdown);
    let _ = std::fs::write(
        dir.join(format!("{name}.json")),
        serde_json::to_string_pretty(json).unwrap_or_default(),
    );
    println!(
        "results written to {}",
        dir.join(format!("{name}.md")).display()
    );
}

/// The bench crate's folder: from cargo at run time (so a moved checkout with a reused build
/// cache still finds its files), else where it was compiled.
pub fn manifest_dir() -> PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")))
}

/// Median and p99 milliseconds of `runs` calls after one warm-up; `f` must finish its work
/// (read back a value) so that asynchronous backends are timed fully.
pub fn time_runs<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, f64, T) {
    let mut last = f();
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let started = std::time::Instant::now();
            last = f();
            started.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    (percentile(&times, 0.5), percentile(&times, 0.99), last)
}

/// The real nuScenes keyframe the tokenizer benchmarks run on, its pillars at the graphs'
/// defaults (20 points per pillar, as PointPillars; the frame's token set, as `encode` checks),
/// and the model inputs of `config`.
pub fn nuscenes_keyframe(
    config: &bevworld_tokenizer::TokenizerConfig,
) -> (
    bevworld_types::SensorFrame,
    bevworld_types::Pillars,
    bevworld_tokenizer::FrameInputs,
) {
    let frame = bevworld_sensors::Dataset::open(
        &bevworld_sensors::data_root().join("nuscenes-sample"),
        &bevworld_sensors::DatasetOptions::default(),
    )
    .expect("the nuScenes sample in $BEVWORLD_DATA (default ../shared/data)")
    .read(0)
    .expect("frame 0");
    let mut points = Vec::new();
    bevworld_pillarize::ego_points_into(&frame.lidar, &mut points);
    let inputs = bevworld_tokenizer::FrameInputs::new(config);
    let mut pillars = bevworld_pillarize::Pillarizer::new(
        inputs.pillar_grid(),
        bevworld_pillarize::Limits::default(),
    )
    .run(&points);
    pillars.meta.frame_token = frame.frame_token.clone();
    (frame, pillars, inputs)
}
