//! One model bundle per graph, and commands bound to graphs by contract: each model of the
//! forecast graph is loaded once and shared by the nodes that run it; `check` names a
//! tokenizer and a world model that do not belong together before anything runs; a renamed
//! node breaks `check`, and a graph that lacks a name a command binds to is refused by the
//! command before it runs.

use std::path::Path;

use crate::common::{bevworld_owned, repo, text};

fn path(p: &Path) -> String {
    p.display().to_string()
}

#[test]
fn each_model_of_the_forecast_graph_is_loaded_once_and_shared() {
    let registry = crate::registry::registry();
    let graph = bevworld_graph::load(&repo().join("configs/graphs/forecast.yaml"), &registry, &[])
        .expect("valid")
        .build()
        .expect("built");
    let loads = graph.spec.models.loads();
    let asked = graph.spec.models.asked();
    // `encode` and `render` run one tokenizer; `rollout` loads the world model; `scores` the
    // latent statistics. Each once, however many nodes ask.
    assert_eq!(loads.get("tiny/LoadedModel"), Some(&1), "{loads:?}");
    assert_eq!(asked.get("tiny/LoadedModel"), Some(&2), "{asked:?}");
    assert_eq!(loads.get("tiny/LoadedWorldModel"), Some(&1), "{loads:?}");
    assert!(loads.values().all(|&n| n == 1), "{loads:?}");
    assert_eq!(loads.len(), 3, "{loads:?}");
}

#[test]
fn check_names_a_world_model_trained_on_another_tokenizer_before_anything_runs() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The shipped tokenizer's weights with one byte more: another digest, the same tensors.
    let other = dir.path().join("other-tokenizer.bpk");
    let mut bytes =
        std::fs::read(repo().join("nodes/tokenizer/weights/tokenizer-tiny.bpk")).expect("read");
    bytes.push(0);
    std::fs::write(&other, bytes).expect("write");
    let out = dir.path().join("forecast");
    let sets = [
        format!("models.tiny.tokenizer.weights={}", path(&other)),
        "models.tiny.tokenizer.latent_stats=nodes/tokenizer/weights/tokenizer-tiny.stats.json"
            .to_string(),
        format!("out={}", path(&out)),
    ];
    for command in ["check", "run"] {
        let mut args = vec![command.to_string(), "configs/graphs/forecast.yaml".into()];
        for set in &sets {
            args.extend(["--set".to_string(), set.clone()]);
        }
        let output = bevworld_owned(&args);
        let message = text(&output);
        assert_eq!(output.status.code(), Some(2), "{command}: {message}");
        // At the bundle's world model, with its line, once.
        assert!(
            message.contains("configs/graphs/forecast.yaml:")
                && message.contains("model bundle 'tiny', 'world_model.weights'")
                && message.contains("trained on the latents of tokenizer"),
            "{command}: {message}"
        );
        assert!(
            message.contains("1 problem(s) found"),
            "{command}: {message}"
        );
        assert!(!out.exists(), "{command} wrote {}", out.display());
    }
    // The shipped pair passes, and the graph serves the commands that run it.
    let output = bevworld_owned(&["check".into(), "configs/graphs/forecast.yaml".into()]);
    assert!(output.status.success(), "{}", text(&output));
    for command in ["`eval forecast`", "`eval control`"] {
        assert!(
            text(&output).contains(&format!("serves {command}")),
            "{}",
            text(&output)
        );
    }
}

/// `forecast.yaml` with node `rollout` renamed everywhere but in its `interface:`, or with an
/// exposed name left out.
fn edited_forecast(dir: &Path, name: &str, edit: impl Fn(&str) -> String) -> String {
    let text = std::fs::read_to_string(repo().join("configs/graphs/forecast.yaml")).expect("graph");
    let edited = edit(&text);
    assert_ne!(edited, text, "the edit changed nothing");
    let file = dir.join(name);
    std::fs::write(&file, edited).expect("write");
    path(&file)
}

#[test]
fn a_renamed_node_breaks_check_not_a_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    let renamed = edited_forecast(dir.path(), "renamed.yaml", |text| {
        text.replace("- id: rollout", "- id: diffusion")
            .replace("to: rollout.window", "to: diffusion.window")
            .replace("from: rollout.forecast", "from: diffusion.forecast")
    });
    let output = bevworld_owned(&["check".into(), renamed]);
    let message = text(&output);
    assert_eq!(output.status.code(), Some(2), "{message}");
    assert!(
        message.contains(
            "interface parameter 'actions' names node 'rollout', which the graph does not have"
        ) && message.contains("nodes: source, pillars, encode, history, diffusion"),
        "{message}"
    );
}

#[test]
fn a_command_refuses_a_graph_that_lacks_a_name_it_binds_to() {
    let dir = tempfile::tempdir().expect("tempdir");
    let graph = edited_forecast(dir.path(), "no-horizons.yaml", |text| {
        text.replace("    horizons: rollout.horizons\n", "")
    });
    // The graph alone is valid; the command's contract is what it fails.
    let checked = bevworld_owned(&["check".into(), graph.clone()]);
    assert!(checked.status.success(), "{}", text(&checked));
    let output = bevworld_owned(&[
        "eval".into(),
        "forecast".into(),
        "--graph".into(),
        graph,
        "--data".into(),
        path(dir.path()),
        "--out".into(),
        path(&dir.path().join("eval")),
    ]);
    let message = text(&output);
    assert_eq!(output.status.code(), Some(2), "{message}");
    assert!(
        message.contains("`eval forecast` binds to the parameter 'horizons', which this graph's `interface:` does not expose"),
        "{message}"
    );
    assert!(!dir.path().join("eval").exists());
}
