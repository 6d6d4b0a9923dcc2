//! What each command needs of the graph it drives: the parameters it sets and the outputs it
//! collects, by the names the graph exposes (`interface:`), never by node ids. A command holds
//! its graph to its contract before it runs, and `bevworld check` holds each command's default
//! graph to it, so renaming a node breaks `check`, not a run.

use std::path::Path;

use bevworld_graph::Contract;

pub const EVAL_FORECAST: Contract = Contract {
    command: "eval forecast",
    params: &[
        "model",
        "data",
        "out",
        "scores_json",
        "roi",
        "print_scores",
        "actions",
        "log_future",
        "steps",
        "samples",
        "horizons",
        "shrink",
    ],
    outputs: &["scores"],
};

pub const EVAL_CONTROL: Contract = Contract {
    command: "eval control",
    params: &[
        "model",
        "data",
        "scenes",
        "start",
        "max_frames",
        "log_future",
        "actions",
        "horizons",
        "steps",
        "methods",
        "written_method",
        "sensors",
        "out",
        "scores_json",
        "print_scores",
    ],
    outputs: &["rendered"],
};

pub const EVAL_TOKENIZER: Contract = Contract {
    command: "eval tokenizer",
    params: &["model", "data", "out", "metrics_csv", "roi"],
    outputs: &["summary"],
};

/// The world model's latent caches (`train world-model`, `eval world-model`).
pub const LATENT_CACHE: Contract = Contract {
    command: "train world-model",
    params: &["model", "data", "sweeps", "out", "index"],
    outputs: &[],
};

/// The tokenizer's features of the detector's sets (`train detector`): the latent into `out`,
/// the fused feature into `fused_out`, in one pass.
pub const DETECTOR_FEATURES: Contract = Contract {
    command: "train detector",
    params: &["model", "data", "out", "fused_out"],
    outputs: &[],
};

/// The weight-free pillar statistics of the detector's sets (`train detector --input
/// bev_stats`).
pub const DETECTOR_BEV_STATS: Contract = Contract {
    command: "train detector",
    params: &["data", "out"],
    outputs: &[],
};

/// Each command's default graph, with its contract.
pub const DEFAULT_GRAPHS: &[(&str, Contract)] = &[
    ("configs/graphs/forecast.yaml", EVAL_FORECAST),
    ("configs/graphs/forecast.yaml", EVAL_CONTROL),
    ("configs/graphs/reconstruct.yaml", EVAL_TOKENIZER),
    (super::latent_cache::EXPORT_GRAPH, LATENT_CACHE),
    (super::detector_train::FEATURES_GRAPH, DETECTOR_FEATURES),
    (super::detector_train::BEV_STATS_GRAPH, DETECTOR_BEV_STATS),
];

/// The contracts of the commands whose default graph is `graph`.
pub fn of_default_graph(graph: &Path) -> Vec<Contract> {
    let Ok(graph) = graph.canonicalize() else {
        return Vec::new();
    };
    DEFAULT_GRAPHS
        .iter()
        .filter(|(path, _)| Path::new(path).canonicalize().is_ok_and(|p| p == graph))
        .map(|(_, contract)| *contract)
        .collect()
}
