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

pub mod agent_tracks;
pub mod cli;
pub mod forecast_budget;
pub mod readme;

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
    format!(
        "{cores} cores, {} ({}; host kernels: {})",
        bevworld_device::cpu_model(),
        bevworld_device::simd_features().join(" "),
        bevworld_blocks::host::dispatch_level()
    )
}

/// The machine a benchmark ran on, as a record: cores, CPU model, the vector instruction sets
/// detected, and the kernels they select (our host kernels' dispatch level; gemm, under
/// burn's `x86-v4`, runs AVX-512 micro-kernels wherever `avx512f` is detected).
pub fn machine_record() -> serde_json::Value {
    let simd = bevworld_device::simd_features();
    serde_json::json!({
        "cores": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        "cpu": bevworld_device::cpu_model(),
        "simd": simd,
        "host_kernels": bevworld_blocks::host::dispatch_level(),
        "matmul_kernels": if simd.contains(&"avx512f") { "gemm avx512 (x86-v4)" } else if simd.contains(&"avx2") { "gemm avx2+fma" } else { "gemm baseline" },
    })
}

/// The code a benchmark ran: the checkout's commit, marked when tracked files had changes
/// beside it; "unknown" outside a git checkout.
pub fn code_version() -> String {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .current_dir(manifest_dir())
            .output()
            .ok()
            .filter(|out| out.status.success())
            .map(|out| String::from_utf8_lossy(&out.stdout).trim().to_string())
    };
    let Some(head) = git(&["rev-parse", "--short", "HEAD"]) else {
        return "unknown".into();
    };
    match git(&["status", "--porcelain", "--untracked-files=no"]) {
        Some(changes) if !changes.is_empty() => format!("{head} with changes"),
        _ => head,
    }
}

/// The records `<prefix><kind>.json` in `results`, one per kind of machine measured, as
/// (kind, path) in the order of their file names: the pages that keep a table per CPU kind read them all.
pub fn kind_records(results: &std::path::Path, prefix: &str) -> Vec<(String, PathBuf)> {
    let mut records: Vec<(String, PathBuf)> = std::fs::read_dir(results)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|entry| {
            let path = entry.path();
            let kind = path
                .file_name()?
                .to_str()?
                .strip_prefix(prefix)?
                .strip_suffix(".json")?
                .to_string();
            Some((kind, path))
        })
        .collect();
    records.sort_by(|a, b| a.1.cmp(&b.1));
    records
}

/// A short name for a kind of machine, for the file of its figures: `intel-xeon-avx512`,
/// `amd-epyc-avx2`. Machines of one kind run the same kernels.
pub fn machine_kind(record: &serde_json::Value) -> String {
    let cpu = record["cpu"]
        .as_str()
        .unwrap_or("unknown")
        .to_ascii_lowercase();
    let family = if cpu.contains("epyc") {
        "amd-epyc".to_string()
    } else if cpu.contains("xeon") {
        "intel-xeon".to_string()
    } else {
        cpu.split(|c: char| !c.is_ascii_alphanumeric())
            .filter(|w| !w.is_empty() && !matches!(*w, "r" | "tm" | "processor" | "cpu"))
            .take(3)
            .collect::<Vec<_>>()
            .join("-")
    };
    let simd: Vec<&str> = record["simd"]
        .as_array()
        .map(|a| a.iter().filter_map(serde_json::Value::as_str).collect())
        .unwrap_or_default();
    let widest = if simd.contains(&"avx512f") {
        "avx512"
    } else if simd.contains(&"avx2") {
        "avx2"
    } else if simd.is_empty() {
        "unrecorded"
    } else {
        "sse"
    };
    format!("{family}-{widest}")
}

/// Nearest-rank percentile, the one the forecast metrics report.
pub use bevworld_metrics::forecast_node::percentile;

/// PSNR in dB of two images of one size with values in [0, 1], flat: the metrics' one
/// definition (`bevworld_metrics::psnr`); infinite when they are equal.
pub fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let flat = |data| bevworld_metrics::Planes {
        data,
        channels: 1,
        height: 1,
        width: a.len(),
    };
    bevworld_metrics::psnr(&flat(a), &flat(b), 1.0)
        .expect("a benchmark compares two finite, non-empty images of one size")
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
    for (file, text) in [
        (dir.join(format!("{name}.md")), markdown),
        (
            dir.join(format!("{name}.json")),
            serde_json::to_string_pretty(json).unwrap_or_default(),
        ),
    ] {
        bevworld_atomic_file::write(&file, text.as_bytes())
            .unwrap_or_else(|e| panic!("writing {}: {e}", file.display()));
    }
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
