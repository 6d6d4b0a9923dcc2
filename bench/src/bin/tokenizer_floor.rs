//! The table of tokenizer reconstructions side by side, from their summaries (`bevworld eval
//! tokenizer --json`, or the `summary.json` it writes): per run the cameras' PSNR, the sweep's
//! Chamfer distance and the rendered sweep's agent-level scores against the annotated vehicles,
//! the floor no forecast decoded through that tokenizer can beat by much. Each figure is the
//! mean over scenes ± its spread over them. The pages quote this table, generated from the
//! figures, never typed.
//!
//!   cargo run --release -p bevworld-bench --bin tokenizer_floor -- shipped=a.json "fine-tune=b.json"

use std::fmt::Write as _;

const USAGE: &str = "usage: tokenizer_floor LABEL=SUMMARY.json ...";

/// `mean ± spread` with `digits` decimals; the mean alone without a spread; `—` without either.
fn with_spread(mean: &serde_json::Value, spread: &serde_json::Value, digits: usize) -> String {
    match (mean.as_f64(), spread.as_f64()) {
        (Some(mean), Some(spread)) => format!("{mean:.digits$} ± {spread:.digits$}"),
        (Some(mean), None) => format!("{mean:.digits$}"),
        _ => "—".to_string(),
    }
}

/// One summary's row. The whole-sweep figures are the means over keyframes with the spread of
/// the scenes' means (`eval tokenizer`'s own); the agent figures the mean over scenes of each
/// scene's pooled value, with their spread.
fn row(label: &str, file: &str, summary: &serde_json::Value) -> Result<String, String> {
    let frames = summary["frames"]
        .as_u64()
        .ok_or_else(|| format!("{file}: no \"frames\"; is it an `eval tokenizer` summary?"))?;
    let agents = &summary["agents"];
    if agents.is_null() {
        return Err(format!(
            "{file}: no \"agents\": the dataset had no annotated vehicles, or the summary predates the agent scores"
        ));
    }
    let scenes = summary["scenes"].as_array().map_or(0, Vec::len);
    let agent = |class: &str, name: &str, digits: usize| {
        let figure = &agents[class]["over_scenes"][name];
        with_spread(&figure["mean"], &figure["std"], digits)
    };
    let whole = |name: &str, digits: usize| {
        with_spread(&summary[name], &summary["scene_std"][name], digits)
    };
    Ok(format!(
        "| {label} | {scenes} / {frames} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
        whole("psnr_db", 2),
        whole("chamfer_m2", 3),
        agent("moving_vehicles", "recall_0.5m", 2),
        agent("moving_vehicles", "recall_1m", 2),
        agent("moving_vehicles", "recall_0.5m_above_ground", 2),
        agent("moving_vehicles", "chamfer_to_forecast", 2),
        agent("parked_vehicles", "recall_0.5m", 2),
        agent("parked_vehicles", "recall_1m", 2),
        agent("static", "chamfer_to_forecast", 3),
    ))
}

fn table(runs: &[(String, String, serde_json::Value)]) -> Result<String, String> {
    let mut text = String::from(
        "| weights | scenes / keyframes | PSNR (dB) | Chamfer (m²) | moving: recall@0.5 m | moving: recall@1 m | moving: recall@0.5 m above ground | moving: Chamfer truth→render (m²) | parked: recall@0.5 m | parked: recall@1 m | static: Chamfer truth→render (m²) |\n|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (label, file, summary) in runs {
        let _ = writeln!(text, "{}", row(label, file, summary)?);
    }
    Ok(text)
}

fn main() -> std::process::ExitCode {
    let mut runs = Vec::new();
    for argument in std::env::args().skip(1) {
        let Some((label, file)) = argument.split_once('=') else {
            eprintln!("{argument}: not LABEL=FILE\n{USAGE}");
            return std::process::ExitCode::FAILURE;
        };
        let summary = std::fs::read_to_string(file)
            .map_err(|e| format!("{file}: {e}"))
            .and_then(|text| {
                serde_json::from_str::<serde_json::Value>(&text).map_err(|e| format!("{file}: {e}"))
            });
        match summary {
            Ok(summary) => runs.push((label.to_string(), file.to_string(), summary)),
            Err(message) => {
                eprintln!("{message}");
                return std::process::ExitCode::FAILURE;
            }
        }
    }
    if runs.is_empty() {
        eprintln!("{USAGE}");
        return std::process::ExitCode::FAILURE;
    }
    match table(&runs) {
        Ok(text) => {
            print!("{text}");
            std::process::ExitCode::SUCCESS
        }
        Err(message) => {
            eprintln!("{message}");
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A summary of two scenes, its figures chosen by hand.
    fn summary() -> serde_json::Value {
        let over = |mean: f64, std: f64| serde_json::json!({"mean": mean, "std": std});
        let class = |near: f64, far: f64, above: f64, chamfer: f64| {
            serde_json::json!({"over_scenes": {
                "recall_0.5m": over(near, 0.01),
                "recall_1m": over(far, 0.02),
                "recall_0.5m_above_ground": over(above, 0.03),
                "chamfer_to_forecast": over(chamfer, 0.5),
            }})
        };
        serde_json::json!({
            "frames": 16,
            "psnr_db": 24.234,
            "chamfer_m2": 0.4712,
            "scene_std": {"psnr_db": 0.45, "chamfer_m2": 0.009},
            "scenes": [{"scene": "a"}, {"scene": "b"}],
            "agents": {
                "moving_vehicles": class(0.32, 0.67, 0.28, 2.74),
                "parked_vehicles": class(0.42, 0.81, 0.35, 0.873),
                "static": class(0.87, 0.95, 0.17, 0.449),
            },
        })
    }

    #[test]
    fn a_row_gives_each_figure_with_its_spread_over_scenes() {
        let text = table(&[("shipped".into(), "s.json".into(), summary())]).expect("table");
        let row = text.lines().nth(2).expect("one row");
        assert_eq!(
            row,
            "| shipped | 2 / 16 | 24.23 ± 0.45 | 0.471 ± 0.009 | 0.32 ± 0.01 | 0.67 ± 0.02 | 0.28 ± 0.03 | 2.74 ± 0.50 | 0.42 ± 0.01 | 0.81 ± 0.02 | 0.449 ± 0.500 |"
        );
    }

    #[test]
    fn a_summary_without_agents_or_frames_is_refused_by_file() {
        let mut without = summary();
        without["agents"] = serde_json::Value::Null;
        let message = table(&[("x".into(), "old.json".into(), without)]).expect_err("refused");
        assert!(message.starts_with("old.json: no \"agents\""), "{message}");
        let message = table(&[("x".into(), "other.json".into(), serde_json::json!({}))])
            .expect_err("refused");
        assert!(
            message.starts_with("other.json: no \"frames\""),
            "{message}"
        );
    }

    #[test]
    fn missing_figures_show_as_dashes_not_zeros() {
        let mut partial = summary();
        partial["agents"]["moving_vehicles"] = serde_json::Value::Null;
        partial["scene_std"]["psnr_db"] = serde_json::Value::Null;
        let text = table(&[("p".into(), "p.json".into(), partial)]).expect("table");
        let row = text.lines().nth(2).expect("one row");
        assert!(
            row.starts_with("| p | 2 / 16 | 24.23 | 0.471 ± 0.009 | — | — | — | — | 0.42"),
            "{row}"
        );
    }
}
