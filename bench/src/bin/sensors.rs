//! Sensor replay as fast as possible on real-size frames: six 1600x900 JPEG decodes and a
//! 34,688-point sweep per nuScenes frame, a 124k-point KITTI scan, and the synthetic world's
//! generation rate.
//!
//!   cargo run --release -p bevworld-bench --bin sensors

use std::path::PathBuf;
use std::time::Instant;

use bevworld_bench::{markdown_table, percentile, results_dir, write_results};
use bevworld_graph::{
    Inputs, KindSpec, Node, NodeError, Port, Registry, RunOptions, Sink, resolve, run,
};
use bevworld_sensors::synth::{SynthConfig, generate};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_types::SensorFrame;
use serde::{Deserialize, Serialize};

// The node's ports, each named once (`bevworld_graph::Port`).
const FRAME: Port<SensorFrame> = Port::new("frame");

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct NoParams {}

/// Touches every frame so nothing is optimised away.
struct FrameSink;

impl Sink for FrameSink {
    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let frame = inputs.get(&FRAME)?;
        if frame.lidar.is_empty() {
            return Err(NodeError::fatal("empty sweep"));
        }
        Ok(())
    }
}

fn registry() -> Registry {
    let mut registry = Registry::new();
    bevworld_sensors::register(&mut registry);
    registry.register(
        KindSpec::sink("frame_sink", "consumes frames").input(FRAME.spec()),
        |_: NoParams| Ok(Node::Sink(Box::new(FrameSink))),
    );
    registry
}

fn shared_data(name: &str) -> PathBuf {
    bevworld_sensors::data_root().join(name)
}

/// Replays `repeat` frames unpaced through source -> sink; (frames/s, source p50 ms, p99 ms).
fn replay(data: &str, repeat: usize) -> (f64, f64, f64) {
    let yaml = format!(
        "settings: {{progress: false, default_capacity: 2}}\nnodes:\n  - {{id: source, kind: dataset_source, params: {{data: \"{data}\", repeat: {repeat}}}}}\n  - {{id: sink, kind: frame_sink}}\nedges:\n  - {{from: source.frame, to: sink.frame}}\n"
    );
    let graph = resolve(&yaml, "bench", &registry(), &[]).expect("replay graph");
    let started = Instant::now();
    let outcome = run(graph, RunOptions::default());
    let wall = started.elapsed().as_secs_f64();
    if let Some(error) = outcome.error {
        panic!("replay failed: {error}");
    }
    let source = outcome.report.node("source").expect("source");
    let frames = source.items_out as f64;
    (
        frames / wall,
        source.latency_p50_us / 1000.0,
        source.latency_p99_us / 1000.0,
    )
}

/// Fetch + decode of one frame, `n` times, on a rayon pool of `threads`; per-frame ms sorted.
fn decode_loop(dataset: &Dataset, n: usize, threads: usize) -> Vec<f64> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    let mut times: Vec<f64> = pool.install(|| {
        (0..n)
            .map(|_| {
                let started = Instant::now();
                let frame = dataset.read(0).expect("frame");
                assert_eq!(frame.lidar.len(), 34_688);
                started.elapsed().as_secs_f64() * 1000.0
            })
            .collect()
    });
    times.sort_by(f64::total_cmp);
    times
}

fn main() {
    let nuscenes = shared_data("nuscenes-sample");
    let kitti = shared_data("kitti-odometry-00");
    let dataset = Dataset::open(&nuscenes, &DatasetOptions::default()).expect("nuScenes sample");

    let sequential = decode_loop(&dataset, 15, 1);
    let parallel = decode_loop(&dataset, 15, 2);
    let (graph_rate, graph_p50, graph_p99) = replay(&nuscenes.display().to_string(), 40);
    let (kitti_rate, kitti_p50, kitti_p99) = replay(&kitti.display().to_string(), 5);

    let synth_dir =
        std::env::temp_dir().join(format!("bevworld-bench-synth-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&synth_dir);
    let synth = generate(
        &synth_dir,
        &SynthConfig {
            seconds: 2.0,
            ..Default::default()
        },
        |_, _| {},
    )
    .expect("synth");
    let _ = std::fs::remove_dir_all(&synth_dir);

    let ms = |v: f64| format!("{v:.1}");
    let rows = vec![
        vec![
            "nuScenes frame: read + decode, 1 thread".into(),
            format!("{:.1}", 1000.0 / percentile(&sequential, 0.5)),
            ms(percentile(&sequential, 0.5)),
            ms(percentile(&sequential, 0.99)),
        ],
        vec![
            "nuScenes frame: read + decode, 2 threads (cameras in parallel)".into(),
            format!("{:.1}", 1000.0 / percentile(&parallel, 0.5)),
            ms(percentile(&parallel, 0.5)),
            ms(percentile(&parallel, 0.99)),
        ],
        vec![
            "nuScenes frame through the graph (prefetch on the I/O pool)".into(),
            format!("{graph_rate:.1}"),
            ms(graph_p50),
            ms(graph_p99),
        ],
        vec![
            "KITTI scan (124k points) through the graph".into(),
            format!("{kitti_rate:.1}"),
            ms(kitti_p50),
            ms(kitti_p99),
        ],
        vec![
            format!(
                "synthetic world generation, 400x224 cameras, {} points/sweep",
                synth.lidar_points / synth.frames.max(1)
            ),
            format!("{:.2}", synth.frames_per_second()),
            ms(1000.0 / synth.frames_per_second()),
            "-".into(),
        ],
    ];
    let table = markdown_table(
        &["workload", "frames/s", "latency p50 ms", "latency p99 ms"],
        &rows,
    );
    print!("{table}");
    let notes = "A nuScenes frame is six 1600x900 JPEG decodes plus the 34,688-point LIDAR_TOP sweep. \
The graph rows measure the sustainable rate of source -> sink with the next frame's files read on the I/O pool while the current one decodes; \
latency is the source's time per frame. Goal: >= 24 Hz (2x headroom over 12 Hz live replay) on these 2 cores.\n\n![rates](sensors.svg)\n";
    write_results(
        "sensors",
        "Sensor replay and synthetic generation",
        "cargo run --release -p bevworld-bench --bin sensors",
        &table,
        notes,
        &serde_json::json!({
            "nuscenes_decode_1_thread_ms_p50": percentile(&sequential, 0.5),
            "nuscenes_decode_2_threads_ms_p50": percentile(&parallel, 0.5),
            "nuscenes_graph_hz": graph_rate, "nuscenes_graph_p50_ms": graph_p50, "nuscenes_graph_p99_ms": graph_p99,
            "kitti_graph_hz": kitti_rate,
            "synth_frames_per_s": synth.frames_per_second(),
        }),
    );
    if let Err(error) = bevworld_plot::bars_svg(
        &results_dir().join("sensors.svg"),
        "Frames per second (2 cores)",
        "frames/s",
        &[
            (
                "nuScenes decode, 1 thread".into(),
                1000.0 / percentile(&sequential, 0.5),
            ),
            (
                "nuScenes decode, 2 threads".into(),
                1000.0 / percentile(&parallel, 0.5),
            ),
            ("nuScenes through graph".into(), graph_rate),
            ("KITTI through graph".into(), kitti_rate),
            ("synthetic generation".into(), synth.frames_per_second()),
        ],
        false,
    ) {
        eprintln!("{error}");
    }
}
