//! Our tokenizer beside a PyTorch reference of it, on the same CPU: the half of the side-by-side
//! benchmark that runs here. `bench/scripts/vs-pytorch.sh` runs both halves back to back.
//!
//! - `dump DIR`: loads the shipped tiny weights and the real nuScenes keyframe, writes what the
//!   reference needs (the weights as safetensors, the encoder's input arrays, the rays and
//!   sample depths, our outputs to check against as `.npy`, and `meta.json`), then times each
//!   stage on 1 and on 2 threads and writes `ours.json`;
//! - `report DIR`: reads the rounds' `ours*.json` and the reference's `torch*.json` (when torch
//!   was there), writes this kind of machine's `bench/results/vs-pytorch-<kind>.json` and `.svg`,
//!   and the page `bench/results/vs-pytorch.md` with one section per kind of machine measured.
//!
//!   cargo run --release -p bevworld-bench --bin vs_pytorch -- dump out/vs-pytorch

use std::path::Path;

use bevworld_bench::{markdown_table, nuscenes_keyframe, psnr, time_runs};
use bevworld_blocks::host::{Cores, Right, matrix_product};
use bevworld_blocks::init::random_normal;
use bevworld_blocks::{sinusoidal_1d, sinusoidal_2d, timestep_embedding};
use bevworld_pillarize::Limits;
use bevworld_tokenizer::flops::TokenizerFlops;
use bevworld_tokenizer::render::{OccupancyGrid, SkipOptions, VoxelScene};
use bevworld_tokenizer::{TokenizerConfig, load_weights};
use bevworld_world_model::{ACTION_FEATURES, LoadedWorldModel};
use burn::prelude::*;
use burn::store::{ModuleSnapshot, SafetensorsStore};
use serde_json::{Value, json};

const WEIGHTS: &str = "nodes/tokenizer/weights/tokenizer-tiny.bpk";
const CONFIG: &str = "configs/models/tokenizer-tiny.yaml";

fn main() {
    bevworld_device::keep_freed_memory();
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.as_slice() {
        [mode, dir] if mode == "dump" => dump(Path::new(dir)),
        [mode, dir] if mode == "report" => report(Path::new(dir)),
        // The page again from the machines' JSON files, as `report` writes it.
        [mode] if mode == "page" => write_page(&bevworld_bench::results_dir()),
        [mode, stage, runs] if mode == "profile" => profile(stage, runs.parse().unwrap_or(50)),
        _ => {
            eprintln!(
                "usage: vs_pytorch dump DIR | vs_pytorch report DIR | vs_pytorch page | \
                 vs_pytorch profile encoder|lift|render|skipping|world_model RUNS (one stage in a loop, for perf)"
            );
            std::process::exit(2);
        }
    }
}

fn write_npy(dir: &Path, name: &str, shape: &[usize], values: &[f32]) {
    let bytes = bevworld_sinks::npy::npy_f32(shape, values).expect("npy shape");
    std::fs::write(dir.join(format!("{name}.npy")), bytes).expect("write npy");
}

fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32 tensor")
}

/// Times `f` on a rayon pool of `threads` threads: every op of burn's CPU backend and every
/// host loop of ours runs on the pool it is called from.
fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("rayon pool")
        .install(f)
}

fn dump(dir: &Path) {
    std::fs::create_dir_all(dir).expect("output folder");
    let device = Device::flex();
    let root = bevworld_bench::manifest_dir().join("..");
    let config = TokenizerConfig::from_yaml_file(&root.join(CONFIG)).expect("tiny config");
    let model = load_weights(&config, &root.join(WEIGHTS), &device).expect("shipped weights");
    let mut store = SafetensorsStore::from_file(dir.join("weights.safetensors")).overwrite(true);
    model.save_into(&mut store).expect("weights as safetensors");

    let (frame, pillars, inputs) = nuscenes_keyframe(&config);
    let limits = Limits::default();
    let arrays = inputs
        .encoder_arrays(&frame, &pillars)
        .expect("encoder input");
    let rays = inputs.frame_rays(&frame).expect("rays");
    let scene_depths = config.render.sample_depths();
    let placement = config.voxel_placement();

    // Inputs, as the reference reads them.
    let [cameras, q, k] = arrays.reference_shape;
    let slots = arrays.pillar_slots;
    let count = arrays.pillar_cells.len();
    write_npy(dir, "images", &arrays.image_shape, &arrays.images);
    write_npy(
        dir,
        "pillar_points",
        &[count, slots, 9],
        &arrays.pillar_points,
    );
    write_npy(dir, "pillar_valid", &[count, slots], &arrays.pillar_valid);
    let cells: Vec<f32> = arrays.pillar_cells.iter().map(|&c| c as f32).collect();
    write_npy(dir, "pillar_cells", &[count], &cells);
    write_npy(dir, "reference", &[cameras, q, k, 2], &arrays.reference);
    write_npy(
        dir,
        "reference_valid",
        &[cameras, q, k],
        &arrays.reference_valid,
    );
    let flat = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<f32>>();
    let (nc, nl) = (rays.camera.len(), rays.lidar.len());
    for (sensor, set) in [("camera", &rays.camera), ("lidar", &rays.lidar)] {
        let n = set.len();
        write_npy(
            dir,
            &format!("{sensor}_origins"),
            &[n, 3],
            &flat(&set.origins),
        );
        write_npy(
            dir,
            &format!("{sensor}_directions"),
            &[n, 3],
            &flat(&set.directions),
        );
    }
    write_npy(dir, "depths", &[scene_depths.len()], &scene_depths);

    // Our outputs, for the reference to check itself against before it times anything.
    let encoded = model.encode(arrays.to_input(&device));
    let latent = encoded.latent.clone();
    write_npy(dir, "latent", &latent.dims(), &host(latent.clone()));
    let voxels = model.voxels(latent.clone());
    let table = voxels.table().clone();
    write_npy(dir, "voxel_table", &table.dims(), &host(table));
    let scene = VoxelScene::new(&model, &config, voxels.clone());
    let camera = scene.render_dense(&rays.camera);
    let lidar = scene.render_dense(&rays.lidar);
    let rgb = scene.camera_planes(&camera, &rays);
    let [h, w] = config.image_size;
    write_npy(dir, "rgb", &[rays.cameras, 3, h, w], &rgb);
    write_npy(dir, "lidar_depth", &[nl], &lidar.depth);
    write_npy(dir, "camera_opacity", &[nc], &camera.opacity);

    let flops = TokenizerFlops::of(&config, pillars.len(), limits.max_points_per_pillar);
    let dense_samples = (nc + nl) * scene_depths.len();
    std::fs::write(
        dir.join("meta.json"),
        serde_json::to_string_pretty(&json!({
            "config": CONFIG,
            "model": serde_json::to_value(&config).expect("config as json"),
            "weights": WEIGHTS,
            // The skipping renderer's saving depends on how much of the field is empty, which
            // the weights decide: the page names the ones it measured.
            "weights_digest": bevworld_tokenizer::weights_digest(&root.join(WEIGHTS))
                .expect("shipped weights' digest"),
            "frame": frame.frame_token,
            "pillars": count,
            "camera_rays": nc,
            "lidar_rays": nl,
            "ray_grid": [rays.cameras, rays.rows, rays.columns],
            "samples": scene_depths.len(),
            "rgb_values": rgb.len(),
            "chunk": scene.chunk,
            "voxel_min": placement.min,
            "voxel_size": placement.voxel_size,
            "voxels_zyx": voxels.shape.voxels(),
            "flops": {
                "encoder": flops.encoder(),
                "lift": flops.lift,
                "render_dense": flops.render(dense_samples as u64, rays.cameras),
            },
        }))
        .expect("json"),
    )
    .expect("meta.json");

    // Timings: the same stages, from the same arrays, on 1 and on 2 threads.
    let runs = 10;
    let read = |t: Tensor<4>| host(t.sum().reshape([1]))[0];
    let mut timings = serde_json::Map::new();
    for threads in [1usize, 2] {
        let stage = on_threads(threads, || {
            let prepare = time_runs(runs, || {
                inputs
                    .encoder_arrays(&frame, &pillars)
                    .expect("encoder input")
            });
            let encoder = time_runs(runs, || {
                let latent = model.encode(arrays.to_input(&device)).latent;
                std::hint::black_box(read(latent))
            });
            let lift = time_runs(runs, || {
                let field = model.voxels(latent.clone());
                std::hint::black_box(host(field.table().clone().sum().reshape([1]))[0])
            });
            let dense = time_runs(5, || {
                let camera = scene.render_dense(&rays.camera);
                let lidar = scene.render_dense(&rays.lidar);
                (scene.camera_planes(&camera, &rays), lidar.depth)
            });
            let options = SkipOptions::default();
            let skipping = time_runs(5, || {
                let grid = OccupancyGrid::build(&scene, &options);
                let camera = scene.render_skipping(&grid, &rays.camera, &options);
                let lidar = scene.render_skipping(&grid, &rays.lidar, &options);
                (
                    scene.camera_planes(&camera, &rays),
                    lidar.depth,
                    camera.samples_evaluated + lidar.samples_evaluated,
                )
            });
            let matmul = bevworld_device::matmul_gflops(&device, 512, 5).unwrap_or(f64::NAN);
            let host_matmul = host_matmul_gflops(512, 5);
            let (dense_rgb, dense_depth) = &dense.2;
            let (skip_rgb, skip_depth, evaluated) = &skipping.2;
            let depth_mae = dense_depth
                .iter()
                .zip(skip_depth)
                .map(|(a, b)| f64::from((a - b).abs()))
                .sum::<f64>()
                / nl.max(1) as f64;
            json!({
                "inputs_ms": prepare.0,
                "encoder_ms": encoder.0,
                "lift_ms": lift.0,
                "render_dense_ms": dense.0,
                "render_skipping_ms": skipping.0,
                "skipping_sample_fraction": *evaluated as f64 / dense_samples as f64,
                "skipping_depth_mae_m": depth_mae,
                "skipping_colour_psnr_db": psnr(dense_rgb, skip_rgb),
                "matmul_gflops": matmul,
                "host_matmul_gflops": host_matmul,
            })
        });
        println!("ours, {threads} thread(s): {stage}");
        timings.insert(threads.to_string(), stage);
    }
    let world_model = dump_world_model(dir, &root, &device);
    timings.insert("world_model".into(), world_model);
    timings.insert("machine".into(), bevworld_bench::machine_record());
    std::fs::write(
        dir.join("ours.json"),
        serde_json::to_string_pretty(&Value::Object(timings)).expect("json"),
    )
    .expect("ours.json");
    println!("wrote {}", dir.display());
}

/// The rate of our own `n × n` product, the call the models' linear layers make
/// (`host::matrix_product` on every core), in GFLOP/s: the best of `reps` after a warm-up, as
/// `bevworld_device::matmul_gflops` times burn's `Tensor::matmul` on the same operands' sizes.
fn host_matmul_gflops(n: usize, reps: usize) -> f64 {
    let ramp = |offset: f32| -> Vec<f32> {
        (0..n * n)
            .map(|i| ((i % 97) as f32 - 48.0 + offset) / 48.0)
            .collect()
    };
    let (a, b) = (ramp(0.0), ramp(0.5));
    let mut product = vec![0f32; n * n];
    let mut run = || {
        matrix_product(
            &mut product,
            &a,
            Right::AsIs(&b),
            [n, n, n],
            1.0,
            false,
            Cores::All,
        );
        std::hint::black_box(&product);
    };
    run();
    let best = (0..reps.max(1))
        .map(|_| {
            let started = std::time::Instant::now();
            run();
            started.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min);
    2.0 * (n as f64).powi(3) / best / 1e9
}

/// One stage run `runs` times on the default pool, nothing written: for `perf record`.
fn profile(stage: &str, runs: usize) {
    let device = Device::flex();
    let root = bevworld_bench::manifest_dir().join("..");
    if stage == "world_model" {
        let loaded = LoadedWorldModel::shipped_tiny(&root, device.clone()).expect("world model");
        let config = &loaded.config;
        let frames = config.context_frames + config.future_frames;
        let [h, w] = config.latent_size;
        let latents = random_normal(
            5,
            [1, frames, config.latent_channels, h, w],
            0.0,
            1.0,
            &device,
        );
        let actions = random_normal(6, [1, frames, ACTION_FEATURES], 0.0, 1.0, &device);
        let warped = random_normal(
            7,
            [1, config.future_frames, config.latent_channels, h, w],
            0.0,
            1.0,
            &device,
        );
        let levels = vec![0.0; frames];
        let started = std::time::Instant::now();
        for _ in 0..runs {
            let out = loaded.weights.model.forward(
                latents.clone(),
                actions.clone(),
                &levels,
                config.future_frames,
                Some(warped.clone()),
            );
            std::hint::black_box(host(out));
        }
        println!(
            "world model: {:.1} ms per run",
            started.elapsed().as_secs_f64() * 1e3 / runs as f64
        );
        return;
    }
    let config = TokenizerConfig::from_yaml_file(&root.join(CONFIG)).expect("tiny config");
    let model = load_weights(&config, &root.join(WEIGHTS), &device).expect("shipped weights");
    let (frame, pillars, inputs) = nuscenes_keyframe(&config);
    let arrays = inputs.encoder_arrays(&frame, &pillars).expect("inputs");
    let latent = model.encode(arrays.to_input(&device)).latent;
    let voxels = model.voxels(latent.clone());
    let rays = inputs.frame_rays(&frame).expect("rays");
    let scene = VoxelScene::new(&model, &config, voxels);
    let started = std::time::Instant::now();
    for _ in 0..runs {
        match stage {
            "encoder" => {
                std::hint::black_box(host(model.encode(arrays.to_input(&device)).latent));
            }
            "lift" => {
                std::hint::black_box(host(model.voxels(latent.clone()).table().clone()));
            }
            "skipping" => {
                let options = SkipOptions::default();
                let built = std::time::Instant::now();
                let grid = OccupancyGrid::build(&scene, &options);
                eprintln!(
                    "occupancy grid: {:.1} ms",
                    built.elapsed().as_secs_f64() * 1e3
                );
                let camera = scene.render_skipping(&grid, &rays.camera, &options);
                std::hint::black_box(scene.camera_planes(&camera, &rays));
                std::hint::black_box(scene.render_skipping(&grid, &rays.lidar, &options));
            }
            _ => {
                let camera = scene.render_dense(&rays.camera);
                std::hint::black_box(scene.camera_planes(&camera, &rays));
                std::hint::black_box(scene.render_dense(&rays.lidar));
            }
        }
    }
    println!(
        "{stage}: {:.1} ms per run",
        started.elapsed().as_secs_f64() * 1e3 / runs as f64
    );
}

/// The world model's half: its weights, one network pass's inputs (3 condition frames and 6
/// future frames at the first DDIM step of the shipped sampler) and output, and that pass's
/// time on 1 and 2 threads.
fn dump_world_model(dir: &Path, root: &Path, device: &Device) -> Value {
    let loaded = LoadedWorldModel::shipped_tiny(root, device.clone()).expect("shipped world model");
    let (model, config) = (&loaded.weights.model, &loaded.config);
    let mut store =
        SafetensorsStore::from_file(dir.join("world_model.safetensors")).overwrite(true);
    model
        .save_into(&mut store)
        .expect("world model weights as safetensors");
    let (context, future) = (config.context_frames, config.future_frames);
    let frames = context + future;
    let [height, width] = config.latent_size;
    let channels = config.latent_channels;
    // Standardised latents are about N(0, 1); the actions are normalised features.
    let latents = random_normal(5, [1, frames, channels, height, width], 0.0, 1.0, device);
    let actions = random_normal(6, [1, frames, ACTION_FEATURES], 0.0, 1.0, device);
    let top = (config.diffusion.steps - 1) as f32;
    let levels: Vec<f32> = (0..frames)
        .map(|f| if f < context { 0.0 } else { top })
        .collect();
    let patch = config.patch;
    let (rows, columns) = (height / patch, width / patch);
    let write = |name: &str, t: Tensor<2>| write_npy(dir, name, &t.dims(), &host(t));
    write(
        "wm_time_embedding",
        timestep_embedding(&levels, config.condition_half, device),
    );
    write(
        "wm_space",
        sinusoidal_2d(rows, columns, config.width, device),
    );
    write("wm_time", sinusoidal_1d(frames, config.width, device));
    write_npy(dir, "wm_latents", &latents.dims(), &host(latents.clone()));
    write_npy(dir, "wm_actions", &actions.dims(), &host(actions.clone()));
    // The future frames' ego-warped current latent, which a model with `ego_warp_input` embeds.
    let warped = random_normal(7, [1, future, channels, height, width], 0.0, 1.0, device);
    write_npy(dir, "wm_warped", &warped.dims(), &host(warped.clone()));
    let output = model.forward(
        latents.clone(),
        actions.clone(),
        &levels,
        future,
        Some(warped.clone()),
    );
    write_npy(dir, "wm_output", &output.dims(), &host(output));
    std::fs::write(
        dir.join("world_model.json"),
        serde_json::to_string_pretty(&json!({
            "config": serde_json::to_value(config).expect("config as json"),
            "context": context,
            "future": future,
        }))
        .expect("json"),
    )
    .expect("world_model.json");
    let mut times = serde_json::Map::new();
    for threads in [1usize, 2] {
        let ms = on_threads(threads, || {
            time_runs(5, || {
                let out = model.forward(
                    latents.clone(),
                    actions.clone(),
                    &levels,
                    future,
                    Some(warped.clone()),
                );
                std::hint::black_box(host(out.sum().reshape([1]))[0])
            })
            .0
        });
        println!("ours, world model pass, {threads} thread(s): {ms:.1} ms");
        times.insert(threads.to_string(), json!(ms));
    }
    Value::Object(times)
}

fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

/// Every `<stem>*.json` of `dir`: one per round of the script.
fn rounds(dir: &Path, stem: &str) -> Vec<Value> {
    let mut paths: Vec<_> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    p.file_name()
                        .and_then(|n| n.to_str())
                        .is_some_and(|n| n.starts_with(stem) && n.ends_with(".json"))
                })
                .collect()
        })
        .unwrap_or_default();
    paths.sort();
    paths.iter().filter_map(|p| read_json(p)).collect()
}

/// The rounds merged: each number the median of its values over the rounds, anything else
/// the first round's.
fn median_of_rounds(rounds: &[Value]) -> Option<Value> {
    let first = rounds.first()?;
    Some(match first {
        Value::Number(_) => {
            let mut values: Vec<f64> = rounds.iter().filter_map(Value::as_f64).collect();
            values.sort_by(f64::total_cmp);
            json!(bevworld_bench::percentile(&values, 0.5))
        }
        Value::Object(fields) => Value::Object(
            fields
                .keys()
                .filter_map(|key| {
                    let column: Vec<Value> =
                        rounds.iter().filter_map(|r| r.get(key).cloned()).collect();
                    median_of_rounds(&column).map(|v| (key.clone(), v))
                })
                .collect(),
        ),
        other => other.clone(),
    })
}

/// The stages of the table: label, key, and the key of their analytic FLOPs.
const STAGES: [(&str, &str, Option<&str>); 5] = [
    (
        "encoder (from its input arrays)",
        "encoder",
        Some("encoder"),
    ),
    ("voxel lift", "lift", Some("lift")),
    (
        "render, dense, with the RGB upsampler",
        "render_dense",
        Some("render_dense"),
    ),
    ("render, skipping", "render_skipping", None),
    (
        "world model, one network pass (3 + 6 frames)",
        "world_model",
        None,
    ),
];

fn get(v: &Value, path: &[&str]) -> Option<f64> {
    path.iter().try_fold(v, |v, key| v.get(*key))?.as_f64()
}

fn ms(v: Option<f64>) -> String {
    v.map_or("—".to_string(), |v| format!("{v:.1}"))
}

/// Our time of a stage on `threads` threads (the world model's sit under their own key).
fn ours_ms(ours: &Value, key: &str, threads: &str) -> Option<f64> {
    if key == "world_model" {
        get(ours, &["world_model", threads])
    } else {
        get(ours, &[threads, &format!("{key}_ms")])
    }
}

/// Merges this machine's rounds into `bench/results/vs-pytorch-<kind>.json` (one file per kind
/// of machine, so that each CPU kind keeps its own table) and writes the page from every such
/// file.
fn report(dir: &Path) {
    let our_rounds = rounds(dir, "ours");
    let torch_rounds = rounds(dir, "torch");
    let ours = median_of_rounds(&our_rounds).expect("ours*.json: run `vs_pytorch dump` first");
    let meta = read_json(&dir.join("meta.json")).expect("meta.json");
    let torch = median_of_rounds(&torch_rounds);
    let machine = our_rounds
        .first()
        .and_then(|r| r.get("machine").cloned())
        .unwrap_or_else(bevworld_bench::machine_record);
    let kind = bevworld_bench::machine_kind(&machine);
    let record = json!({
        "machine": machine,
        // The rounds ran just before, from this checkout (`bench/scripts/vs-pytorch.sh`).
        "commit": bevworld_bench::code_version(),
        "rounds": our_rounds.len(),
        "ours": ours,
        "torch": torch,
        "meta": meta,
    });
    let results = bevworld_bench::results_dir();
    let file = results.join(format!("vs-pytorch-{kind}.json"));
    bevworld_atomic_file::write(
        &file,
        serde_json::to_string_pretty(&record)
            .expect("json")
            .as_bytes(),
    )
    .expect("the machine's figures");
    println!("wrote {}", file.display());
    write_page(&results);
}

/// `bench/results/vs-pytorch.md` from every `vs-pytorch-<kind>.json`: one section per kind
/// of machine, then what holds for all of them.
fn write_page(results: &Path) {
    let mut sections = Vec::new();
    for (kind, path) in bevworld_bench::kind_records(results, "vs-pytorch-") {
        let Some(record) = read_json(&path) else {
            continue;
        };
        sections.push(machine_section(results, &kind, &record));
    }
    let page = format!(
        "# The tiny tokenizer and world model beside a PyTorch reference, on each kind of CPU\n\n\
         Reproduce: `bench/scripts/vs-pytorch.sh` (it adds or replaces the section of the \
         machine it runs on).\n\n{}\n{}{}",
        sections.join("\n"),
        common_notes(results),
        gemm_kernels(results)
    );
    bevworld_atomic_file::write(&results.join("vs-pytorch.md"), page.as_bytes())
        .expect("vs-pytorch.md");
    println!(
        "results written to {}",
        results.join("vs-pytorch.md").display()
    );
}

/// One machine's table, its agreement and setup, and its goals, met or missed.
fn machine_section(results: &Path, kind: &str, record: &Value) -> String {
    draw_bars(results, kind, record);
    // A record without our own product's rate predates the host kernels of attention, linear
    // layers and adaLN: say so rather than let its times stand for today's code.
    // A record without the commit predates the world model's packed attention.
    let era = if get(&record["ours"], &["2", "host_matmul_gflops"]).is_none() {
        "*Measured before our host kernels for attention, linear layers and adaLN, and before \
         `fast_math::exp` lost its saturating conversion: these times are of the code then, not \
         re-measured since.*\n\n"
            .to_string()
    } else if let Some(commit) = record["commit"].as_str() {
        format!("Code: commit `{commit}`.\n\n")
    } else {
        "*Measured before the world model's attention read its packed projection in place \
         (commit `5a90777`): the world model's time is of the code then, not re-measured \
         since.*\n\n"
            .to_string()
    };
    format!(
        "## {kind}\n\n{era}Machine: {}\n\n{}\n{}\n\n{}\n\n{}\n\n### Goals on this machine\n\n{}\n\n![ours \
         against PyTorch on {kind}](vs-pytorch-{kind}.svg)\n",
        machine_line(record),
        stage_table(record),
        matmul_line(record),
        agreement(record),
        input_line(record),
        goals(record).join("\n")
    )
}

/// Per stage: ours and PyTorch's times, their ratios, and the rates.
fn stage_table(record: &Value) -> String {
    let ours = &record["ours"];
    let meta = &record["meta"];
    let torch = record.get("torch").filter(|t| !t.is_null());
    let mut rows = Vec::new();
    for (label, key, flop_key) in STAGES {
        let field = format!("{key}_ms");
        let (ours1, ours2) = (ours_ms(ours, key, "1"), ours_ms(ours, key, "2"));
        let eager1 = torch.and_then(|t| get(t, &["eager", "1", &field]));
        let eager2 = torch.and_then(|t| get(t, &["eager", "2", &field]));
        let compiled = torch.and_then(|t| get(t, &["compiled", "2", &field]));
        let ratio = |theirs: Option<f64>| match (theirs, ours2) {
            (Some(t), Some(o)) => format!("{:.2}×", t / o),
            _ => "—".into(),
        };
        let flop = flop_key.and_then(|f| get(meta, &["flops", f]));
        let rate = |t: Option<f64>| match (flop, t) {
            (Some(f), Some(t)) => format!("{:.1}", f / (t * 1e-3) / 1e9),
            _ => "—".into(),
        };
        rows.push(vec![
            label.to_string(),
            ms(ours1),
            ms(ours2),
            ms(eager1),
            ms(eager2),
            ms(compiled),
            ratio(eager2),
            ratio(compiled),
            flop.map_or("—".into(), |f| format!("{:.3}", f / 1e9)),
            format!("{} / {}", rate(ours2), rate(eager2)),
        ]);
    }
    markdown_table(
        &[
            "stage",
            "ours, 1 thread (ms)",
            "ours, 2 threads",
            "PyTorch eager, 1 thread",
            "PyTorch eager, 2 threads",
            "torch.compile, 2 threads",
            "eager 2t / ours 2t",
            "compile / ours 2t",
            "GFLOP",
            "GFLOP/s ours / eager (2 threads)",
        ],
        &rows,
    )
}

/// The CPU, its vector instructions and the kernels each side ran.
fn machine_line(record: &Value) -> String {
    let machine = &record["machine"];
    let torch = record.get("torch").filter(|t| !t.is_null());
    let simd: Vec<&str> = machine["simd"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    format!(
        "{} cores, {}; vector instructions: {}; our host kernels dispatch to {}, matrix products \
         run {}{}.",
        machine["cores"]
            .as_u64()
            .map_or("?".into(), |c| c.to_string()),
        machine["cpu"].as_str().unwrap_or("?"),
        if simd.is_empty() {
            "not recorded".to_string()
        } else {
            simd.join(" ")
        },
        machine["host_kernels"].as_str().unwrap_or("(not recorded)"),
        machine["matmul_kernels"]
            .as_str()
            .unwrap_or("(not recorded)"),
        torch
            .and_then(|t| t["cpu_capability"].as_str())
            .map_or(String::new(), |c| format!(
                "; PyTorch's CPU capability: {c}"
            )),
    )
}

/// The 512² matmul rate of both sides.
fn matmul_line(record: &Value) -> String {
    let ours = &record["ours"];
    let torch = record.get("torch").filter(|t| !t.is_null());
    format!(
        "Matmul rate at 512², same run, GFLOP/s on 1 / 2 threads: ours, the product the \
         models' linear layers call (`host::matrix_product`), {} / {}; burn's `Tensor::matmul` \
         {} / {}; PyTorch {} / {}.",
        ms(get(ours, &["1", "host_matmul_gflops"])),
        ms(get(ours, &["2", "host_matmul_gflops"])),
        ms(get(ours, &["1", "matmul_gflops"])),
        ms(get(ours, &["2", "matmul_gflops"])),
        ms(torch.and_then(|t| get(t, &["eager", "1", "matmul_gflops"]))),
        ms(torch.and_then(|t| get(t, &["eager", "2", "matmul_gflops"]))),
    )
}

/// How far the reference's outputs are from ours, and its build.
fn agreement(record: &Value) -> String {
    let meta = &record["meta"];
    let torch = record.get("torch").filter(|t| !t.is_null());
    match torch {
        Some(t) => {
            let a = |key: &str| t["agreement"][key].as_f64().unwrap_or(f64::NAN);
            format!(
                "The reference checked itself against our outputs before timing: latent max \
                 |Δ| {:.1e}, voxel table max |Δ| {:.1e}, RGB max |Δ| {:.1e} ({:.0} 8-bit \
                 levels differ of {}), LiDAR depth max |Δ| {:.1e} m, world model output max \
                 |Δ| {:.1e}. PyTorch {} ({}), allocator: {}; ours: mimalloc.",
                a("latent_max_abs"),
                a("voxel_table_max_abs"),
                a("rgb_max_abs"),
                a("rgb_8bit_levels_differing"),
                meta["rgb_values"],
                a("lidar_depth_max_abs_m"),
                a("world_model_max_abs"),
                t["torch_version"].as_str().unwrap_or("?"),
                t["build"].as_str().unwrap_or("?"),
                t["allocator"].as_str().unwrap_or("?"),
            )
        }
        None => "PyTorch was not found, so only our side ran: `bench/scripts/vs-pytorch.sh` \
                 says how to install it."
            .into(),
    }
}

/// The input, the weights and how the times were taken.
fn input_line(record: &Value) -> String {
    let ours = &record["ours"];
    let meta = &record["meta"];
    format!(
        "Input: the real nuScenes keyframe ({} pillars, {} camera rays, {} LiDAR rays, {} \
         samples each, rendered in chunks of {} rays on both sides), the weights `{}` (digest \
         `{}`). Each time is the median over {} rounds run alternately (ours, then PyTorch) of \
         each round's median after a warm-up. The encoder starts from the same arrays on both \
         sides; preparing them from the decoded frame is ours alone and takes {} / {} ms on 1 / \
         2 threads.",
        meta["pillars"],
        meta["camera_rays"],
        meta["lidar_rays"],
        meta["samples"],
        meta["chunk"],
        meta["weights"].as_str().unwrap_or(WEIGHTS),
        meta["weights_digest"].as_str().unwrap_or("not recorded"),
        record["rounds"]
            .as_u64()
            .map_or("?".into(), |r| r.to_string()),
        ms(get(ours, &["1", "inputs_ms"])),
        ms(get(ours, &["2", "inputs_ms"])),
    )
}

/// The goals of issue 55, checked on this machine's figures.
fn goals(record: &Value) -> Vec<String> {
    let ours = &record["ours"];
    let torch = record.get("torch").filter(|t| !t.is_null());
    let mut goals = Vec::new();
    for (threads, label) in [("1", "1 thread"), ("2", "2 threads")] {
        let theirs = torch.and_then(|t| get(t, &["eager", threads, "matmul_gflops"]));
        // Pages measured before the models had their own product judge burn's.
        let (key, path) = match get(ours, &[threads, "host_matmul_gflops"]) {
            Some(_) => ("host_matmul_gflops", "our linear layers' product"),
            None => ("matmul_gflops", "burn's matmul"),
        };
        if let (Some(m), Some(t)) = (get(ours, &[threads, key]), theirs) {
            goals.push(format!(
                "- matmul on {label} ({path}): {:.0}% of PyTorch's GFLOP/s ({m:.1} against {t:.1}); the goal is ≥ 90%: {}",
                100.0 * m / t,
                if m >= 0.9 * t { "met" } else { "MISSED" }
            ));
        }
    }
    for (_, key, _) in STAGES {
        let field = format!("{key}_ms");
        let mine = ours_ms(ours, key, "2");
        let eager = torch.and_then(|t| get(t, &["eager", "2", &field]));
        let compiled = torch.and_then(|t| get(t, &["compiled", "2", &field]));
        if let (Some(o), Some(e)) = (mine, eager) {
            goals.push(format!(
                "- {key}: {} eager on 2 threads ({o:.1} ms against {e:.1} ms){}",
                if o <= e {
                    "at least as fast as"
                } else {
                    "SLOWER than"
                },
                match compiled {
                    Some(c) if key == "lift" => format!(
                        "; {} half of torch.compile's {c:.1} ms (the goal)",
                        if o <= c / 2.0 { "within" } else { "NOT within" }
                    ),
                    _ => String::new(),
                }
            ));
        }
    }
    let dense2 = ours_ms(ours, "render_dense", "2").unwrap_or(f64::NAN);
    let skip2 = ours_ms(ours, "render_skipping", "2").unwrap_or(f64::NAN);
    goals.push(format!(
        "- skipping against dense: {:.2}× faster ({dense2:.1} ms against {skip2:.1} ms, {:.0}% \
         of the samples evaluated); the goal is 3×: {}",
        dense2 / skip2,
        100.0 * get(ours, &["2", "skipping_sample_fraction"]).unwrap_or(f64::NAN),
        if dense2 >= 3.0 * skip2 {
            "met"
        } else {
            "MISSED"
        }
    ));
    let enc1 = ours_ms(ours, "encoder", "1").unwrap_or(f64::NAN);
    let enc2 = ours_ms(ours, "encoder", "2").unwrap_or(f64::NAN);
    goals.push(format!(
        "- both cores in inference: the encoder takes {enc1:.1} ms on 1 thread and {enc2:.1} ms \
         on 2 ({:.2}× speed-up)",
        enc1 / enc2
    ));
    goals
}

/// The stages' times on 2 threads, ours beside PyTorch's, as bars.
fn draw_bars(results: &Path, kind: &str, record: &Value) {
    let ours = &record["ours"];
    let torch = record.get("torch").filter(|t| !t.is_null());
    let plot = results.join(format!("vs-pytorch-{kind}.svg"));
    let mut bars = Vec::new();
    for (label, key, _) in STAGES {
        let field = format!("{key}_ms");
        let short = label.split(" (").next().unwrap_or(label);
        bars.push((
            format!("{short}: ours"),
            ours_ms(ours, key, "2").unwrap_or(f64::NAN),
        ));
        bars.push((
            format!("{short}: PyTorch eager"),
            torch
                .and_then(|t| get(t, &["eager", "2", &field]))
                .unwrap_or(f64::NAN),
        ));
        bars.push((
            format!("{short}: torch.compile"),
            torch
                .and_then(|t| get(t, &["compiled", "2", &field]))
                .unwrap_or(f64::NAN),
        ));
    }
    if let Err(error) = bevworld_plot::bars_svg(
        &plot,
        &format!("{kind}, 2 threads: ours against PyTorch"),
        "ms (median of rounds)",
        &bars,
        false,
    ) {
        eprintln!("plot: {error}");
    }
}

/// What holds on every machine: why the misses are misses, and the training step.
fn common_notes(results: &Path) -> String {
    let occupied = read_json(&results.join("tokenizer.json"))
        .and_then(|t| t["occupied_fraction"].as_f64())
        .unwrap_or(f64::NAN);
    let train = read_json(&results.join("train_step.json"));
    let step_s = train.as_ref().and_then(|t| {
        t["steps"]
            .as_array()?
            .iter()
            .find(|s| s["threads"].as_u64() == Some(2))?["seconds_per_step"]
            .as_f64()
    });
    let backward_share = train.as_ref().and_then(|t| {
        let phases = t["phases_ms"].as_array()?;
        let total: f64 = phases.iter().filter_map(|p| p["ms"].as_f64()).sum();
        let backward = phases
            .iter()
            .find(|p| p["phase"].as_str() == Some("backward"))?["ms"]
            .as_f64()?;
        Some(backward / total)
    });
    format!(
        "## On every machine\n\n\
         - **Matrix products.** burn's CPU backend multiplies through `gemm`, which picks its \
         micro-kernel at run time from the instructions it was compiled with. Its AVX-512 \
         kernels sit behind the `x86-v4` feature, which burn forwards and the workspace turns on \
         (`Cargo.toml`); without it an AVX-512 CPU ran the AVX2 kernels (the last table measures \
         what that cost on the Xeon). `bevworld device` prints the CPU, its vector instructions and the kernels they \
         select; a unit test holds our host kernels' dispatch to what the CPU reports.\n\
         - **burn's `Tensor::matmul` against the product itself.** burn's CPU backend makes \
         every op's output with `FlexTensor::empty`, which zero-fills a `Vec<u8>` and hands it \
         to `Bytes::from_bytes_vec`; a byte vector's alignment is 1, so \
         `try_enforce_runtime_align` copies it into a 16-byte-aligned allocation \
         (burn-flex 0.22.1 `tensor.rs`, cubecl-environment 0.11.3 `bytes/base.rs`). A 512² \
         product's output is written three times, and fresh pages are faulted in twice: that, \
         not gemm, is why `Tensor::matmul` trails PyTorch on the Xeon. Reproduction: \
         `gemm::gemm` called directly on 512² operands (`Parallelism::Rayon(0)`, as burn calls \
         it; `host_matmul_gflops` in `bench/src/bin/vs_pytorch.rs`) against `Tensor::matmul` \
         (`bevworld_device::matmul_gflops`), the two rates of ours above. It needs a change in burn (allocate aligned `f32` storage, not bytes), which we \
         cannot make from outside without a fork; our models no longer go through it for their \
         linear layers (`linear_on_host`: the output starts as the bias and gemm accumulates \
         onto it) nor their attention (`attention_on_host`).\n\
         - **The lift against torch.compile** is missed. The lift is Swin blocks at 16–32 \
         channels; compile fuses each block's norms, GELU and residuals into few kernels, while \
         ours still runs its norms and residuals as separate burn ops around our attention and \
         linear kernels. `perf` on the AVX-512 EPYC puts about two fifths of the lift in the \
         window attention kernel itself (64-token windows of 8–16 channels a head, too small \
         for gemm to pay) and much of the rest in writing the head's 16.8 MB voxel table: the \
         bias copied in, gemm's accumulation, and burn's copy into an aligned allocation. \
         Folding the kernel's reductions pairwise instead of in one running sum was tried and \
         did not move the lift's time beyond the noise, so it was not kept.\n\
         - **The world model against eager.** Its attention reads the packed `[tokens, 3·C]` \
         projection where it lies (`packed_attention_on_host`, commit `5a90777`): one \
         (sequence, head) per task, its logits kept in L2, each product reading its head by \
         strides, for the spatial attention within each frame and the temporal attention \
         across frames alike, so the heads are no longer split into copies and the `[B, F, L, \
         D]` tokens no longer regrouped by place and back; only the condition frames' cache \
         copies its keys and values out. Its adaLN norm and modulation are one pass per token, \
         and `fast_math::exp` no longer converts with a saturating `as i32`, which had made it \
         four times slower under AVX-512. Before the packed attention the pass tied eager on \
         one thread and fell behind on two, where the copies took a larger share; a section \
         marked as measured before it still shows that.\n\
         - **Skipping** is far from 3×, and emptier air does not bring it nearer. The shipped \
         field has α > 0.001 in {:.0}% of its voxels; a decoder fine-tuned with a sparsity prior \
         empties much of that air at the same validation quality, and skipping then evaluates \
         about the same share of samples ([sparse-field.md](sparse-field.md)): the samples it keeps lie along \
         each LiDAR ray before its return, in air the field already leaves nearly empty but the \
         grid's margin (a voxel of dilation, 2³ cells) keeps around the ground the rays graze, \
         and behind it, up to early stop. The RGB upsampler, which both renders run, \
         and the occupancy grid, which skipping adds, bound it below 3× on their own.\n\
         - **How firm.** On a 2-core VM PyTorch's 2-thread times move more between runs than \
         ours (on the EPYC its encoder took 24–33 ms over four runs of one day), so a 2-thread \
         margin under ~25% is within the noise.\n\
         - **The tokenizer's training step**: {} s per step of 2 frames on 2 threads \
         ([train_step.md](train_step.md)) against the goal of 0.415 s: missed. Training runs \
         under autodiff, where the host kernels do not apply, and the backward pass, burn's own \
         ops, is {:.0}% of a frame's step.\n",
        100.0 * occupied,
        step_s.map_or("—".into(), |s| format!("{s:.3}")),
        100.0 * backward_share.unwrap_or(f64::NAN)
    )
}

/// `gemm-x86-v4.json`: ours on one machine with burn built without and with `x86-v4`, when
/// it was measured.
fn gemm_kernels(results: &Path) -> String {
    let Some(record) = read_json(&results.join("gemm-x86-v4.json")) else {
        return String::new();
    };
    let (without, with) = (&record["without_x86_v4"], &record["with_x86_v4"]);
    let mut rows = Vec::new();
    for (label, key, _) in STAGES {
        for threads in ["1", "2"] {
            let (a, b) = (ours_ms(without, key, threads), ours_ms(with, key, threads));
            rows.push(vec![
                format!("{label}, {threads} thread(s)"),
                ms(a),
                ms(b),
                match (a, b) {
                    (Some(a), Some(b)) => format!("{:.2}×", a / b),
                    _ => "—".into(),
                },
            ]);
        }
    }
    for threads in ["1", "2"] {
        let (a, b) = (
            get(without, &[threads, "matmul_gflops"]),
            get(with, &[threads, "matmul_gflops"]),
        );
        rows.push(vec![
            format!("matmul 512², {threads} thread(s), GFLOP/s"),
            ms(a),
            ms(b),
            match (a, b) {
                (Some(a), Some(b)) => format!("{:.2}×", b / a),
                _ => "—".into(),
            },
        ]);
    }
    format!(
        "\n## gemm's AVX-512 kernels (`x86-v4`), on {}\n\n{}\n\n{}",
        record["machine"]["cpu"].as_str().unwrap_or("?"),
        record["about"].as_str().unwrap_or(""),
        markdown_table(
            &[
                "stage (ms) or rate",
                "without x86-v4",
                "with x86-v4",
                "gain"
            ],
            &rows
        )
    )
}
