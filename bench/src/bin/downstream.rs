//! The downstream page: every arm of `bench/scripts/downstream.sh` (a run folder per input,
//! frames and initialisation, each with `test/scores.json`) collected into one JSON, and the
//! tables of `bench/results/downstream.md` generated from it, beside the paper's own table.
//!
//!   cargo run --release -p bevworld-bench --bin downstream -- --runs runs/downstream \
//!     --graph-metrics out/detect-metrics.json \
//!     --json bench/results/downstream.json --page bench/results/downstream.md
//!
//! `--forecast FILE` adds `forecast_detection`'s figures (the detector on forecast latents);
//! `--graph-check FILE --graph-check-run RUN` a run scored again through `detect.yaml` (the
//! `eval detector --json` of its results there).
//! `--graph-metrics` is a `bevworld run configs/graphs/detect.yaml --metrics FILE` report: the
//! `detect` node's time per frame in the graph (p50, p99) and the encoder's beside it.
//!   cargo run --release -p bevworld-bench --bin downstream -- --from bench/results/downstream.json \
//!     --page bench/results/downstream.md     (the page again from the figures)
//!
//! `--curves FILE.png` draws every arm's validation NDS against its steps.

use bevworld_bench::cli::arg;
use std::path::{Path, PathBuf};

use bevworld_plot::{Panel, Series, panels_png};
use bevworld_training::metrics_log::read_series;
use serde_json::{Value, json};

/// The paper's "Comparison of whether use pretrained tokenizer" (nuScenes val): frames,
/// pretrained, NDS, mAP, minADE, minFDE.
const PAPER: [(&str, &str, f64, f64, f64, f64); 4] = [
    ("single", "without", 0.366, 0.338, 2.055, 3.469),
    ("single", "with", 0.415, 0.412, 1.851, 3.153),
    ("two", "without", 0.392, 0.253, 1.426, 2.230),
    ("two", "with", 0.476, 0.387, 0.971, 1.481),
];

/// The run folders of the pretraining table.
const PRETRAIN_PREFIX: &str = "pretrain-";

fn read(path: &Path) -> Result<Value, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

/// Every run under `runs` with a test score, in name order.
fn collect(runs: &Path) -> Result<Value, String> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(runs)
        .map_err(|e| format!("{}: {e}", runs.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.join("test/scores.json").is_file())
        .collect();
    names.sort();
    let mut arms = Vec::new();
    for run in names {
        let scores = read(&run.join("test/scores.json"))?;
        let evaluation = &scores["evaluation"];
        let name = run
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_default();
        // downstream.sh's two tables: the exports read frozen (`frozen-*`, one budget) and the
        // paper's pretraining comparison on the fused feature (`pretrain-*`, another).
        let table = if name.starts_with(PRETRAIN_PREFIX) {
            "pretrain"
        } else {
            "export"
        };
        arms.push(json!({
            "run": name,
            "table": table,
            "input": scores["input"],
            "frames": scores["frames"],
            "init": scores["init"],
            "steps": scores["steps"],
            "test_set": scores["test_set"],
            "keyframes": evaluation["frames"],
            "nds": evaluation["detection"]["nd_score"],
            "map": evaluation["detection"]["mean_ap"],
            "tp_errors": evaluation["detection"]["tp_errors"],
            "class_ap": evaluation["detection"]["mean_dist_aps"],
            "scene_spread": {"nds": evaluation["scene_spread"][0], "map": evaluation["scene_spread"][1], "min_ade": evaluation["scene_spread"][2]},
            "motion": evaluation["motion"],
            "seconds_per_step": seconds_per_step(&run.join("metrics.csv")),
            "validation_nds": validation_nds(&run.join("metrics.csv")),
        }));
    }
    let speed = match arg("--graph-metrics") {
        Some(file) => {
            let report = read(Path::new(&file))?;
            let node = |id: &str| {
                report["nodes"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .find(|n| n["id"] == id)
                    .cloned()
                    .unwrap_or(Value::Null)
            };
            let (detect, encode) = (node("detect"), node("encode"));
            json!({
                "graph": "configs/graphs/detect.yaml",
                "cpu": bevworld_device::cpu_model(),
                "threads": std::thread::available_parallelism().map_or(1, |n| n.get()),
                "frames": detect["items_in"],
                "detect_ms_p50": detect["latency_p50_us"].as_f64().map(|v| v / 1000.0),
                "detect_ms_p99": detect["latency_p99_us"].as_f64().map(|v| v / 1000.0),
                "encode_ms_p50": encode["latency_p50_us"].as_f64().map(|v| v / 1000.0),
            })
        }
        None => Value::Null,
    };
    let forecast = match arg("--forecast") {
        Some(file) => read(Path::new(&file))?,
        None => Value::Null,
    };
    // A run's test score again, through the graph a user runs (`--graph-check FILE`, the
    // `eval detector --json` of detect.yaml's results with the run's encoder and detector).
    let graph_check = match (arg("--graph-check"), arg("--graph-check-run")) {
        (Some(file), Some(run)) => {
            let eval = read(Path::new(&file))?;
            let present = &eval["present_classes"];
            let arm = arms
                .iter()
                .find(|a| a["run"] == run.as_str())
                .ok_or_else(|| format!("--graph-check-run {run}: no such run with a test score"))?;
            json!({
                "run": run,
                "graph": "configs/graphs/detect.yaml",
                "samples": eval["samples"],
                "graph_nds": present["nd_score"],
                "graph_map": present["mean_ap"],
                "run_nds": arm["nds"],
                "run_map": arm["map"],
            })
        }
        _ => Value::Null,
    };
    Ok(json!({
        "graph_check": graph_check,
        "forecast": forecast,
        "speed": speed,
        "note": "bench/scripts/downstream.sh: each arm trained on seeds 4000-4011, validated on 9200-9201, scored once on the test seeds 9600-9603; spreads are population deviations over the test scenes",
        "arms": arms,
        "paper": PAPER.iter().map(|(frames, pretrain, nds, map, ade, fde)| json!({
            "frames": frames, "pretrain": pretrain, "nds": nds, "map": map, "min_ade": ade, "min_fde": fde,
        })).collect::<Vec<_>>(),
    }))
}

/// A run's training time per step: the elapsed seconds of its last training row in
/// `metrics.csv` over its step (validation included; a resumed run's clock restarts, so its
/// figure is of the part after the resume). `null` without a log.
fn seconds_per_step(log: &Path) -> Value {
    read_series(log, "train", "elapsed_s")
        .ok()
        .and_then(|rows| rows.last().copied())
        .filter(|(step, _)| *step > 0.0)
        .map_or(Value::Null, |(step, elapsed)| Value::from(elapsed / step))
}

/// A run's validation NDS at each validation step, `[[step, nds], …]`.
fn validation_nds(log: &Path) -> Value {
    read_series(log, "val", "nds").map_or(Value::Null, |rows| {
        Value::from(
            rows.iter()
                .map(|&(step, nds)| vec![step, nds])
                .collect::<Vec<_>>(),
        )
    })
}

/// One arm's curve: its label and `(step, NDS)` points.
type Line = (String, Vec<(f64, f64)>);

/// The validation curves of both tables (`--curves FILE.png`): NDS against steps, one panel
/// per table and number of frames, one line per arm.
fn curves(figures: &Value, path: &Path) -> Result<(), String> {
    let mut owned: Vec<(String, Vec<Line>)> = Vec::new();
    for (table, name) in [("export", "frozen exports"), ("pretrain", "pretraining")] {
        for frames in [1u64, 2] {
            let lines = arms_of(figures, table)
                .filter(|a| a["frames"] == frames)
                .map(|a| {
                    let label = format!(
                        "{} {}",
                        a["init"].as_str().unwrap_or("?"),
                        a["input"].as_str().unwrap_or("?")
                    );
                    let points = a["validation_nds"]
                        .as_array()
                        .into_iter()
                        .flatten()
                        .filter_map(|p| Some((p[0].as_f64()?, p[1].as_f64()?)))
                        .collect();
                    (label, points)
                })
                .collect();
            owned.push((format!("validation NDS: {name}, {frames} frame(s)"), lines));
        }
    }
    let panels: Vec<Panel> = owned
        .iter()
        .map(|(title, lines)| Panel {
            title,
            x_label: "step",
            log_y: false,
            series: lines
                .iter()
                .map(|(label, points)| Series { label, points })
                .collect(),
        })
        .collect();
    panels_png(path, &panels).map_err(|e| format!("{}: {e}", path.display()))
}

fn number(value: &Value, decimals: usize) -> String {
    value
        .as_f64()
        .map_or_else(|| "—".to_string(), |v| format!("{v:.decimals$}"))
}

fn page(figures: &Value) -> String {
    let mut text = String::new();
    text.push_str("<!-- generated from bench/results/downstream.json by `cargo run --release -p bevworld-bench --bin downstream -- --from bench/results/downstream.json --page bench/results/downstream.md` -->\n");
    text.push_str("| input | frames | encoder | steps | NDS | mAP | mATE | mASE | mAOE | mAVE | mAAE | minADE (m) | minFDE (m) | miss rate | const. vel. ADE / FDE (m) | agents matched |\n");
    text.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for arm in arms_of(figures, "export") {
        let tp = |name: &str| number(&arm["tp_errors"][name], 3);
        let spread = &arm["scene_spread"];
        let motion = &arm["motion"];
        text.push_str(&format!(
            "| {} | {} | {} | {} | {} ± {} | {} ± {} | {} | {} | {} | {} | {} | {} ± {} | {} | {} | {} / {} | {} of {} |\n",
            arm["input"].as_str().unwrap_or("?"),
            arm["frames"],
            arm["init"].as_str().unwrap_or("?"),
            arm["steps"],
            number(&arm["nds"], 3),
            number(&spread["nds"], 3),
            number(&arm["map"], 3),
            number(&spread["map"], 3),
            tp("trans_err"),
            tp("scale_err"),
            tp("orient_err"),
            tp("vel_err"),
            tp("attr_err"),
            number(&motion["min_ade"], 2),
            number(&spread["min_ade"], 2),
            number(&motion["min_fde"], 2),
            number(&motion["miss_rate"], 3),
            number(&motion["constant_velocity_ade"], 2),
            number(&motion["constant_velocity_fde"], 2),
            motion["matched"],
            motion["agents"],
        ));
    }
    text.push_str(&pretrain_table(figures));
    text.push_str(&graph_check(&figures["graph_check"]));
    text.push_str(&forecast_table(&figures["forecast"]));
    text.push_str(&targets(figures));
    text.push_str("\nThe paper's table (nuScenes val, its query head):\n\n| frames | pretrained tokenizer | NDS | mAP | minADE | minFDE |\n|---|---|---|---|---|---|\n");
    for row in figures["paper"].as_array().into_iter().flatten() {
        text.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            row["frames"].as_str().unwrap_or("?"),
            row["pretrain"].as_str().unwrap_or("?"),
            number(&row["nds"], 3),
            number(&row["map"], 3),
            number(&row["min_ade"], 3),
            number(&row["min_fde"], 3),
        ));
    }
    text.push_str("\nPer class AP (mean over the 0.5/1/2/4 m thresholds):\n\n| input | frames | encoder | steps |");
    let arms: Vec<&Value> = figures["arms"].as_array().into_iter().flatten().collect();
    let classes: Vec<String> = arms
        .first()
        .and_then(|a| a["class_ap"].as_object())
        .map(|m| m.keys().cloned().collect())
        .unwrap_or_default();
    for class in &classes {
        text.push_str(&format!(" {class} |"));
    }
    text.push_str(&format!(
        "\n|---|---|---|---|{}\n",
        "---|".repeat(classes.len())
    ));
    for arm in arms {
        text.push_str(&format!(
            "| {} | {} | {} | {} |",
            arm["input"].as_str().unwrap_or("?"),
            arm["frames"],
            arm["init"].as_str().unwrap_or("?"),
            arm["steps"]
        ));
        for class in &classes {
            text.push_str(&format!(" {} |", number(&arm["class_ap"][class], 3)));
        }
        text.push('\n');
    }
    text
}

/// A run scored again through the graph: its encoder's features made by `detect.yaml`.
fn graph_check(check: &Value) -> String {
    if check.is_null() {
        return String::new();
    }
    format!(
        "\nThe run `{}` as a user runs it: `{}` with its `tokenizer.bpk` and `detector.bpk` on the test set's {} keyframes, its `results_nusc.json` scored by `eval detector`: NDS {}, mAP {}; the run's own test score: NDS {}, mAP {}.\n",
        check["run"].as_str().unwrap_or("?"),
        check["graph"].as_str().unwrap_or("?"),
        check["samples"],
        number(&check["graph_nds"], 4),
        number(&check["graph_map"], 4),
        number(&check["run_nds"], 4),
        number(&check["run_map"], 4),
    )
}

/// The detector on the world model's forecast latents, beside the true future latent and the
/// ego warp (`forecast_detection`'s figures), when measured.
fn forecast_table(forecast: &Value) -> String {
    let Some(horizons) = forecast["horizons"].as_array() else {
        return String::new();
    };
    let mut text = format!(
        "\nThe latent one-frame detector on the world model's forecast latents ({} forecasts of the test scenes, one DDIM step; `forecast_detection`), scored against the future keyframe's annotations:\n\n| horizon | latents | mAP | NDS | mATE | mAVE |\n|---|---|---|---|---|---|\n",
        forecast["windows"]
    );
    for horizon in horizons {
        for (method, label) in [
            ("forecast", "world model forecast"),
            ("latent_ego_warp", "`latent_ego_warp` (only the ego moves)"),
            ("true_latent", "the true future keyframe's latent"),
        ] {
            let m = &horizon[method];
            text.push_str(&format!(
                "| +{} s | {label} | {} | {} | {} | {} |\n",
                horizon["horizon_s"],
                number(&m["map"], 3),
                number(&m["nds"], 3),
                number(&m["tp_errors"]["trans_err"], 3),
                number(&m["tp_errors"]["vel_err"], 3),
            ));
        }
    }
    text
}

/// The arms of one table (`export` or `pretrain`).
fn arms_of<'a>(figures: &'a Value, table: &'a str) -> impl Iterator<Item = &'a Value> + 'a {
    figures["arms"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(move |a| a["table"] == table)
}

/// The frozen export's arm of `input` with `frames`, when run.
fn arm<'a>(figures: &'a Value, input: &str, frames: u64) -> Option<&'a Value> {
    arms_of(figures, "export").find(|a| a["input"] == input && a["frames"] == frames)
}

/// The pretraining table's arm of `init` with `frames`, when run.
fn pretrain_arm<'a>(figures: &'a Value, init: &str, frames: u64) -> Option<&'a Value> {
    arms_of(figures, "pretrain").find(|a| a["init"] == init && a["frames"] == frames)
}

/// The paper's comparison at our scale: the fused feature through the encoder trained with the
/// heads from the tokenizer's weights and from scratch, and frozen, for one budget.
fn pretrain_table(figures: &Value) -> String {
    let arms: Vec<&Value> = arms_of(figures, "pretrain").collect();
    if arms.is_empty() {
        return String::new();
    }
    let mut text = String::from(
        "\nThe paper's pretraining comparison at our scale (`pretrain-*` runs: the fused feature, the encoder trained with the heads from the shipped tokenizer's weights or from a fresh initialisation, or frozen; every arm the same steps):\n\n| frames | encoder | steps | s per step | NDS | mAP | mAVE | minADE (m) | minFDE (m) | miss rate |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for frames in [1, 2] {
        for init in ["scratch", "tokenizer", "frozen"] {
            let Some(arm) = pretrain_arm(figures, init, frames) else {
                continue;
            };
            let spread = &arm["scene_spread"];
            let motion = &arm["motion"];
            text.push_str(&format!(
                "| {frames} | {init} | {} | {} | {} ± {} | {} ± {} | {} | {} ± {} | {} | {} |\n",
                arm["steps"],
                number(&arm["seconds_per_step"], 2),
                number(&arm["nds"], 3),
                number(&spread["nds"], 3),
                number(&arm["map"], 3),
                number(&spread["map"], 3),
                number(&arm["tp_errors"]["vel_err"], 3),
                number(&motion["min_ade"], 2),
                number(&spread["min_ade"], 2),
                number(&motion["min_fde"], 2),
                number(&motion["miss_rate"], 3),
            ));
        }
    }
    text
}

fn verdict(met: bool) -> &'static str {
    if met { "met" } else { "**missed**" }
}

/// The target "two frames beat one in mAVE and minADE" for a pair of arms, when both ran.
fn two_frames_row(label: &str, one: Option<&Value>, two: Option<&Value>) -> Option<String> {
    let f = |arm: Option<&Value>, pointer: &str| {
        arm.and_then(|a| a.pointer(pointer)).and_then(Value::as_f64)
    };
    let (ave_1, ave_2) = (f(one, "/tp_errors/vel_err")?, f(two, "/tp_errors/vel_err")?);
    let (ade_1, ade_2) = (f(one, "/motion/min_ade")?, f(two, "/motion/min_ade")?);
    Some(format!(
        "| {label}: two frames beat one in mAVE and minADE | mAVE {ave_2:.3} against {ave_1:.3}, minADE {ade_2:.2} against {ade_1:.2} m | {} |",
        verdict(ave_2 < ave_1 && ade_2 < ade_1)
    ))
}

/// The targets that these arms can answer, each computed from the figures.
fn targets(figures: &Value) -> String {
    let mut rows = Vec::new();
    let f = |arm: Option<&Value>, pointer: &str| {
        arm.and_then(|a| a.pointer(pointer)).and_then(Value::as_f64)
    };
    for frames in [1, 2] {
        let stats = f(arm(figures, "bev_stats", frames), "/nds");
        for input in ["latent", "feature"] {
            if let (Some(ours), Some(stats)) = (f(arm(figures, input, frames), "/nds"), stats) {
                let gain = ours / stats - 1.0;
                rows.push(format!(
                    "| frozen {input} against bev_stats, {frames} frame(s): NDS +20% relative | {ours:.3} against {stats:.3}: {:+.1}% | {} |",
                    100.0 * gain,
                    verdict(gain >= 0.2)
                ));
            }
        }
    }
    for input in ["bev_stats", "latent", "feature"] {
        rows.extend(two_frames_row(
            input,
            arm(figures, input, 1),
            arm(figures, input, 2),
        ));
    }
    for frames in [1, 2] {
        let (with, without) = (
            pretrain_arm(figures, "tokenizer", frames),
            pretrain_arm(figures, "scratch", frames),
        );
        if let (Some(nds), Some(nds_0), Some(map), Some(map_0)) = (
            f(with, "/nds"),
            f(without, "/nds"),
            f(with, "/map"),
            f(without, "/map"),
        ) {
            let (gain_nds, gain_map) = (nds / nds_0 - 1.0, map / map_0 - 1.0);
            rows.push(format!(
                "| pretraining pays, {frames} frame(s): tokenizer beats scratch by ≥ 10% relative NDS and mAP | NDS {nds:.3} against {nds_0:.3} ({:+.1}%), mAP {map:.3} against {map_0:.3} ({:+.1}%) | {} |",
                100.0 * gain_nds,
                100.0 * gain_map,
                verdict(gain_nds >= 0.1 && gain_map >= 0.1)
            ));
        }
    }
    for init in ["tokenizer", "scratch"] {
        rows.extend(two_frames_row(
            &format!("encoder trained from {init}"),
            pretrain_arm(figures, init, 1),
            pretrain_arm(figures, init, 2),
        ));
    }
    for a in figures["arms"].as_array().into_iter().flatten() {
        let m = &a["motion"];
        if let (Some(ade), Some(fde), Some(cv_ade), Some(cv_fde)) = (
            m["min_ade"].as_f64(),
            m["min_fde"].as_f64(),
            m["constant_velocity_ade"].as_f64(),
            m["constant_velocity_fde"].as_f64(),
        ) {
            rows.push(format!(
                "| {} {}, {} frame(s), {} steps: the motion head beats constant velocity | minADE {ade:.2} against {cv_ade:.2} m, minFDE {fde:.2} against {cv_fde:.2} m | {} |",
                a["init"].as_str().unwrap_or("?"),
                a["input"].as_str().unwrap_or("?"),
                a["frames"],
                a["steps"],
                verdict(ade < cv_ade && fde < cv_fde)
            ));
        }
    }
    for horizon in figures["forecast"]["horizons"]
        .as_array()
        .into_iter()
        .flatten()
    {
        if horizon["horizon_s"].as_f64() != Some(1.0) {
            continue;
        }
        let map = |method: &str| horizon[method]["map"].as_f64();
        if let (Some(forecast), Some(truth), Some(warp)) =
            (map("forecast"), map("true_latent"), map("latent_ego_warp"))
        {
            rows.push(format!(
                "| the forecast carries the agents: mAP at +1 s ≥ 0.8× the true latent's and above `latent_ego_warp`'s | {forecast:.3} against {truth:.3} ({:.2}×) and {warp:.3} | {} |",
                forecast / truth,
                verdict(forecast >= 0.8 * truth && forecast > warp)
            ));
        }
    }
    let speed = &figures["speed"];
    if let Some(ms) = speed["detect_ms_p50"].as_f64() {
        rows.push(format!(
            "| the detector in `detect.yaml` adds ≤ 30 ms per frame ({} threads, {}) | {ms:.1} ms p50, {:.1} ms p99 over {} frames (the encoder beside it: {:.1} ms p50) | {} |",
            speed["threads"],
            speed["cpu"].as_str().unwrap_or("?"),
            speed["detect_ms_p99"].as_f64().unwrap_or(f64::NAN),
            speed["frames"],
            speed["encode_ms_p50"].as_f64().unwrap_or(f64::NAN),
            verdict(ms <= 30.0)
        ));
    }
    format!(
        "\nThe targets these arms answer (test seeds, computed from the figures above):\n\n| target | figure | verdict |\n|---|---|---|\n{}\n",
        rows.join("\n")
    )
}

fn main() {
    let figures = match (arg("--runs"), arg("--from")) {
        (Some(runs), None) => collect(Path::new(&runs)),
        (None, Some(from)) => read(Path::new(&from)),
        _ => Err(
            "usage: downstream (--runs DIR | --from FILE.json) [--json OUT.json] [--page OUT.md] [--curves OUT.png]"
                .into(),
        ),
    };
    let figures = match figures {
        Ok(figures) => figures,
        Err(error) => {
            eprintln!("{error}");
            std::process::exit(1);
        }
    };
    if let Some(path) = arg("--json") {
        let text = serde_json::to_string_pretty(&figures).unwrap_or_default();
        if let Err(error) = std::fs::write(&path, text + "\n") {
            eprintln!("{path}: {error}");
            std::process::exit(1);
        }
    }
    if let Some(path) = arg("--curves")
        && let Err(error) = curves(&figures, Path::new(&path))
    {
        eprintln!("{error}");
        std::process::exit(1);
    }
    let tables = page(&figures);
    match arg("--page") {
        Some(path) => {
            // The tables replace what lies between the page's markers; a page without them
            // gets them at its end.
            let begin = "<!-- downstream tables: begin -->";
            let end = "<!-- downstream tables: end -->";
            let existing = std::fs::read_to_string(&path).unwrap_or_default();
            let block = format!("{begin}\n{tables}{end}");
            let text = match (existing.find(begin), existing.find(end)) {
                (Some(a), Some(b)) if a < b => {
                    format!("{}{block}{}", &existing[..a], &existing[b + end.len()..])
                }
                _ => format!("{existing}{block}\n"),
            };
            if let Err(error) = std::fs::write(&path, text) {
                eprintln!("{path}: {error}");
                std::process::exit(1);
            }
        }
        None => print!("{tables}"),
    }
}
