//! The forecast graph's latency budget on each kind of CPU: where one keyframe's time goes when
//! the README's main job runs (`configs/graphs/forecast.yaml`, the model's views only), and
//! whether the graph keeps up with the log's keyframes.
//!
//! One record per kind of machine, `bench/results/forecast-budget-<kind>.json`, from one run's
//! `--metrics` report and its `scores.json`; `speed-vs-error.md` shows every kind's record as
//! one line of its budget table, between the markers below.
//!
//!   bench/scripts/forecast-budget.sh

use std::path::Path;

use serde_json::{Value, json};

use crate::{kind_records, machine_kind, machine_record, markdown_table};

/// Where the budget table starts and ends in `speed-vs-error.md`.
pub const BEGIN: &str = "<!-- forecast budget: generated from forecast-budget-*.json -->";
pub const END: &str = "<!-- end of forecast budget -->";

/// The keyframe interval of the logs the graph replays (nuScenes and ours: 2 Hz).
const KEYFRAME_INTERVAL_MS: f64 = 500.0;

/// The graph's nodes whose time is the budget, by their ids in `forecast.yaml`, with the name
/// the table gives them.
const STAGES: [(&str, &str); 4] = [
    ("pillars", "pillarize"),
    ("encode", "encode"),
    ("rollout", "rollout"),
    ("render", "render"),
];

/// Why a run's files cannot make a record: which file, which field.
#[derive(Debug, thiserror::Error)]
pub enum BudgetError {
    #[error("{file}: {reason}")]
    Unreadable { file: String, reason: String },
    #[error("{file}: no `{field}`")]
    Missing { file: String, field: String },
}

fn read(path: &Path) -> Result<Value, BudgetError> {
    let unreadable = |reason: String| BudgetError::Unreadable {
        file: path.display().to_string(),
        reason,
    };
    let bytes = std::fs::read(path).map_err(|e| unreadable(e.to_string()))?;
    serde_json::from_slice(&bytes).map_err(|e| unreadable(e.to_string()))
}

fn number(value: &Value, file: &Path, field: &str) -> Result<f64, BudgetError> {
    value.as_f64().ok_or_else(|| BudgetError::Missing {
        file: file.display().to_string(),
        field: field.to_string(),
    })
}

/// This machine's record from a run of the forecast graph: `metrics` is its `--metrics`
/// report, `scores` its `scores.json` (per forecast, the rollout and the rollout with the
/// render of the requested horizons). `commit` names the code that ran.
pub fn record(metrics: &Path, scores: &Path, commit: &str) -> Result<Value, BudgetError> {
    let report = read(metrics)?;
    let table = read(scores)?;
    let node = |id: &str| -> Result<&Value, BudgetError> {
        report["nodes"]
            .as_array()
            .and_then(|nodes| nodes.iter().find(|n| n["id"] == id))
            .ok_or_else(|| BudgetError::Missing {
                file: metrics.display().to_string(),
                field: format!("nodes[id = {id}]"),
            })
    };
    let mut stages = serde_json::Map::new();
    for (id, name) in STAGES {
        let n = node(id)?;
        stages.insert(
            name.to_string(),
            json!({
                "calls": n["items_in"],
                "p50_ms": number(&n["latency_p50_us"], metrics, &format!("{id}.latency_p50_us"))? / 1e3,
                "p99_ms": number(&n["latency_p99_us"], metrics, &format!("{id}.latency_p99_us"))? / 1e3,
            }),
        );
    }
    let keyframes = number(&node("source")?["items_out"], metrics, "source.items_out")?;
    let wall = number(&report["wall_seconds"], metrics, "wall_seconds")?;
    let latency = |name: &str| {
        number(
            &table["latency_ms"][name],
            scores,
            &format!("latency_ms.{name}"),
        )
    };
    Ok(json!({
        "machine": machine_record(),
        "commit": commit,
        "graph": report["graph"],
        "keyframes": keyframes,
        "forecasts": number(&table["contexts"], scores, "contexts")?,
        "wall_seconds": wall,
        "stages": stages,
        "forecast_ms": {
            "rollout_p50": latency("rollout_p50")?,
            "rollout_p99": latency("rollout_p99")?,
            "with_render_p50": latency("with_render_p50")?,
            "with_render_p99": latency("with_render_p99")?,
        },
    }))
}

/// Writes `record` as this kind of machine's file in `results`, and returns its path.
pub fn write(results: &Path, record: &Value) -> std::io::Result<std::path::PathBuf> {
    let file = results.join(format!(
        "forecast-budget-{}.json",
        machine_kind(&record["machine"])
    ));
    let text = serde_json::to_string_pretty(record).map_err(std::io::Error::other)?;
    bevworld_atomic_file::write(&file, text.as_bytes())?;
    Ok(file)
}

/// The budget table, one line per kind of machine recorded in `results`, between `BEGIN` and
/// `END`.
pub fn section(results: &Path) -> String {
    let files = kind_records(results, "forecast-budget-");
    let ms = |v: &Value| v.as_f64().map_or("—".to_string(), |x| format!("{x:.0}"));
    let rows: Vec<Vec<String>> = files
        .iter()
        .filter_map(|(_, path)| read(path).ok())
        .map(|r| {
            let machine = &r["machine"];
            let per_keyframe = r["wall_seconds"].as_f64().unwrap_or(f64::NAN) * 1e3
                / r["keyframes"].as_f64().unwrap_or(f64::NAN);
            let stage = |name: &str| ms(&r["stages"][name]["p50_ms"]);
            vec![
                format!(
                    "{} ({}, {} cores)",
                    machine_kind(machine),
                    machine["cpu"].as_str().unwrap_or("?"),
                    machine["cores"]
                ),
                stage("pillarize"),
                stage("encode"),
                format!(
                    "{} / {}",
                    ms(&r["forecast_ms"]["rollout_p50"]),
                    ms(&r["forecast_ms"]["rollout_p99"])
                ),
                stage("render"),
                format!(
                    "{} / {}",
                    ms(&r["forecast_ms"]["with_render_p50"]),
                    ms(&r["forecast_ms"]["with_render_p99"])
                ),
                format!(
                    "{per_keyframe:.0} ({})",
                    if per_keyframe <= KEYFRAME_INTERVAL_MS {
                        "keeps up"
                    } else {
                        "falls behind"
                    }
                ),
                format!("`{}`", r["commit"].as_str().unwrap_or("?")),
            ]
        })
        .collect();
    // Kinds that other pages measured but this table lacks: named, so that a missing line reads
    // as not yet measured rather than as absent.
    let unmeasured: Vec<String> = kind_records(results, "vs-pytorch-")
        .into_iter()
        .map(|(kind, _)| kind)
        .filter(|kind| !files.iter().any(|(budgeted, _)| budgeted == kind))
        .collect();
    let unmeasured = if unmeasured.is_empty() {
        String::new()
    } else {
        format!(
            "\nNo line yet for {}, measured in [vs-pytorch.md](vs-pytorch.md): the script adds \
             one when run on that kind.\n",
            unmeasured
                .iter()
                .map(|k| format!("`{k}`"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    };
    let table = if rows.is_empty() {
        "No machine recorded yet: run `bench/scripts/forecast-budget.sh`.\n".to_string()
    } else {
        markdown_table(
            &[
                "CPU kind",
                "pillarize p50 (ms)",
                "encode p50 (ms)",
                "rollout p50 / p99 (ms)",
                "render one horizon p50 (ms)",
                "forecast with 3 horizons rendered p50 / p99 (ms)",
                "graph time per keyframe (ms; keyframes every 500 ms)",
                "code",
            ],
            &rows,
        )
    };
    format!(
        "{BEGIN}\n## The forecast graph's latency budget, per kind of CPU\n\n\
         The README's main job with the model's views only (`bevworld run \
         configs/graphs/forecast.yaml --set 'methods=[model]' --metrics …`: the demo scene's \
         keyframes, one forecast each where three are behind it, 1 DDIM step), made by `bench/scripts/forecast-budget.sh`: each stage's time \
         per call inside the graph, where the nodes share the cores (the scores node beside \
         them), so a stage reads slower here than alone. A forecast is its rollout and the \
         render of 6 cameras and the sweep at +0.5, +1 and +3 s; the graph's time per keyframe \
         is the run's wall time over its keyframes, against the logs' 500 ms between keyframes.\n\n\
         {table}{unmeasured}{END}\n"
    )
}

/// `page` with its budget section replaced by `section`, or with it appended when it has
/// none.
pub fn replace_section(page: &str, section: &str) -> String {
    match (page.find(BEGIN), page.find(END)) {
        (Some(start), Some(end)) if end > start => {
            let rest = &page[end + END.len()..];
            format!(
                "{}{section}{}",
                &page[..start],
                rest.strip_prefix('\n').unwrap_or(rest)
            )
        }
        _ => format!("{page}\n{section}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run's two files: four stages at known times, 16 keyframes in 6.4 s.
    fn run_files(dir: &Path, drop_encode: bool) -> (std::path::PathBuf, std::path::PathBuf) {
        let node = |id: &str, calls: u64, p50_us: f64| {
            json!({"id": id, "items_in": calls, "items_out": calls,
                   "latency_p50_us": p50_us, "latency_p99_us": 2.0 * p50_us})
        };
        let mut nodes = vec![
            node("source", 0, 100.0),
            node("pillars", 16, 30_000.0),
            node("rollout", 13, 300_000.0),
            node("render", 39, 200_000.0),
        ];
        if !drop_encode {
            nodes.push(node("encode", 16, 50_000.0));
        }
        nodes[0]["items_out"] = json!(16);
        let metrics = dir.join("metrics.json");
        let scores = dir.join("scores.json");
        std::fs::write(
            &metrics,
            json!({"graph": "forecast", "wall_seconds": 6.4, "nodes": nodes}).to_string(),
        )
        .expect("metrics");
        std::fs::write(
            &scores,
            json!({"contexts": 12, "latency_ms": {"rollout_p50": 310.0, "rollout_p99": 400.0,
                   "with_render_p50": 900.0, "with_render_p99": 1100.0}})
            .to_string(),
        )
        .expect("scores");
        (metrics, scores)
    }

    #[test]
    fn a_run_becomes_one_line_of_the_table() {
        let dir = tempfile::tempdir().expect("dir");
        let (metrics, scores) = run_files(dir.path(), false);
        let record = record(&metrics, &scores, "abc1234").expect("record");
        assert_eq!(record["stages"]["encode"]["p50_ms"], 50.0);
        assert_eq!(record["stages"]["render"]["p99_ms"], 400.0);
        assert_eq!(record["forecast_ms"]["with_render_p50"], 900.0);
        let file = write(dir.path(), &record).expect("written");
        assert!(
            file.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("forecast-budget-")),
            "{}",
            file.display()
        );
        let section = section(dir.path());
        // 6.4 s over 16 keyframes: 400 ms each, inside the 500 ms between keyframes.
        assert!(
            section.contains(
                "| 30 | 50 | 310 / 400 | 200 | 900 / 1100 | 400 (keeps up) | `abc1234` |"
            ),
            "{section}"
        );
    }

    #[test]
    fn a_missing_stage_names_its_file_and_node() {
        let dir = tempfile::tempdir().expect("dir");
        let (metrics, scores) = run_files(dir.path(), true);
        let error = record(&metrics, &scores, "abc1234").expect_err("no encode node");
        let text = error.to_string();
        assert!(
            text.contains("metrics.json") && text.contains("nodes[id = encode]"),
            "{text}"
        );
        let error = record(&dir.path().join("absent.json"), &scores, "x").expect_err("no file");
        assert!(error.to_string().contains("absent.json"), "{error}");
    }

    #[test]
    fn the_section_is_replaced_in_place_or_appended() {
        let page = format!("# page\n\n{BEGIN}\nold\n{END}\n\n## after\n");
        let replaced = replace_section(&page, &format!("{BEGIN}\nnew\n{END}\n"));
        assert_eq!(
            replaced,
            format!("# page\n\n{BEGIN}\nnew\n{END}\n\n## after\n")
        );
        assert_eq!(
            replace_section(&replaced, &format!("{BEGIN}\nnew\n{END}\n")),
            replaced,
            "replacing twice changes nothing"
        );
        let appended = replace_section("# page\n", &format!("{BEGIN}\nnew\n{END}\n"));
        assert_eq!(appended, format!("# page\n\n{BEGIN}\nnew\n{END}\n"));
    }
}
