//! Pillarization of real sweeps: the 34,688-point nuScenes sweep and a 124k-point KITTI scan,
//! sparse beside the dense-grid implementation, on one core.
//!
//!   cargo run --release -p bevworld-bench --bin pillarize

use std::time::Instant;

use bevworld_bench::{markdown_table, percentile, results_dir, write_results};
use bevworld_pillarize::dense::pillarize_dense;
use bevworld_pillarize::{Limits, Pillarizer};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_types::PillarGrid;

fn ego_points(dataset: &str) -> Vec<[f32; 4]> {
    let root = bevworld_sensors::data_root().join(dataset);
    let options = DatasetOptions {
        skip_images: true,
        ..Default::default()
    };
    let frame = Dataset::open(&root, &options)
        .expect("dataset")
        .read(0)
        .expect("frame");
    let cloud = &frame.lidar;
    cloud
        .points
        .iter()
        .map(|p| {
            let q = cloud.ego_from_lidar.transform_point3(glam::DVec3::new(
                p.x.into(),
                p.y.into(),
                p.z.into(),
            ));
            [q.x as f32, q.y as f32, q.z as f32, p.intensity]
        })
        .collect()
}

/// Median and p99 time in µs over `runs` calls.
fn time(runs: usize, mut f: impl FnMut() -> usize) -> (f64, f64, usize) {
    let mut pillars = 0;
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let started = Instant::now();
            pillars = std::hint::black_box(f());
            started.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    times.sort_by(f64::total_cmp);
    (percentile(&times, 0.5), percentile(&times, 0.99), pillars)
}

fn main() {
    let grid = PillarGrid::default();
    let limits = Limits::default();
    let mut rows = Vec::new();
    let mut json = serde_json::Map::new();
    let mut bars = Vec::new();
    for (name, dataset) in [
        ("nuScenes LIDAR_TOP", "nuscenes-sample"),
        ("KITTI HDL-64E", "kitti-odometry-00"),
    ] {
        let points = ego_points(dataset);
        let mut pillarizer = Pillarizer::new(grid, limits);
        let (sparse_p50, sparse_p99, pillars) = time(200, || pillarizer.run(&points).len());
        let (dense_p50, dense_p99, dense_pillars) =
            time(30, || pillarize_dense(&grid, limits, &points).len());
        assert_eq!(pillars, dense_pillars);
        let rate = points.len() as f64 / (sparse_p50 * 1e-6);
        rows.push(vec![
            name.to_string(),
            points.len().to_string(),
            pillars.to_string(),
            format!("{sparse_p50:.0} / {sparse_p99:.0}"),
            format!("{:.1} M", rate / 1e6),
            format!("{dense_p50:.0} / {dense_p99:.0}"),
            format!("{:.1}x", dense_p50 / sparse_p50),
        ]);
        json.insert(dataset.into(), serde_json::json!({"points": points.len(), "pillars": pillars, "sparse_us_p50": sparse_p50, "sparse_us_p99": sparse_p99, "dense_us_p50": dense_p50, "points_per_s": rate}));
        bars.push((format!("{name}, sparse"), sparse_p50));
        bars.push((format!("{name}, dense grid"), dense_p50));
    }
    let table = markdown_table(
        &[
            "sweep",
            "points",
            "pillars",
            "sparse µs p50 / p99",
            "points/s",
            "dense grid µs p50 / p99",
            "dense / sparse",
        ],
        &rows,
    );
    print!("{table}");
    write_results(
        "pillarize",
        "Pillarization: sparse vs dense grid, one core",
        "cargo run --release -p bevworld-bench --bin pillarize",
        &table,
        "Grid: the paper's 384 x 384 over x, y in [-80, 80) m, z in [-4.5, 4.5) m; at most 20 points per pillar and 40,000 pillars. \
Both implementations run in the same process on one thread and produce identical pillars (checked). Goal: <= 0.5 ms per nuScenes sweep on one core.\n\n![times](pillarize.svg)\n",
        &serde_json::Value::Object(json),
    );
    if let Err(error) = bevworld_plot::bars_svg(
        &results_dir().join("pillarize.svg"),
        "Pillarization time per sweep (one core)",
        "µs",
        &bars,
        false,
    ) {
        eprintln!("{error}");
    }
}
