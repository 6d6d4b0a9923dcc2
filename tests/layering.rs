//! The workspace's layering, read from `cargo metadata` and `cargo tree`, so that
//! ARCHITECTURE.md's rules stay true:
//!
//! - the runtime (`graph/`), the domain types, the plots and the device selection depend on no
//!   other crate of ours;
//! - the shared network blocks depend only on the types, and the training machinery only on the
//!   types and the plots: neither knows a model or a dataset;
//! - a model crate (the tokenizer, the world model, the heads) depends on the runtime, the types, the blocks and the device,
//!   never on the data (sensors, pillarization), the metrics or the sinks;
//! - the data families (sensors, pillarization, sinks, metrics) depend on the runtime, the
//!   types, the blocks and the plots, never on each other or on a model;
//! - a model's training crate is where model, data and metrics meet (the heads' also trains the
//!   tokenizer's encoder, for the paper's pretraining arms);
//! - the CLI and the benchmarks may use anything.
//!
//! And every crate builds burn with the features the whole workspace does, so that
//! `cargo test -p CRATE` and `cargo build` reuse the one build of burn.

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

/// Each crate of ours and the crates of ours it may depend on (normal dependencies; tests may
/// use more). The workspace hack, which only unifies features, and the atomic file writer, a
/// leaf, are allowed everywhere.
const ALLOWED: &[(&str, &[&str])] = &[
    ("bevworld-workspace-hack", &[]),
    ("bevworld-atomic-file", &[]),
    ("bevworld-graph", &[]),
    ("bevworld-types", &[]),
    ("bevworld-plot", &[]),
    ("bevworld-device", &[]),
    ("bevworld-blocks", &["bevworld-types"]),
    ("bevworld-training", &["bevworld-types", "bevworld-plot"]),
    ("bevworld-sensors", &["bevworld-graph", "bevworld-types"]),
    ("bevworld-pillarize", &["bevworld-graph", "bevworld-types"]),
    (
        "bevworld-sinks",
        &["bevworld-graph", "bevworld-types", "bevworld-plot"],
    ),
    (
        "bevworld-metrics",
        &["bevworld-graph", "bevworld-types", "bevworld-blocks"],
    ),
    (
        "bevworld-tokenizer",
        &[
            "bevworld-graph",
            "bevworld-types",
            "bevworld-blocks",
            "bevworld-device",
        ],
    ),
    (
        "bevworld-world-model",
        &[
            "bevworld-graph",
            "bevworld-types",
            "bevworld-blocks",
            "bevworld-device",
        ],
    ),
    (
        "bevworld-heads",
        &[
            "bevworld-graph",
            "bevworld-types",
            "bevworld-blocks",
            "bevworld-device",
        ],
    ),
    (
        "bevworld-heads-train",
        &[
            "bevworld-graph",
            "bevworld-types",
            "bevworld-blocks",
            "bevworld-training",
            "bevworld-heads",
            // The paper's pretraining arms train the tokenizer's encoder with the heads, on
            // images and pillars.
            "bevworld-tokenizer",
            "bevworld-pillarize",
            "bevworld-sensors",
            "bevworld-sinks",
            "bevworld-metrics",
        ],
    ),
    (
        "bevworld-world-model-train",
        &[
            "bevworld-graph",
            "bevworld-types",
            "bevworld-blocks",
            "bevworld-training",
            "bevworld-world-model",
            "bevworld-sensors",
            "bevworld-sinks",
            "bevworld-metrics",
        ],
    ),
    (
        "bevworld-tokenizer-train",
        &[
            "bevworld-graph",
            "bevworld-types",
            "bevworld-blocks",
            "bevworld-training",
            "bevworld-tokenizer",
            "bevworld-sensors",
            "bevworld-pillarize",
            "bevworld-metrics",
        ],
    ),
];

/// Crates that may depend on any crate of ours.
const TOP: &[&str] = &["bevworld", "bevworld-bench"];

const HACK: &str = "bevworld-workspace-hack";

/// The one writer of finished files: a leaf with no crate of ours below it, so any crate may
/// write through it.
const ATOMIC_FILE: &str = "bevworld-atomic-file";

fn cargo() -> Command {
    let mut command = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    command.current_dir(env!("CARGO_MANIFEST_DIR"));
    command
}

fn run(command: &mut Command) -> String {
    let output = command.output().expect("cargo runs");
    assert!(
        output.status.success(),
        "{command:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).expect("utf-8")
}

/// Each workspace member and its normal dependencies on other members.
fn member_dependencies() -> BTreeMap<String, BTreeSet<String>> {
    let text = run(cargo().args([
        "metadata",
        "--format-version",
        "1",
        "--no-deps",
        "--offline",
    ]));
    let metadata: serde_json::Value = serde_json::from_str(&text).expect("metadata JSON");
    let packages = metadata["packages"].as_array().expect("packages");
    let members: BTreeSet<String> = packages
        .iter()
        .filter_map(|p| p["name"].as_str().map(String::from))
        .collect();
    packages
        .iter()
        .map(|package| {
            let name = package["name"].as_str().expect("name").to_string();
            let ours = package["dependencies"]
                .as_array()
                .expect("dependencies")
                .iter()
                .filter(|d| d["kind"].is_null())
                .filter_map(|d| d["name"].as_str())
                .filter(|d| members.contains(*d))
                .map(String::from)
                .collect();
            (name, ours)
        })
        .collect()
}

#[test]
fn every_crate_depends_only_on_the_layers_below_it() {
    let dependencies = member_dependencies();
    let rules: BTreeMap<&str, &[&str]> = ALLOWED.iter().copied().collect();
    let mut broken = Vec::new();
    for (name, ours) in &dependencies {
        if TOP.contains(&name.as_str()) {
            continue;
        }
        let Some(allowed) = rules.get(name.as_str()) else {
            broken.push(format!(
                "{name} has no layering rule: add it to ALLOWED in tests/layering.rs and to ARCHITECTURE.md"
            ));
            continue;
        };
        for dependency in ours {
            if dependency != HACK
                && dependency != ATOMIC_FILE
                && !allowed.contains(&dependency.as_str())
            {
                broken.push(format!("{name} must not depend on {dependency}"));
            }
        }
        if name != HACK && !ours.contains(HACK) {
            broken.push(format!(
                "{name} does not depend on {HACK}, so its builds may differ from the workspace's"
            ));
        }
    }
    for (name, _) in ALLOWED {
        assert!(
            dependencies.contains_key(*name),
            "{name} is in the rules but not in the workspace"
        );
    }
    assert!(broken.is_empty(), "{}", broken.join("\n"));
}

#[test]
fn the_rules_forbid_what_the_architecture_forbids() {
    // The rules themselves, so that a loosened rule is a visible change.
    let rules: BTreeMap<&str, &[&str]> = ALLOWED.iter().copied().collect();
    let data = [
        "bevworld-sensors",
        "bevworld-pillarize",
        "bevworld-sinks",
        "bevworld-metrics",
    ];
    // A model knows no data and no training; the world model reads latents, never the
    // tokenizer that makes them (the statistics file in the types is their contract).
    let models = [
        "bevworld-tokenizer",
        "bevworld-world-model",
        "bevworld-heads",
    ];
    for model in models {
        let others = models.iter().filter(|other| **other != model);
        for forbidden in data.iter().chain(&["bevworld-training"]).chain(others) {
            assert!(
                !rules[model].contains(forbidden),
                "{model} may use {forbidden}"
            );
        }
    }
    for machinery in ["bevworld-graph", "bevworld-blocks", "bevworld-training"] {
        for forbidden in data.iter().chain(&models) {
            assert!(
                !rules[machinery].contains(forbidden),
                "{machinery} may use {forbidden}"
            );
        }
    }
    assert!(rules["bevworld-graph"].is_empty());
}

/// Each package's enabled features as `cargo tree` resolves them for `args`, keyed by
/// `name version`.
fn features(args: &[&str]) -> BTreeMap<String, BTreeSet<String>> {
    let text = run(cargo()
        .args(["tree", "--offline", "-e", "features", "--prefix", "none"])
        .args(["--format", "{p} {f}"])
        .args(args));
    let mut packages: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for line in text.lines() {
        if line.contains(" feature \"") {
            continue;
        }
        let parts: Vec<&str> = line.split_whitespace().collect();
        let [name, version, rest @ ..] = parts.as_slice() else {
            continue;
        };
        let enabled = rest
            .iter()
            .rev()
            .find(|p| !p.starts_with('('))
            .map(|f| f.split(',').map(String::from).collect::<Vec<_>>())
            .unwrap_or_default();
        packages
            .entry(format!("{name} {version}"))
            .or_default()
            .extend(enabled);
    }
    packages
}

#[test]
fn every_build_gives_burns_dependencies_the_workspaces_features() {
    let burn: BTreeSet<String> = run(cargo().args([
        "tree",
        "--offline",
        "-p",
        "burn",
        "-e",
        "normal,build",
        "--prefix",
        "none",
        "--format",
        "{p}",
    ]))
    .lines()
    .filter_map(|l| {
        let mut parts = l.split_whitespace();
        Some(format!("{} {}", parts.next()?, parts.next()?))
    })
    .collect();
    let whole = features(&["--workspace", "-e", "normal,build,dev"]);
    let mut builds: Vec<(String, Vec<String>)> = vec![
        (
            "cargo build --release (the binary)".into(),
            ["-p", "bevworld", "-e", "normal,build"]
                .map(String::from)
                .to_vec(),
        ),
        (
            "cargo build --workspace".into(),
            ["--workspace", "-e", "normal,build"]
                .map(String::from)
                .to_vec(),
        ),
    ];
    for member in member_dependencies().keys() {
        builds.push((
            format!("cargo test -p {member}"),
            vec![
                "-p".into(),
                member.clone(),
                "-e".into(),
                "normal,build,dev".into(),
            ],
        ));
    }
    let mut differing = BTreeMap::new();
    let mut builds_differing = BTreeSet::new();
    for (build, args) in &builds {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        for (package, enabled) in features(&args) {
            if burn.contains(&package) && whole.get(&package) != Some(&enabled) {
                differing.insert(
                    package.clone(),
                    whole.get(&package).cloned().unwrap_or_default(),
                );
                builds_differing.insert(build.clone());
            }
        }
    }
    let lines: Vec<String> = differing
        .iter()
        .map(|(package, enabled)| {
            let (name, version) = package.split_once(' ').unwrap_or((package, ""));
            let enabled: Vec<String> = enabled.iter().map(|f| format!("\"{f}\"")).collect();
            format!(
                "{name} = {{ version = \"{}\", default-features = false, features = [{}] }}",
                version.trim_start_matches('v'),
                enabled.join(", ")
            )
        })
        .collect();
    assert!(
        lines.is_empty(),
        "these builds would rebuild burn: {builds_differing:?}; add to \
         nodes/workspace-hack/Cargo.toml's [dependencies]:\n{}",
        lines.join("\n")
    );
}
