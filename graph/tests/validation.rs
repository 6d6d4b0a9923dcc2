//! Every validation error, with its line and column, and all of them reported at once.

mod common;

use bevworld_graph::{Diagnostics, Override, resolve};
use common::registry;

fn problems(yaml: &str) -> Diagnostics {
    match resolve(yaml, "g.yaml", &registry(), &[]) {
        Ok(_) => panic!("expected validation errors"),
        Err(diagnostics) => diagnostics,
    }
}

fn only(diagnostics: &Diagnostics) -> &bevworld_graph::Diagnostic {
    assert_eq!(diagnostics.0.len(), 1, "{diagnostics}");
    &diagnostics.0[0]
}

fn line_col(d: &bevworld_graph::Diagnostic) -> (u64, u64) {
    let p = d.position.as_ref().expect("a position");
    (p.line, p.column)
}

#[test]
fn unknown_kind_points_at_the_kind_and_suggests() {
    let d = problems("nodes:\n  - id: a\n    kind: cuont\n");
    let d = only(&d);
    assert!(d.message.contains("unknown node kind 'cuont'"));
    assert_eq!(line_col(d), (3, 11));
    assert!(d.hint.as_deref().unwrap().contains("did you mean 'count'"));
    assert!(d.to_string().starts_with("g.yaml:3:11: error:"));
}

#[test]
fn unknown_port_lists_the_ports() {
    let d = problems(
        "nodes:\n  - {id: a, kind: count}\n  - {id: b, kind: record, params: {name: x}}\nedges:\n  - {from: a.outt, to: b.in}\n",
    );
    let d = only(&d);
    assert!(d.message.contains("has no output port 'outt'"), "{d}");
    assert_eq!(line_col(d).0, 5);
    assert!(d.hint.as_deref().unwrap().contains("out (Counted)"));
}

#[test]
fn type_mismatch_names_both_types() {
    let d = problems(
        "nodes:\n  - {id: a, kind: count}\n  - {id: t, kind: text_sink}\nedges:\n  - {from: a.out, to: t.text}\n",
    );
    let d = only(&d);
    assert!(d.message.contains("port type mismatch"));
    assert!(
        d.message.contains("Counted") && d.message.contains("String"),
        "{d}"
    );
    assert_eq!(line_col(d).0, 5);
}

#[test]
fn duplicate_id_is_reported_at_the_second() {
    let d = problems(
        "nodes:\n  - {id: a, kind: count}\n  - {id: a, kind: count}\n  - {id: r, kind: record, params: {name: x}}\nedges:\n  - {from: a.out, to: r.in}\n",
    );
    let d = only(&d);
    assert!(d.message.contains("duplicate node id 'a'"));
    assert_eq!(line_col(d).0, 3);
}

#[test]
fn unconnected_required_input() {
    let d = problems("nodes:\n  - {id: r, kind: record, params: {name: x}}\n");
    let d = only(&d);
    assert!(d.message.contains("required input 'r.in'"), "{d}");
    assert_eq!(line_col(d).0, 2);
}

#[test]
fn cycle_is_named() {
    let d = problems(
        "nodes:\n  - {id: s, kind: count}\n  - {id: j, kind: join}\n  - {id: p, kind: pass}\nedges:\n  - {from: s.out, to: j.left}\n  - {from: j.out, to: p.in}\n  - {from: p.out, to: j.right}\n",
    );
    let d = only(&d);
    assert!(d.message.contains("cycle: j -> p -> j"), "{d}");
}

#[test]
fn bad_parameter_gives_field_line_and_accepted_values() {
    let d = problems(
        "nodes:\n  - id: s\n    kind: count\n  - id: t\n    kind: text_sink\n    params:\n      flavour: spicy\n",
    );
    // The unconnected input is a second, separate problem.
    assert_eq!(d.0.len(), 2, "{d}");
    let bad = d
        .iter()
        .find(|d| d.message.contains("bad parameter"))
        .unwrap();
    assert!(bad.message.contains("'flavour'"), "{bad}");
    assert_eq!(line_col(bad).0, 7);
    assert!(
        bad.hint.as_deref().unwrap().contains("`plain` or `fancy`"),
        "{bad}"
    );
}

#[test]
fn unknown_parameter_key_is_an_error() {
    let d = problems(
        "nodes:\n  - id: s\n    kind: count\n    params:\n      count: 3\n      cuont: 4\n",
    );
    let d = only(&d);
    assert!(d.message.contains("'cuont'"), "{d}");
    assert_eq!(line_col(d).0, 6);
    assert!(d.hint.as_deref().unwrap().contains("count"));
}

#[test]
fn builder_range_check_names_the_field() {
    let d = problems(
        "nodes:\n  - {id: s, kind: count}\n  - id: t\n    kind: text_sink\n    params: {scale: -2}\nedges:\n  - {from: s.out, to: t.text}\n",
    );
    let bad = d
        .iter()
        .find(|d| d.message.contains("bad parameter"))
        .unwrap();
    assert!(
        bad.message.contains("'scale'") && bad.message.contains("must be > 0"),
        "{bad}"
    );
    assert_eq!(bad.hint.as_deref(), Some("accepted: a number > 0"));
}

#[test]
fn malformed_yaml_has_a_position() {
    let d = problems("nodes:\n  - {id: a, kind: count\n  - {id: b}\n");
    let d = only(&d);
    assert!(d.message.starts_with("malformed graph file"), "{d}");
    assert!(d.position.is_some());
}

#[test]
fn unknown_top_level_key_is_malformed() {
    let d = problems("nodes: []\nedgez: []\n");
    assert!(d.mentions("edgez"), "{d}");
}

#[test]
fn bad_policy_lists_the_policies() {
    let d = problems(
        "nodes:\n  - {id: a, kind: count}\n  - {id: b, kind: record, params: {name: x}}\nedges:\n  - {from: a.out, to: b.in, policy: newest}\n",
    );
    assert!(d.mentions("newest"), "{d}");
    assert!(d.mentions("drop_oldest"), "{d}");
}

#[test]
fn every_problem_is_reported_at_once() {
    let d = problems(
        r#"nodes:
  - {id: a, kind: count}
  - {id: a, kind: count}
  - {id: b, kind: nosuch}
  - {id: r, kind: record, params: {name: x, extra: 1}}
  - {id: q, kind: record, params: {name: y}}
edges:
  - {from: a.nope, to: q.in}
  - {from: ghost.out, to: q.in}
"#,
    );
    assert!(d.mentions("duplicate node id 'a'"));
    assert!(d.mentions("unknown node kind 'nosuch'"));
    assert!(d.mentions("'extra'"));
    assert!(d.mentions("no output port 'nope'"));
    assert!(d.mentions("unknown node 'ghost'"));
    assert!(d.0.len() >= 5, "{d}");
}

#[test]
fn pacing_is_validated_and_only_for_sources() {
    let d = problems(
        "nodes:\n  - {id: a, kind: count, pacing: {rate_hz: -1}}\n  - {id: b, kind: record, params: {name: x}, pacing: {speed: 1}}\nedges:\n  - {from: a.out, to: b.in}\n",
    );
    assert!(
        d.mentions("rate_hz must be from 0.000001 to 1000000000, got -1"),
        "{d}"
    );
    assert!(d.mentions("only sources are paced"));
}

#[test]
fn set_overrides_parameters_and_rejects_unknown_nodes() {
    let yaml = "nodes:\n  - {id: a, kind: count, params: {count: 3}}\n  - {id: b, kind: record, params: {name: x}}\nedges:\n  - {from: a.out, to: b.in}\n";
    let overrides = vec![
        Override::parse("a.count=7").unwrap(),
        Override::parse("a.pacing.rate_hz=12").unwrap(),
    ];
    let graph = resolve(yaml, "g.yaml", &registry(), &overrides).unwrap();
    assert_eq!(graph.spec.nodes[0].params["count"], 7);
    assert_eq!(
        graph.spec.nodes[0].pacing,
        bevworld_graph::Pacing::Fixed { rate_hz: 12.0 }
    );

    let bad = resolve(
        yaml,
        "g.yaml",
        &registry(),
        &[Override::parse("c.count=1").unwrap()],
    )
    .err()
    .unwrap();
    assert!(bad.mentions("--set names node 'c'"));
    // A name without a dot is a parameter the graph exposes; this one exposes none.
    let unexposed = resolve(
        yaml,
        "g.yaml",
        &registry(),
        &[Override::parse("count=1").unwrap()],
    )
    .err()
    .unwrap();
    assert!(
        unexposed.mentions("the graph exposes no parameter 'count'"),
        "{unexposed}"
    );
    assert!(Override::parse("no-name=1").is_err());
    assert!(Override::parse("a.count").is_err());
    assert!(Override::parse("models.tiny=1").is_err());
}

#[test]
fn check_listing_shows_resolved_defaults() {
    let yaml = "nodes:\n  - {id: a, kind: count}\n  - {id: t, kind: text_sink}\n  - {id: b, kind: record, params: {name: x}}\nedges:\n  - {from: a.out, to: b.in}\n";
    // text_sink's input is unconnected: fix by giving it nothing else to complain about.
    let yaml = yaml.replace("  - {id: t, kind: text_sink}\n", "");
    let graph = resolve(&yaml, "g.yaml", &registry(), &[]).unwrap();
    let listing = graph.spec.describe();
    assert!(listing.contains("\"step_us\":1"), "{listing}");
    assert!(
        listing.contains("edge a.out -> b.in [Counted, capacity 16, block]"),
        "{listing}"
    );
    let dot = bevworld_graph::dot::to_dot(&graph.spec);
    assert!(dot.contains("\"a\" -> \"b\""));
}

#[test]
fn validation_builds_nothing_and_building_reports_at_the_parameter() {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use bevworld_graph::{KindSpec, Node, ParamError, validate};
    use serde::{Deserialize, Serialize};

    static BUILT: AtomicUsize = AtomicUsize::new(0);

    #[derive(Deserialize, Serialize)]
    #[serde(deny_unknown_fields)]
    struct LoaderParams {
        weights: String,
    }

    let mut registry = registry();
    registry.register(
        KindSpec::sink("loader", "loads a file when built").input(common::IN.spec()),
        |params: LoaderParams| {
            BUILT.fetch_add(1, Ordering::SeqCst);
            if params.weights == "broken.bpk" {
                return Err(ParamError::field("weights", "does not fit the model"));
            }
            Ok(Node::Sink(Box::new(common::Discard)))
        },
    );
    let yaml = |weights: &str| {
        format!(
            "nodes:\n  - {{id: s, kind: count}}\n  - id: l\n    kind: loader\n    params:\n      weights: {weights}\nedges:\n  - {{from: s.out, to: l.in}}\n"
        )
    };
    let good = validate(&yaml("good.bpk"), "g.yaml", &registry, &[]).expect("valid");
    assert_eq!(BUILT.load(Ordering::SeqCst), 0, "validation built a node");
    assert_eq!(good.spec.nodes[1].params["weights"], "good.bpk");
    good.build().expect("builds");
    assert_eq!(BUILT.load(Ordering::SeqCst), 1);

    let broken = validate(&yaml("broken.bpk"), "g.yaml", &registry, &[]).expect("valid");
    let problems = match broken.build() {
        Err(problems) => problems,
        Ok(_) => panic!("a node that cannot be built was accepted"),
    };
    let d = only(&problems);
    assert!(
        d.message.contains("'weights' of node 'l'") && d.message.contains("does not fit"),
        "{d}"
    );
    assert_eq!(line_col(d).0, 6, "{d}");
}

fn problems_with(yaml: &str, set: &[&str]) -> Diagnostics {
    let overrides: Vec<Override> = set
        .iter()
        .map(|s| Override::parse(s).expect("override"))
        .collect();
    match resolve(yaml, "g.yaml", &registry(), &overrides) {
        Ok(_) => panic!("expected validation errors for {set:?}"),
        Err(diagnostics) => diagnostics,
    }
}

const CHAIN: &str = "nodes:\n  - {id: a, kind: count, params: {count: 3}}\n  - {id: b, kind: record, params: {name: x}}\nedges:\n  - {from: a.out, to: b.in}\n";

#[test]
fn a_capacity_is_bounded_and_a_bad_default_is_said_once_with_its_line() {
    let yaml = "settings:\n  default_capacity: 0\nnodes:\n  - {id: a, kind: count, params: {count: 3}}\n  - {id: b, kind: record, params: {name: x}}\n  - {id: c, kind: record, params: {name: z}}\nedges:\n  - {from: a.out, to: b.in}\n  - {from: a.out, to: c.in}\n";
    let d = problems(yaml);
    let d = only(&d);
    assert!(d.message.contains("default_capacity 0"), "{d}");
    assert_eq!(line_col(d).0, 2);
    let d = problems(
        "nodes:\n  - {id: a, kind: count, params: {count: 3}}\n  - {id: b, kind: record, params: {name: x}}\nedges:\n  - {from: a.out, to: b.in, capacity: 99999999999}\n",
    );
    let d = only(&d);
    assert!(
        d.message.contains("99999999999") && d.hint.as_deref().unwrap_or("").contains("100000"),
        "{d}"
    );
    assert_eq!(line_col(d).0, 5);
}

#[test]
fn rates_and_speeds_must_convert_to_a_clock_time() {
    for pacing in [
        "{rate_hz: 1e-300}",
        "{speed: 1e-300}",
        "{rate_hz: 1e300}",
        "{speed: -1}",
    ] {
        let yaml = format!(
            "nodes:\n  - {{id: a, kind: count, params: {{count: 3}}, pacing: {pacing}}}\n  - {{id: b, kind: record, params: {{name: x}}}}\nedges:\n  - {{from: a.out, to: b.in}}\n"
        );
        let d = problems(&yaml);
        assert!(only(&d).message.contains("pacing"), "{pacing}: {d}");
    }
    assert!(
        resolve(
            CHAIN,
            "g.yaml",
            &registry(),
            &[Override::parse("a.pacing.rate_hz=12").unwrap()]
        )
        .is_ok()
    );
}

#[test]
fn a_set_goes_through_the_same_checks_as_the_file() {
    // Not a number: said, never ignored.
    let d = problems_with(CHAIN, &["a.pacing.rate_hz=abc"]);
    assert!(
        only(&d).message.contains("'\"abc\"' is not a number") || only(&d).message.contains("abc"),
        "{d}"
    );
    // A task is not paced, from the file or from --set.
    let d = problems_with(CHAIN, &["b.pacing.rate_hz=3"]);
    assert!(only(&d).message.contains("only sources are paced"), "{d}");
    let d = problems_with(CHAIN, &["a.pacing.rate_hz=1e-300"]);
    assert!(only(&d).message.contains("rate_hz"), "{d}");
}

#[test]
fn the_same_edge_twice_is_refused_at_the_second() {
    let d = problems(
        "nodes:\n  - {id: a, kind: count}\n  - {id: r, kind: record, params: {name: x}}\nedges:\n  - {from: a.out, to: r.in}\n  - {from: a.out, to: r.in}\n",
    );
    let d = only(&d);
    assert!(d.message.contains("a.out -> r.in is written twice"), "{d}");
    assert_eq!(line_col(d).0, 6);
}

#[test]
fn a_set_parses_its_value_as_the_file_does() {
    // The file refuses a non-finite number; so does --set, in the same words, rather than
    // reading `.nan` as text.
    let in_file = problems("nodes:\n  - {id: t, kind: text_sink, params: {scale: .nan}}\n");
    assert!(in_file.mentions("non-finite"), "{in_file}");
    for value in [".nan", "[.nan]", "-.inf", "[1, .inf]"] {
        let error = Override::parse(&format!("t.scale={value}")).unwrap_err();
        assert!(error.to_string().contains("non-finite"), "{value}: {error}");
    }
    // Text that is not YAML stays the text typed.
    let text = Override::parse("t.name=[unclosed").unwrap();
    assert_eq!(text.value, serde_json::json!("[unclosed"));
}

#[test]
fn a_graph_rule_reports_at_the_parameter_it_names() {
    let mut registry = registry();
    registry.rule(|graph| {
        graph
            .nodes
            .iter()
            .filter(|n| n.kind.name == "record" && n.params["name"] == "forbidden")
            .map(|n| bevworld_graph::RuleProblem {
                node: n.id.clone(),
                error: bevworld_graph::ParamError::field("name", "is forbidden by a rule"),
            })
            .collect()
    });
    let yaml = "nodes:\n  - {id: a, kind: count}\n  - id: r\n    kind: record\n    params:\n      name: forbidden\nedges:\n  - {from: a.out, to: r.in}\n";
    let d = match resolve(yaml, "g.yaml", &registry, &[]) {
        Ok(_) => panic!("the rule must refuse it"),
        Err(d) => d,
    };
    let d = only(&d);
    assert!(
        d.message.contains("bad parameter 'name' of node 'r'"),
        "{d}"
    );
    assert!(d.message.contains("forbidden by a rule"), "{d}");
    assert_eq!(line_col(d).0, 6);
    let fine = yaml.replace("forbidden", "allowed");
    assert!(resolve(&fine, "g.yaml", &registry, &[]).is_ok());
}
