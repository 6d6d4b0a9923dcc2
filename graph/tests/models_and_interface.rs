//! The graph-level `models:` section (each bundle checked where it is written, each part
//! loaded once and shared), the `interface:` a command binds to instead of node ids, and the
//! collector that hands an exposed output back in-process.

mod common;

use bevworld_graph::{Contract, Diagnostics, Override, RunOptions, StopHandle, resolve, validate};
use common::{Counted, registry};

/// Two nodes run the same bundle; the interface exposes the count and the last output.
const GRAPH: &str = "\
models:
  small: {offset: 100}
  large: {offset: 500}
interface:
  params: {items: source.count, bundle: first.model}
  outputs: {result: second.out}
nodes:
  - {id: source, kind: count, params: {count: 3}}
  - {id: first, kind: offset, params: {model: small}}
  - {id: second, kind: offset, params: {model: small}}
  - {id: sink, kind: record, params: {name: models-graph}}
edges:
  - {from: source.out, to: first.in}
  - {from: first.out, to: second.in}
  - {from: second.out, to: sink.in}
";

fn set(texts: &[&str]) -> Vec<Override> {
    texts
        .iter()
        .map(|t| Override::parse(t).expect("override"))
        .collect()
}

fn problems(yaml: &str, overrides: &[Override]) -> Diagnostics {
    match resolve(yaml, "g.yaml", &registry(), overrides) {
        Ok(_) => panic!("expected problems"),
        Err(diagnostics) => diagnostics,
    }
}

fn run_collecting(
    yaml: &str,
    overrides: &[Override],
) -> (Vec<u64>, std::collections::BTreeMap<String, usize>) {
    let mut graph = resolve(yaml, "g.yaml", &registry(), overrides).expect("valid");
    let collected = graph.collect::<Counted>("result").expect("exposed");
    let models = std::sync::Arc::clone(&graph.spec.models);
    let outcome = bevworld_graph::run(
        graph,
        RunOptions {
            stop: StopHandle::new(),
            observer: None,
        },
    );
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    let values = collected.take().iter().map(|c| c.value).collect();
    (values, models.loads())
}

#[test]
fn a_bundle_named_by_two_nodes_is_loaded_once_and_both_run_it() {
    let (values, loads) = run_collecting(GRAPH, &[]);
    // Each item passes two offset nodes of the same bundle: +100 twice.
    assert_eq!(values, vec![200, 201, 202]);
    assert_eq!(loads.get("small/Offset"), Some(&1), "{loads:?}");
    // The bundle no node names is never loaded.
    assert_eq!(loads.len(), 1, "{loads:?}");
}

#[test]
fn set_models_swaps_a_bundle_for_every_node_and_is_checked_like_the_file() {
    let (values, _) = run_collecting(GRAPH, &set(&["models.small.offset=10"]));
    assert_eq!(values, vec![20, 21, 22]);
    let bad = problems(GRAPH, &set(&["models.small.offset=5000"]));
    assert!(
        bad.mentions("model bundle 'small', 'offset': 5000 is too large"),
        "{bad}"
    );
    let unknown = problems(GRAPH, &set(&["models.smal.offset=1"]));
    assert!(unknown.mentions("no model bundle 'smal'"), "{unknown}");
    assert!(
        unknown.to_string().contains("did you mean 'small'"),
        "{unknown}"
    );
}

#[test]
fn a_bad_bundle_points_at_its_key() {
    let yaml = GRAPH.replace("large: {offset: 500}", "large: {offset: 500, nope: 1}");
    let bad = problems(&yaml, &[]);
    let d = &bad.0[0];
    assert!(d.message.contains("model bundle 'large', 'nope'"), "{bad}");
    let position = d.position.as_ref().expect("a position");
    assert_eq!(position.line, 3, "{bad}");
    let yaml = GRAPH.replace("small: {offset: 100}", "small: {offset: 2000}");
    let bad = problems(&yaml, &[]);
    assert_eq!(bad.0[0].position.as_ref().map(|p| p.line), Some(2), "{bad}");
}

#[test]
fn a_node_naming_a_missing_bundle_is_refused_at_its_model_field() {
    let yaml = GRAPH.replace(
        "params: {model: small}}\n  - {id: sink",
        "params: {model: smal}}\n  - {id: sink",
    );
    let bad = problems(&yaml, &[]);
    assert!(
        bad.mentions("bad parameter 'model' of node 'second'"),
        "{bad}"
    );
    assert!(bad.mentions("no model bundle 'smal'"), "{bad}");
    assert_eq!(
        bad.0[0].position.as_ref().map(|p| p.line),
        Some(10),
        "{bad}"
    );
}

#[test]
fn models_is_no_node_id() {
    let yaml = "nodes:\n  - {id: models, kind: count, params: {count: 1}}\n  - {id: b, kind: record, params: {name: m}}\nedges:\n  - {from: models.out, to: b.in}\n";
    assert!(problems(yaml, &[]).mentions("node id 'models' is not valid"));
}

#[test]
fn exposed_parameters_are_set_by_name() {
    let (values, _) = run_collecting(GRAPH, &set(&["items=2", "bundle=large"]));
    // first runs `large` (+500), second still `small` (+100).
    assert_eq!(values, vec![600, 601]);
    let graph = validate(GRAPH, "g.yaml", &registry(), &set(&["items=5"])).expect("valid");
    assert_eq!(
        graph.spec.exposed_param("items"),
        Some(&serde_json::json!(5))
    );
    assert_eq!(
        graph.spec.exposed_param("bundle"),
        Some(&serde_json::json!("small"))
    );
    let bad = problems(GRAPH, &set(&["itmes=2"]));
    assert!(bad.mentions("exposes no parameter 'itmes'"), "{bad}");
    assert!(bad.to_string().contains("did you mean 'items'"), "{bad}");
}

#[test]
fn renaming_a_node_breaks_the_interface_at_validation() {
    let renamed = GRAPH
        .replace("{id: source,", "{id: counter,")
        .replace("from: source.out", "from: counter.out");
    let bad = problems(&renamed, &[]);
    assert!(
        bad.mentions(
            "interface parameter 'items' names node 'source', which the graph does not have"
        ),
        "{bad}"
    );
    assert_eq!(bad.0[0].position.as_ref().map(|p| p.line), Some(5), "{bad}");
    let wrong_key = GRAPH.replace("source.count", "source.cnt");
    assert!(problems(&wrong_key, &[]).mentions("has no parameter 'cnt'"));
    let wrong_port = GRAPH.replace("second.out", "second.output");
    assert!(problems(&wrong_port, &[]).mentions("has no output port 'output'"));
}

#[test]
fn a_contract_names_what_the_graph_does_not_expose() {
    let graph = validate(GRAPH, "g.yaml", &registry(), &[]).expect("valid");
    let met = Contract {
        command: "demo",
        params: &["items"],
        outputs: &["result"],
    };
    assert!(graph.spec.check_contract(&met).is_ok());
    let unmet = Contract {
        command: "demo",
        params: &["items", "horizons"],
        outputs: &["scores"],
    };
    let bad = graph.spec.check_contract(&unmet).expect_err("unmet");
    assert_eq!(bad.0.len(), 2, "{bad}");
    assert!(
        bad.mentions("`demo` binds to the parameter 'horizons'"),
        "{bad}"
    );
    assert!(bad.mentions("`demo` binds to the output 'scores'"), "{bad}");
}

#[test]
fn a_collector_checks_the_output_and_its_type() {
    let mut graph = resolve(GRAPH, "g.yaml", &registry(), &[]).expect("valid");
    assert!(graph.collect::<Counted>("nothing").is_err());
    let wrong = graph.collect::<String>("result").err().expect("wrong type");
    assert!(wrong.mentions("carries Counted, not the String"), "{wrong}");
}

#[test]
fn a_refused_bundle_is_reported_once_not_again_at_every_node_naming_it() {
    let bad = problems(GRAPH, &set(&["models.small.offset=5000"]));
    assert_eq!(bad.0.len(), 1, "{bad}");
}
