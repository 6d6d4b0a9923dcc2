//! Sparse fine tokens (issue 51): which tokens the rule selects, what it catches, what the fine
//! stage costs, and the validation forecasts of the fine-tune beside its ablation.
//!
//!   cargo run --release -p bevworld-bench --bin fine_tokens -- measure   # fine-tokens.json
//!   cargo run --release -p bevworld-bench --bin fine_tokens -- page      # fine-tokens.md
//!
//! `measure` reads the validation cache of `finetune-world-model-fine-tiny.yaml` (seeds
//! 9100-9101, keyframes): for each threshold and dilation, the share of coarse tokens selected
//! and the share of the cells whose residual over the ego warp at +1 s is in a window's top 2%
//! that lie in a selected token (what the fine tokens are there for). Then it times one 1-step
//! forecast of the fine model with none, the selection's mean share, and all of its tokens
//! opened, and of the coarse model. `page` writes the page from that file and the three
//! forecasts `bench/scripts/fine-tokens.sh` writes (`fine-tokens-val-*.json`).

use std::path::{Path, PathBuf};

use bevworld_bench::{code_version, machine_record, markdown_table, results_dir, time_runs};
use bevworld_blocks::init::random_normal;
use bevworld_blocks::seeded_init;
use bevworld_metrics::forecast_node::compare_markdown_of;
use bevworld_world_model::fine_tokens::{FineTokenRule, motion_score, select_tokens};
use bevworld_world_model::{
    DdimConfig, FineTokenSelection, ForecastInputs, NoiseSchedule, PlanarMotion, WorldModelConfig,
    forecast, warp_latent,
};
use bevworld_world_model_train::config::KEYFRAMES_INDEX;
use bevworld_world_model_train::run::tokenizer_identity;
use bevworld_world_model_train::{TrainWorldModelConfig, load_sequences};
use burn::prelude::*;
use serde_json::{Value, json};

const TRAINING: &str = "configs/models/finetune-world-model-fine-tiny.yaml";
const THRESHOLDS: [f32; 6] = [4.0, 5.0, 6.0, 7.0, 8.0, 10.0];
const DILATIONS: [usize; 2] = [0, 1];
/// Keyframes ahead of the current one for +1 s at 2 Hz.
const ONE_SECOND: usize = 2;
/// The residual cells a fine token is for: a window's top 2%.
const TOP_SHARE: f64 = 0.02;
const RUNS: usize = 9;
/// The forecasts `bench/scripts/fine-tokens.sh` writes, `fine-tokens-val-NAME.json`: the
/// comparison, then where the fine model loses.
const FORECASTS: [(&str, &str); 3] = [
    ("shipped", "shipped"),
    ("300 more steps, coarse", "coarse"),
    ("300 more steps, fine tokens", "fine"),
];
const DIAGNOSTICS: [(&str, &str); 5] = [
    ("coarse", "coarse"),
    ("fine, no token opened", "fine-off"),
    ("fine, rule 10 / dilation 1", "fine-t10d1"),
    ("coarse, no shrink", "coarse-noshrink"),
    ("fine, no shrink", "fine-noshrink"),
];

fn root() -> PathBuf {
    bevworld_bench::manifest_dir().join("..")
}

fn main() {
    match std::env::args().nth(1).as_deref() {
        Some("measure") => measure(),
        Some("page") => page(),
        _ => {
            eprintln!("usage: fine_tokens measure | fine_tokens page");
            std::process::exit(2);
        }
    }
}

/// One window's cell scores and its +1 s residual over the current latent's warp, `[H·W]` each.
struct Window {
    score: Vec<f32>,
    residual: Vec<f32>,
}

fn windows(train: &TrainWorldModelConfig, model: &WorldModelConfig) -> Vec<Window> {
    let root = root();
    let tokenizer = tokenizer_identity(&root.join(&train.tokenizer_weights)).expect("tokenizer");
    let expected = tokenizer.expected(model, train.gap_factor);
    let sequences = load_sequences(&root.join(&train.val.latents), KEYFRAMES_INDEX, &expected)
        .expect("the validation cache (bench/scripts/fine-tokens.sh makes it)");
    let grid = model.latent_grid();
    let plane = grid.height * grid.width;
    let context = model.context_frames;
    sequences
        .windows(context + model.future_frames)
        .into_iter()
        .map(|(s, start)| {
            let frames = &sequences.sequences[s].frames[start..];
            let condition: Vec<f32> = frames[..context]
                .iter()
                .flat_map(|f| f.latent.iter().copied())
                .collect();
            let motions: Vec<PlanarMotion> = frames[..context]
                .windows(2)
                .map(|pair| {
                    PlanarMotion::between(&pair[0].global_from_ego, &pair[1].global_from_ego)
                })
                .collect();
            let (current, future) = (&frames[context - 1], &frames[context - 1 + ONE_SECOND]);
            let moved = PlanarMotion::between(&current.global_from_ego, &future.global_from_ego);
            let warped = warp_latent(&current.latent, &grid, &moved, 0.0);
            let residual = (0..plane)
                .map(|cell| {
                    (0..grid.channels)
                        .map(|c| (future.latent[c * plane + cell] - warped[c * plane + cell]).abs())
                        .sum()
                })
                .collect();
            Window {
                score: motion_score(&condition, &grid, &motions),
                residual,
            }
        })
        .collect()
}

fn measure() {
    let root = root();
    let train =
        TrainWorldModelConfig::from_yaml_file(&root.join(TRAINING)).expect("training config");
    let model = WorldModelConfig::from_yaml_file(&root.join(&train.model)).expect("model config");
    let windows = windows(&train, &model);
    let [rows, columns] = model.token_grid();
    let tokens = rows * columns;
    let size = model.latent_size;
    let token_of =
        |cell: usize| (cell / size[1] / model.patch) * columns + (cell % size[1]) / model.patch;
    let mut selection = Vec::new();
    for threshold in THRESHOLDS {
        for dilate in DILATIONS {
            let rule = FineTokenRule { threshold, dilate };
            let (mut shares, mut caught, mut top) = (Vec::new(), 0usize, 0usize);
            for window in &windows {
                let selected = select_tokens(&window.score, size, model.patch, &rule);
                shares.push(selected.len() as f64 / tokens as f64);
                let mut open = vec![false; tokens];
                for token in selected {
                    open[token] = true;
                }
                let mut sorted = window.residual.clone();
                sorted.sort_by(f32::total_cmp);
                let bar = sorted[((sorted.len() as f64) * (1.0 - TOP_SHARE)) as usize];
                for (cell, &r) in window.residual.iter().enumerate() {
                    if r >= bar {
                        top += 1;
                        caught += usize::from(open[token_of(cell)]);
                    }
                }
            }
            let mean = shares.iter().sum::<f64>() / shares.len().max(1) as f64;
            let max = shares.iter().copied().fold(0.0, f64::max);
            selection.push(json!({
                "threshold": threshold, "dilate": dilate,
                "mean_share": mean, "max_share": max,
                "top_residual_caught": caught as f64 / top.max(1) as f64,
            }));
        }
    }
    let chosen = model.fine_tokens.as_ref().expect("a fine model").select;
    let chosen_share = selection
        .iter()
        .find(|r| {
            r["threshold"].as_f64() == Some(chosen.threshold as f64)
                && r["dilate"].as_u64() == Some(chosen.dilate as u64)
        })
        .and_then(|r| r["mean_share"].as_f64())
        .expect("the config's rule is among those measured");
    let timing = timings(&root, &model, chosen_share);
    let record = json!({
        "machine": machine_record(),
        "code": code_version(),
        "windows": windows.len(),
        "cache": train.val.latents,
        "rule": {"threshold": chosen.threshold, "dilate": chosen.dilate},
        "selection": selection,
        "timing_ms": timing,
    });
    let file = results_dir().join("fine-tokens.json");
    bevworld_atomic_file::write(
        &file,
        serde_json::to_string_pretty(&record)
            .unwrap_or_default()
            .as_bytes(),
    )
    .expect("writing fine-tokens.json");
    println!("{}", file.display());
}

/// Median ms of one 1-step forecast: the coarse model, and the fine model with no token, the
/// rule's mean share and every token opened (timing does not depend on the weights' values).
fn timings(root: &Path, fine: &WorldModelConfig, share: f64) -> Value {
    let coarse =
        WorldModelConfig::from_yaml_file(&root.join("configs/models/world-model-tiny.yaml"))
            .expect("coarse config");
    let device = Device::flex();
    let [h, w] = fine.latent_size;
    let (p, n, c) = (
        fine.context_frames,
        fine.future_frames,
        fine.latent_channels,
    );
    let [rows, columns] = fine.token_grid();
    let tokens = rows * columns;
    let warped = random_normal(3, [1, n, c, h, w], 0.0, 1.0, &device);
    let inputs = |opened: usize| ForecastInputs {
        context: random_normal(1, [1, p, c, h, w], 0.0, 1.0, &device),
        actions: random_normal(2, [1, p + n, 5], 0.0, 0.5, &device),
        base: Some(warped.clone()),
        warped: warped.clone(),
        // Spread over the grid, as a scene's movers are.
        fine_tokens: FineTokenSelection {
            tokens: vec![(0..opened).map(|k| k * tokens / opened.max(1)).collect()],
        },
    };
    let sampler = DdimConfig::deterministic(1, 0);
    let time = |config: &WorldModelConfig, opened: usize| {
        let model = seeded_init(0, &device, |d| config.init(d));
        let schedule = NoiseSchedule::new(&config.diffusion);
        let inputs = inputs(opened);
        time_runs(RUNS, || {
            forecast(&model, config, &schedule, &inputs, &sampler)
                .expect("forecast")
                .into_data()
        })
        .0
    };
    let opened = ((share * tokens as f64).round() as usize).max(1);
    json!({
        "coarse": time(&coarse, 0),
        "fine_none": time(fine, 0),
        "fine_rule_share": time(fine, opened),
        "fine_every_token": time(fine, tokens),
        "tokens_opened_at_rule_share": opened,
        "tokens": tokens,
    })
}

fn read(path: &Path) -> Option<Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

fn page() {
    let dir = results_dir();
    let record =
        read(&dir.join("fine-tokens.json")).expect("fine-tokens.json: run `measure` first");
    let number = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    let selection_rows: Vec<Vec<String>> = record["selection"]
        .as_array()
        .map(|rows| {
            rows.iter()
                .map(|r| {
                    vec![
                        format!("{}", number(&r["threshold"])),
                        format!("{}", number(&r["dilate"])),
                        format!("{:.1}%", 100.0 * number(&r["mean_share"])),
                        format!("{:.1}%", 100.0 * number(&r["max_share"])),
                        format!("{:.1}%", 100.0 * number(&r["top_residual_caught"])),
                    ]
                })
                .collect()
        })
        .unwrap_or_default();
    let t = &record["timing_ms"];
    let opened = number(&t["tokens_opened_at_rule_share"]);
    let all = number(&t["tokens"]);
    let timing_rows = vec![
        vec![
            "coarse model (shipped size)".into(),
            format!("{:.1}", number(&t["coarse"])),
            "–".into(),
        ],
        vec![
            "fine model, no token opened".into(),
            format!("{:.1}", number(&t["fine_none"])),
            "0".into(),
        ],
        vec![
            format!("fine model, the rule's mean share ({opened} of {all} tokens)"),
            format!("{:.1}", number(&t["fine_rule_share"])),
            format!("{opened}"),
        ],
        vec![
            "fine model, every token opened".into(),
            format!("{:.1}", number(&t["fine_every_token"])),
            format!("{all}"),
        ],
    ];
    let fine_cost = number(&t["fine_rule_share"]) - number(&t["fine_none"]);
    let every_cost = number(&t["fine_every_token"]) - number(&t["fine_none"]);
    let table = |runs: &[(&str, &str)]| {
        let read_runs: Vec<(String, Value)> = runs
            .iter()
            .filter_map(|(label, name)| {
                read(&dir.join(format!("fine-tokens-val-{name}.json")))
                    .map(|v| (label.to_string(), v))
            })
            .collect();
        if read_runs.len() == runs.len() {
            compare_markdown_of(&read_runs)
        } else {
            "(not measured yet: bench/scripts/fine-tokens.sh)\n".into()
        }
    };
    let forecasts = table(&FORECASTS);
    let diagnostics = table(&DIAGNOSTICS);
    let machine = record["machine"]["cpu"].as_str().unwrap_or("this machine");
    let text = format!(
        "# Sparse fine tokens (issue 51)\n\n\
Reproduce: `bench/scripts/fine-tokens.sh` (about 80 minutes on 2 cores). Validation scenes only \
(seeds 9100-9101); the test scenes were not touched. Code {code}; timings on {machine}.\n\n\
**What it is.** A tiny world-model token covers 4 × 4 latent cells, 10 m × 10 m, and a car is a \
fraction of one. `fine_tokens` (`world-model-fine-tiny.yaml`) opens the coarse tokens where the \
context moves into one token per 2.5 m cell. A cell moves when its standardised latent changes, \
summed over the channels, by more than a threshold between two condition frames, once the earlier \
frame is warped into the later one's ego frame (`fine_tokens.rs`; cells that enter the grid as the \
ego drives do not count). A fine stage (`fine_stage.rs`: the coarse model's block at a fine width, \
attention over the frames of a cell and among the cells of a token, each cell also embedding its \
ego-warped current latent and the coarse output token above it) corrects those cells' \
prediction through a head that starts at zero. The rule reads only the model's own input, so \
training and forecasting select alike, and a static context opens nothing (a unit test).\n\n\
## Which tokens the rule opens\n\n\
On the {windows} keyframe windows of the validation cache: the share of coarse tokens opened, and \
the share of the cells whose residual over the ego warp at +1 s is in their window's top 2% that lie \
in an opened token. The config uses threshold {rt}, dilation {rd}. The latent of a standing world \
is not the same from two viewpoints, so most cells change a little, and the threshold has to sit \
far above the median cell's change.\n\n{selection}\n\
## What the fine stage costs\n\n\
One 1-step forecast, median of {runs} runs (weights' values do not change the time). The fine \
stage on the rule's share adds {fine_cost:.1} ms; on every token it would add {every_cost:.1} ms.\n\n{timing}\n\
## The forecasts (validation)\n\n\
The shipped weights; 300 more steps of the counterfactual stage from them without the fine stage \
(`finetune-world-model-coarse-tiny.yaml`, the ablation); and the same 300 steps with it \
(`finetune-world-model-fine-tiny.yaml`, which starts as the shipped model). Each figure is the mean \
over scenes.\n\n{forecasts}\n## Where the fine model loses\n\nThe fine model's own weights with no token opened (the rule's threshold out of reach); another rule, trained the same way (`--fine-select 10,1`: fewer tokens opened by weak changes, and the neighbours of the strong ones, where a mover goes); and both fine-tunes sampled without the residual shrink (`--set rollout.shrink=null`).\n\n{diagnostics}\n{reading}",
        code = record["code"].as_str().unwrap_or("?"),
        windows = record["windows"],
        rt = record["rule"]["threshold"],
        rd = record["rule"]["dilate"],
        selection = markdown_table(
            &[
                "threshold",
                "dilation",
                "tokens opened (mean)",
                "tokens opened (most)",
                "top-2% residual cells caught"
            ],
            &selection_rows
        ),
        runs = RUNS,
        timing = markdown_table(&["forecast", "ms", "tokens opened"], &timing_rows),
        reading = READING,
    );
    let file = dir.join("fine-tokens.md");
    bevworld_atomic_file::write(&file, text.as_bytes()).expect("writing fine-tokens.md");
    println!("{}", file.display());
}

/// What the forecasts say, written after reading them.
const READING: &str = "## Reading\n\n\
- **The rule finds where the scene changes, cheaply.** At the config's threshold about an eighth of \
the tokens open, and they hold well over half of the cells with the largest residual at +1 s: \
several times what a random eighth would hold.\n\
- **The fine stage runs on few tokens.** Opened everywhere it would cost several times the whole \
coarse forecast; on the rule's share it adds about a third. The target \"no slower than today's \
1-step forecast\" is therefore missed by that third.\n\
- **It lowers the latent error and raises the rendered one.** In training, both rules end with a \
lower validation latent L1 than the coarse ablation at every horizon (`runs/*/metrics.csv`, \
1-2%). Rendered, the fine models lose at every horizon, in whole-scene Chamfer and on the static \
class, and gain nothing on the moving or parked vehicles. Precision in the moving boxes rises: \
fewer points are drawn there, not more.\n\
- **The loss is the fine stage's own.** Its weights with no token opened forecast as the coarse \
ablation does, and without the residual shrink it still loses: it is not the shrink turning small \
corrections into re-predicted static cells. Opening fewer weak tokens and the neighbours of strong \
ones (rule 10 / dilation 1) does not help either.\n\
- The same pattern (latent L1 down, Chamfer up) was measured for `ego_warp_input` \
([world-model-training.md](world-model-training.md)). The L1 on the latent rewards a prediction \
between the futures the decoder does not render as a car. Finer tokens give the model room to say \
where a car is; a 1-step mean still does not say it. The draws page ([forecast.md](forecast.md), \
\"Draws\") found the samples hold the cars where the mean erases them: the next lever is the \
sampler on the opened tokens, not their resolution.\n\
- **Pictures.** The top-down pictures of the two fine-tunes (`out/eval-forecast-val-{coarse,fine}`) \
differ in a few points along the walls; neither shows the cars of the logged sweep.\n\
- **Not shipped.** The fine stage stays a config option (`world-model-fine-tiny.yaml`); the test \
scenes were not touched.\n";
