//! Speed against error for the whole forecast: DDIM step counts, the condition frames' cache,
//! rendering only the requested horizons, and the tokenizer's empty-space skipping.
//!
//! Reads the forecast evaluations that `bench/scripts/speed-vs-error.sh` makes (`eval forecast
//! --json` at each step count, into RUNS/steps-S.json, and RUNS/horizons-all.json with every
//! horizon rendered), times the condition-frame cache itself, and writes
//! `bench/results/speed-vs-error.{md,json,png}`.
//!
//!   bench/scripts/speed-vs-error.sh
//!   cargo run --release -p bevworld-bench --bin speed_error -- out/speed-vs-error
//!
//! With `budget METRICS SCORES` it records this machine's line of the forecast graph's latency
//! budget from one run of the graph instead (`bench/scripts/forecast-budget.sh`,
//! `bevworld_bench::forecast_budget`) and regenerates that table in the page.
//!   cargo run --release -p bevworld-bench --bin speed_error -- budget METRICS.json SCORES.json

use std::path::{Path, PathBuf};
use std::time::Instant;

use bevworld_bench::{
    forecast_budget, machine_record, markdown_table, percentile, results_dir, write_results,
};
use bevworld_blocks::init::random_normal;
use bevworld_plot::{Labelled, Reference, ScatterPlot, scatter_png};
use bevworld_world_model::{
    ContextPasses, DdimConfig, ForecastInputs, LoadedWorldModel, NoiseSchedule, forecast_with,
};
use burn::prelude::*;

/// What the tables mean; their numbers come from the run.
const READING: &str = "## Reading it

- **The step count.** The forecast graph samples with one DDIM step (`rollout.steps: 1`,
  chosen on the validation seeds before this page was made). One step is the fastest and the
  most accurate, in Chamfer and in latent L1, at every horizon. The shipped model predicts v
  under a zero-terminal-SNR schedule, sampled with trailing spacing: from pure noise at t = T its one
  step is the conditional mean, and every further step adds back detail that a point metric
  (L1, Chamfer) charges for. No distilled or consistency model was needed for the few-step
  goal. Every row samples as the graph ships, with the residual shrink after the last step
  (`rollout.shrink`, [forecast.md](forecast.md)); it leaves +3 s as drawn.
- **Latency in the graph.** The rollout's latency is measured inside the forecast graph, which
  encodes and renders other frames on the same two cores meanwhile; the network alone is the
  cache table's figure at the same step count.
- **The condition frames' cache** pays from a few steps on: after the first pass, each step
  runs 6 of the 9 frames, and the saving nears the 33% that predicts at many steps. At two
  steps it saves between 1% and 13% over runs on this VM, inside its noise. With one step
  there is nothing to reuse: both ways run each frame once and time the same within their
  noise (about 10 ms either way over runs on this VM), so `forecast` takes the single pass
  then and caches from two steps on (the default this table chose).
- **Rendering only the requested horizons.** Rendering is most of a forecast's latency;
  three requested horizons instead of all six take half the render time, and a horizon's
  score does not depend on which others are rendered.
- **The static world moved, not re-predicted.** The model predicts a residual over the
  ego-warped current latent. Its cost is the warp on the host (under 2 ms for six frames); what
  it buys, against a model of the latent itself, is in
  [world-model-training.md](world-model-training.md): better at +0.5 s (latent L1 0.426 against
  0.478), worse at +3 s (0.684 against 0.571). The rollout's shrink then keeps the warp
  wherever the sampled residual is under τ, which costs one clamp per frame; on these contexts
  one step's 1 s Chamfer was 1.153 with it and 1.165 without (the weights of 2026-12-05; not
  re-measured since).
- **The tokenizer's skipping** evaluates half the samples at segments of 12 with depth and
  colour indistinguishable from dense, but is not faster on these 2 cores yet: its per-ray
  bookkeeping costs what the skipped samples save (issue 35's subject).
- **Long rollouts.** Chained for 20 s (7 forecasts, each one's last frames the next one's
  context, sampled without the shrink), the forecasts' per-channel RMS stays between 0.62 and 1.27 of the training
  latents' 1 (`tests/hard_cases.rs`). Their error against what really came grows with the
  horizon, below the chained ego warp and the last observed frame copied throughout, though
  by +20 s the margin over the chained warp is small ([long-rollout.md](long-rollout.md), two
  held-out 24 s scenes, has the figures).
- **Memory.** One forecast peaks at 81 MiB at the tiny size and 5.6 GiB at the paper's; a
  tiny training step at 360 MiB ([memory.md](memory.md)).
";

/// The step counts of the report.
const STEPS: [usize; 6] = [1, 2, 4, 8, 16, 50];

fn read(path: &Path) -> Option<serde_json::Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// A method's figure at a horizon (seconds) of an `eval forecast --json` table.
fn figure(table: &serde_json::Value, horizon: f64, method: &str, name: &str) -> f64 {
    table["horizons"]
        .as_array()
        .into_iter()
        .flatten()
        .find(|row| (row["horizon_s"].as_f64().unwrap_or(f64::NAN) - horizon).abs() < 1e-6)
        .and_then(|row| row[method][name].as_f64())
        .unwrap_or(f64::NAN)
}

fn latency(table: &serde_json::Value, name: &str) -> f64 {
    table["latency_ms"][name].as_f64().unwrap_or(f64::NAN)
}

fn fmt(value: f64, digits: usize) -> String {
    if value.is_finite() {
        format!("{value:.digits$}")
    } else {
        "—".into()
    }
}

/// Milliseconds of `run`, the median of `repeats` after one warm-up.
fn median_ms(repeats: usize, mut run: impl FnMut()) -> f64 {
    run();
    let mut times: Vec<f64> = (0..repeats)
        .map(|_| {
            let started = Instant::now();
            run();
            started.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    percentile(&times, 0.5)
}

/// The cache's saving: the shipped model's forecast with the condition frames run once, and
/// run again at every step, on one context.
fn cache_timings(root: &Path) -> Vec<(usize, f64, f64)> {
    let loaded = LoadedWorldModel::shipped_tiny(root, Device::flex()).expect("shipped world model");
    let (config, weights, device) = (&loaded.config, &loaded.weights, loaded.device.clone());
    let [h, w] = config.latent_size;
    let (p, n) = (config.context_frames, config.future_frames);
    // Timing does not depend on the values: a standardised context, ordinary actions.
    let warped = random_normal(3, [1, n, config.latent_channels, h, w], 0.0, 1.0, &device);
    let inputs = ForecastInputs {
        context: random_normal(1, [1, p, config.latent_channels, h, w], 0.0, 1.0, &device),
        actions: random_normal(2, [1, p + n, 5], 0.0, 0.5, &device),
        base: Some(warped.clone()),
        warped,
        fine_tokens: Default::default(),
    };
    let schedule = NoiseSchedule::new(&config.diffusion);
    STEPS
        .iter()
        .map(|&steps| {
            let sampler = DdimConfig::deterministic(steps, 0);
            let repeats = if steps >= 16 { 1 } else { 3 };
            let time = |passes: ContextPasses| {
                median_ms(repeats, || {
                    let _ =
                        forecast_with(&weights.model, config, &schedule, &inputs, &sampler, passes)
                            .expect("forecast")
                            .into_data();
                })
            };
            let cached = time(ContextPasses::Cached);
            let recomputed = time(ContextPasses::EveryStep);
            println!("{steps} steps: cached {cached:.0} ms, recomputed {recomputed:.0} ms");
            (steps, cached, recomputed)
        })
        .collect()
}

/// `budget METRICS SCORES`: this machine's line of the budget, then the page's table again.
fn record_budget(metrics: &Path, scores: &Path) {
    let record = forecast_budget::record(metrics, scores, &bevworld_bench::code_version())
        .unwrap_or_else(|e| panic!("the forecast graph's run: {e}"));
    let results = results_dir();
    let file = forecast_budget::write(&results, &record)
        .unwrap_or_else(|e| panic!("writing the budget record: {e}"));
    let page_path = results.join("speed-vs-error.md");
    let page = std::fs::read_to_string(&page_path)
        .unwrap_or_else(|e| panic!("{}: {e}", page_path.display()));
    let page = forecast_budget::replace_section(&page, &forecast_budget::section(&results));
    bevworld_atomic_file::write(&page_path, page.as_bytes())
        .unwrap_or_else(|e| panic!("writing {}: {e}", page_path.display()));
    println!(
        "{} written; the budget table of {} regenerated",
        file.display(),
        page_path.display()
    );
}

fn main() {
    bevworld_device::keep_freed_memory();
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).is_some_and(|mode| mode == "budget") {
        let [_, _, metrics, scores] = args.as_slice() else {
            eprintln!("usage: speed_error budget METRICS.json SCORES.json");
            std::process::exit(2);
        };
        record_budget(Path::new(metrics), Path::new(scores));
        return;
    }
    let root = bevworld_bench::manifest_dir().join("..");
    let runs = std::env::args()
        .nth(1)
        .map_or_else(|| root.join("out/speed-vs-error"), PathBuf::from);
    let tables: Vec<(usize, serde_json::Value)> = STEPS
        .iter()
        .filter_map(|&s| read(&runs.join(format!("steps-{s}.json"))).map(|t| (s, t)))
        .collect();
    assert!(
        !tables.is_empty(),
        "no {}/steps-S.json: run bench/scripts/speed-vs-error.sh first",
        runs.display()
    );
    let reference = tables
        .iter()
        .find(|(s, _)| *s == 50)
        .or(tables.last())
        .map(|(_, t)| t.clone())
        .expect("a table");
    let reference_steps = tables
        .iter()
        .find(|(s, _)| *s == 50)
        .or(tables.last())
        .map_or(0, |(s, _)| *s);

    // 1. Step counts.
    let mut rows = Vec::new();
    let mut points = Vec::new();
    let mut json_rows = Vec::new();
    let mut labels = Vec::new();
    for (steps, table) in &tables {
        let chamfer_1 = figure(table, 1.0, "model", "chamfer");
        let chamfer_3 = figure(table, 3.0, "model", "chamfer");
        let l1_1 = figure(table, 1.0, "model", "latent_l1");
        let l1_3 = figure(table, 3.0, "model", "latent_l1");
        let relative = |value: f64, name: &str, horizon: f64| {
            let base = figure(&reference, horizon, "model", name);
            100.0 * (value / base - 1.0)
        };
        rows.push(vec![
            steps.to_string(),
            fmt(latency(table, "rollout_p50"), 0),
            fmt(latency(table, "rollout_p99"), 0),
            fmt(latency(table, "with_render_p50"), 0),
            fmt(latency(table, "with_render_p99"), 0),
            format!(
                "{} ± {}",
                fmt(chamfer_1, 3),
                fmt(figure(table, 1.0, "model", "chamfer_scene_std"), 3)
            ),
            format!(
                "{} ± {}",
                fmt(chamfer_3, 3),
                fmt(figure(table, 3.0, "model", "chamfer_scene_std"), 3)
            ),
            fmt(l1_1, 3),
            fmt(l1_3, 3),
            format!(
                "{:+.1}% / {:+.1}% / {:+.1}%",
                relative(chamfer_1, "chamfer", 1.0),
                relative(chamfer_3, "chamfer", 3.0),
                relative(l1_3, "latent_l1", 3.0)
            ),
        ]);
        labels.push(format!(
            "{steps} step{}",
            if *steps == 1 { "" } else { "s" }
        ));
        points.push((latency(table, "rollout_p50"), chamfer_3));
        json_rows.push(serde_json::json!({
            "steps": steps,
            "contexts": table["contexts"],
            "latency_ms": table["latency_ms"],
            "chamfer_1s": chamfer_1,
            "chamfer_3s": chamfer_3,
            "latent_l1_1s": l1_1,
            "latent_l1_3s": l1_3,
        }));
    }
    let contexts = tables[0].1["contexts"].as_u64().unwrap_or(0);
    let step_table = markdown_table(
        &[
            "DDIM steps",
            "rollout p50 (ms)",
            "rollout p99 (ms)",
            "+ render p50 (ms)",
            "+ render p99 (ms)",
            "Chamfer 1 s (m², ± spread over scenes)",
            "Chamfer 3 s (m², ± spread over scenes)",
            "latent L1 1 s",
            "latent L1 3 s",
            &format!("vs {reference_steps} steps: Chamfer 1 s / 3 s / L1 3 s"),
        ],
        &rows,
    );

    // The baselines, from the first table (they do not depend on the step count).
    let first = &tables[0].1;
    let baselines = [
        "latent_ego_warp",
        "latent_copy_last",
        "oracle",
        "ego_warp",
        "copy_last",
    ];
    let baseline_rows: Vec<Vec<String>> = baselines
        .iter()
        .map(|method| {
            vec![
                format!("`{method}`"),
                fmt(figure(first, 1.0, method, "chamfer"), 3),
                fmt(figure(first, 3.0, method, "chamfer"), 3),
                fmt(figure(first, 1.0, method, "latent_l1"), 3),
                fmt(figure(first, 3.0, method, "latent_l1"), 3),
            ]
        })
        .collect();
    let baseline_table = markdown_table(
        &[
            "baseline",
            "Chamfer 1 s",
            "Chamfer 3 s",
            "latent L1 1 s",
            "latent L1 3 s",
        ],
        &baseline_rows,
    );

    // 2. The condition frames' cache.
    let cache = cache_timings(&root);
    let cache_rows: Vec<Vec<String>> = cache
        .iter()
        .map(|(steps, cached, recomputed)| {
            vec![
                steps.to_string(),
                fmt(*recomputed, 0),
                fmt(*cached, 0),
                format!("{:.0}%", 100.0 * (1.0 - cached / recomputed)),
            ]
        })
        .collect();
    let cache_table = markdown_table(
        &[
            "DDIM steps",
            "condition frames every step (ms)",
            "cached once (ms)",
            "saved",
        ],
        &cache_rows,
    );

    // 3. Rendering only the requested horizons.
    let horizons_all = read(&runs.join("horizons-all.json"));
    let one_step = tables.iter().find(|(s, _)| *s == 1).map(|(_, t)| t);
    let horizon_rows: Vec<Vec<String>> = [
        ("3 requested (0.5, 1, 3 s)", one_step),
        ("all 6 (0.5 to 3 s)", horizons_all.as_ref()),
    ]
    .iter()
    .filter_map(|(name, table)| {
        table.map(|t| {
            vec![
                (*name).to_string(),
                fmt(latency(t, "rollout_p50"), 0),
                fmt(latency(t, "with_render_p50"), 0),
                fmt(latency(t, "with_render_p99"), 0),
                fmt(figure(t, 3.0, "model", "chamfer"), 3),
            ]
        })
    })
    .collect();
    let horizon_table = markdown_table(
        &[
            "horizons rendered (1 step)",
            "rollout p50 (ms)",
            "+ render p50 (ms)",
            "+ render p99 (ms)",
            "Chamfer 3 s (m²)",
        ],
        &horizon_rows,
    );

    // 4. The tokenizer's own trade, from bench/results/tokenizer.json.
    let tokenizer = read(&results_dir().join("tokenizer.json"));
    let tokenizer_table = tokenizer.as_ref().map(|t| {
        let rays = t["rays"].as_f64().unwrap_or(f64::NAN);
        let dense = t["render_dense_ms_p50"].as_f64().unwrap_or(f64::NAN);
        let mut rows = vec![vec![
            "dense (every sample)".to_string(),
            fmt(rays / dense / 1e3, 3),
            "0 (reference)".into(),
            "∞ (reference)".into(),
            "100%".into(),
        ]];
        for skip in t["render_skipping"].as_array().into_iter().flatten() {
            let ms = skip["ms_p50"].as_f64().unwrap_or(f64::NAN);
            rows.push(vec![
                format!("skipping, segments of {}", skip["segment"]),
                fmt(rays / ms / 1e3, 3),
                fmt(skip["depth_mae_m"].as_f64().unwrap_or(f64::NAN), 5),
                fmt(skip["colour_psnr_db"].as_f64().unwrap_or(f64::NAN), 1),
                format!(
                    "{:.1}%",
                    100.0 * skip["sample_fraction"].as_f64().unwrap_or(f64::NAN)
                ),
            ]);
        }
        markdown_table(
            &[
                "tokenizer render (real keyframe)",
                "M rays/s",
                "depth error vs dense (m)",
                "colour PSNR vs dense (dB)",
                "samples evaluated",
            ],
            &rows,
        )
    });

    // The plot: ms per forecast (log) against the 3 s Chamfer, baselines across.
    let png = results_dir().join("speed-vs-error.png");
    let references: Vec<(String, f64)> = ["latent_ego_warp", "latent_copy_last", "oracle"]
        .iter()
        .map(|m| (m.to_string(), figure(first, 3.0, m, "chamfer")))
        .collect();
    scatter_png(
        &png,
        &ScatterPlot {
            title: &format!("Forecast speed against 3 s Chamfer ({contexts} held-out contexts)"),
            x_label: "rollout p50, ms per forecast (log)",
            y_label: "LiDAR Chamfer at +3 s (m²)",
            log_x: true,
            points: points
                .iter()
                .zip(&labels)
                .map(|((x, y), label)| Labelled {
                    label,
                    x: *x,
                    y: *y,
                })
                .collect(),
            references: references
                .iter()
                .map(|(label, y)| Reference { label, y: *y })
                .collect(),
        },
    )
    .expect("plot");

    // The few-step goal: 4 steps or fewer within 5% of the reference's error (Chamfer at 1 s
    // and 3 s, latent L1 at 3 s), at least 10 times faster.
    let reference_ms = latency(&reference, "rollout_p50");
    let verdicts: Vec<String> = tables
        .iter()
        .filter(|(s, _)| *s <= 4)
        .map(|(steps, t)| {
            let worst = [("chamfer", 1.0), ("chamfer", 3.0), ("latent_l1", 3.0)]
                .iter()
                .map(|(name, h)| {
                    figure(t, *h, "model", name) / figure(&reference, *h, "model", name) - 1.0
                })
                .fold(f64::NEG_INFINITY, f64::max);
            let faster = reference_ms / latency(t, "rollout_p50");
            let met = worst <= 0.05 && faster >= 10.0;
            format!(
                "- {steps} step(s): worst error {:+.1}% against {reference_steps} steps, {faster:.1}x faster: {}",
                100.0 * worst,
                if met { "**met**" } else { "not met" }
            )
        })
        .collect();
    let mut table = format!(
        "## DDIM steps\n\n{contexts} held-out contexts (test seeds 9500 and 9501, 10 s each), \
         rendered at +0.5, +1 and +3 s; latency per forecast on 2 cores, the rollout alone and \
         with the render of the model's views (6 cameras and the LiDAR sweep at 3 horizons).\n\n\
         {step_table}\n![speed against error](speed-vs-error.png)\n\n{baseline_table}\n\
         The few-step goal (4 steps or fewer within 5% of {reference_steps} steps' error, at \
         least 10x faster):\n\n{}\n\n\
         ## The condition frames' cache\n\n{cache_table}\n\
         ## Rendering only the requested horizons\n\n{horizon_table}\n",
        verdicts.join("\n")
    );
    if let Some(tokenizer) = &tokenizer_table {
        table.push_str(&format!(
            "## The tokenizer: dense rendering against empty-space skipping\n\n{tokenizer}\n"
        ));
    }
    table.push_str(&forecast_budget::section(&results_dir()));
    write_results(
        "speed-vs-error",
        "Speed against error: the forecast's switches",
        "bench/scripts/speed-vs-error.sh",
        &table,
        READING,
        &serde_json::json!({
            "machine": machine_record(),
            "steps": json_rows,
            "cache": cache.iter().map(|(s, c, r)| serde_json::json!({"steps": s, "cached_ms": c, "recomputed_ms": r})).collect::<Vec<_>>(),
            "horizons_all": horizons_all.map(|t| t["latency_ms"].clone()),
        }),
    );
}
