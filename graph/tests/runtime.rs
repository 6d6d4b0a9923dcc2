//! The runtime's guarantees: lossless backpressure, exact drop counting, bounded-time failure,
//! fan-out and fan-in without deadlock, skipping, and draining.

mod common;

use std::time::{Duration, Instant};

use bevworld_graph::{RunError, RunOptions, StopHandle, resolve, run};
use common::{recorded, registry};

fn run_yaml(yaml: &str) -> bevworld_graph::RunOutcome {
    let graph = resolve(yaml, "test.yaml", &registry(), &[]).unwrap_or_else(|d| panic!("{d}"));
    run(graph, RunOptions::default())
}

/// `run_yaml` on another thread; a run that has not returned after `HUNG` has hung. The limit
/// only tells a hang from a slow machine: the test's own assertions are about what happened,
/// never about how long it took.
fn run_yaml_or_hang(yaml: &'static str) -> bevworld_graph::RunOutcome {
    const HUNG: Duration = Duration::from_secs(120);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(run_yaml(yaml));
    });
    rx.recv_timeout(HUNG)
        .unwrap_or_else(|_| panic!("the run did not return within {HUNG:?}: it hung"))
}

#[test]
fn block_delivers_every_item_in_order_with_bounded_memory() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 300}}
  - {id: slow, kind: record, params: {name: block_slow, sleep_us: 200}}
edges:
  - {from: src.out, to: slow.in, capacity: 4, policy: block}
"#,
    );
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    assert_eq!(recorded("block_slow"), (0..300).collect::<Vec<u64>>());
    let sink = outcome.report.node("slow").unwrap();
    assert_eq!(sink.items_in, 300);
    assert_eq!(sink.drops, 0);
    assert!(
        sink.max_queue_depth <= 5,
        "queue depth {}",
        sink.max_queue_depth
    );
}

#[test]
fn drop_oldest_counts_exactly_the_items_not_delivered() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 2000}}
  - {id: slow, kind: record, params: {name: drop_slow, sleep_us: 300}}
edges:
  - {from: src.out, to: slow.in, capacity: 2, policy: drop_oldest}
"#,
    );
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    let delivered = recorded("drop_slow");
    let sink = outcome.report.node("slow").unwrap();
    assert!(sink.drops > 0, "an overloaded edge must drop");
    assert_eq!(delivered.len() as u64 + sink.drops, 2000);
    assert_eq!(outcome.report.edges[0].dropped, sink.drops);
    assert!(
        delivered.windows(2).all(|w| w[0] < w[1]),
        "drops keep order"
    );
    // The newest item always survives: it is never evicted by a later one.
    assert_eq!(delivered.last(), Some(&1999));
}

#[test]
fn latest_keeps_only_the_newest() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 500}}
  - {id: slow, kind: record, params: {name: latest_slow, sleep_us: 500}}
edges:
  - {from: src.out, to: slow.in, capacity: 16, policy: latest}
"#,
    );
    let delivered = recorded("latest_slow");
    assert_eq!(outcome.report.edges[0].capacity, 1);
    assert_eq!(
        delivered.len() as u64 + outcome.report.node("slow").unwrap().drops,
        500
    );
    assert_eq!(delivered.last(), Some(&499));
}

#[test]
fn an_error_stops_an_endless_graph_in_bounded_time_and_names_the_node() {
    let outcome = run_yaml_or_hang(
        r#"
nodes:
  - {id: src, kind: count}
  - {id: picky, kind: pass, params: {fail_at: 50}}
  - {id: out, kind: record, params: {name: error_out}}
edges:
  - {from: src.out, to: picky.in, capacity: 2}
  - {from: picky.out, to: out.in, capacity: 2}
"#,
    );
    match outcome.error {
        Some(RunError::NodeFailed { node, cause, .. }) => {
            assert_eq!(node, "picky");
            assert!(cause.contains("refused item 50"), "{cause}");
        }
        other => panic!("expected NodeFailed, got {other:?}"),
    }
    assert_eq!(recorded("error_out"), (0..50).collect::<Vec<u64>>());
}

#[test]
fn a_panic_stops_the_graph_and_is_reported() {
    let outcome = run_yaml_or_hang(
        r#"
nodes:
  - {id: src, kind: count}
  - {id: fragile, kind: pass, params: {panic_at: 10}}
  - {id: out, kind: record, params: {name: panic_out}}
edges:
  - {from: src.out, to: fragile.in, capacity: 1}
  - {from: fragile.out, to: out.in, capacity: 1}
"#,
    );
    match outcome.error {
        Some(RunError::NodePanicked { node, cause, .. }) => {
            assert_eq!(node, "fragile");
            assert!(cause.contains("boom at item 10"));
        }
        other => panic!("expected NodePanicked, got {other:?}"),
    }
}

#[test]
fn a_node_stuck_in_compute_does_not_hang_the_run() {
    let outcome = run_yaml_or_hang(
        r#"
settings: {shutdown_grace_ms: 300}
nodes:
  - {id: src, kind: count}
  - {id: stuck, kind: pass, params: {stall_at: 3}}
  - {id: picky, kind: pass, params: {fail_at: 1}}
  - {id: a, kind: record, params: {name: stuck_a}}
  - {id: b, kind: record, params: {name: stuck_b}}
edges:
  - {from: src.out, to: stuck.in}
  - {from: src.out, to: picky.in}
  - {from: stuck.out, to: a.in}
  - {from: picky.out, to: b.in}
"#,
    );
    assert!(
        matches!(outcome.error, Some(RunError::NodeFailed { ref node, .. }) if node == "picky"),
        "{:?}",
        outcome.error
    );
    // The run returned while `stuck` was still asleep in its 30-second stall: its thread never
    // reported (nor did `a`, parked on `stuck`'s edge), and the others did.
    assert!(
        outcome.report.node("stuck").is_none(),
        "the run waited for the stuck node"
    );
    for id in ["src", "picky", "b"] {
        assert!(outcome.report.node(id).is_some(), "{id} did not report");
    }
}

#[test]
fn fan_out_and_fan_in_do_not_deadlock() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 500}}
  - {id: a, kind: pass}
  - {id: b, kind: pass, params: {sleep_us: 20}}
  - {id: join, kind: join}
  - {id: out, kind: record, params: {name: fan_out}}
  - {id: tap, kind: record, params: {name: fan_tap}}
edges:
  - {from: src.out, to: a.in, capacity: 1}
  - {from: src.out, to: b.in, capacity: 1}
  - {from: src.out, to: tap.in, capacity: 1}
  - {from: a.out, to: join.left, capacity: 1}
  - {from: b.out, to: join.right, capacity: 1}
  - {from: join.out, to: out.in, capacity: 1}
"#,
    );
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    let joined = recorded("fan_out");
    assert_eq!(joined, (0..500).map(|v| v * 1000 + v).collect::<Vec<u64>>());
    assert_eq!(recorded("fan_tap").len(), 500);
}

#[test]
fn several_edges_into_one_port_merge() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: s1, kind: count, params: {count: 100}}
  - {id: s2, kind: count, params: {count: 150}}
  - {id: out, kind: record, params: {name: merge_out}}
edges:
  - {from: s1.out, to: out.in, capacity: 2}
  - {from: s2.out, to: out.in, capacity: 2}
"#,
    );
    assert!(outcome.error.is_none());
    assert_eq!(recorded("merge_out").len(), 250);
}

#[test]
fn aligner_pairs_streams_within_tolerance() {
    // Left at 0, 100, 200, ...; right at 30, 130, 230, ... with one fewer item.
    let outcome = run_yaml(
        r#"
nodes:
  - {id: cam, kind: count, params: {count: 20, step_us: 100}}
  - {id: lidar, kind: count, params: {count: 19, step_us: 100, offset_us: 30}}
  - {id: join, kind: join, align_tolerance_us: 40}
  - {id: out, kind: record, params: {name: align_out}}
edges:
  - {from: cam.out, to: join.left}
  - {from: lidar.out, to: join.right}
  - {from: join.out, to: out.in}
"#,
    );
    assert!(outcome.error.is_none());
    assert_eq!(
        recorded("align_out"),
        (0..19).map(|v| v * 1000 + v).collect::<Vec<u64>>()
    );
    assert_eq!(outcome.report.node("join").unwrap().unaligned, 1);
}

#[test]
fn skip_counts_bad_items_and_the_rest_flows_on() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 30}}
  - {id: picky, kind: pass, on_error: skip, params: {reject_every: 3}}
  - {id: out, kind: record, params: {name: skip_out}}
edges:
  - {from: src.out, to: picky.in}
  - {from: picky.out, to: out.in}
"#,
    );
    assert!(outcome.error.is_none());
    assert_eq!(outcome.report.node("picky").unwrap().skips, 10);
    assert_eq!(
        recorded("skip_out"),
        (0..30).filter(|v| v % 3 != 0).collect::<Vec<u64>>()
    );
}

#[test]
fn bad_item_under_stop_ends_the_run() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 30}}
  - {id: picky, kind: pass, params: {reject_every: 7}}
  - {id: out, kind: record, params: {name: stop_out}}
edges:
  - {from: src.out, to: picky.in}
  - {from: picky.out, to: out.in}
"#,
    );
    assert!(
        matches!(outcome.error, Some(RunError::NodeFailed { ref cause, .. }) if cause.contains("item 0 is bad"))
    );
}

#[test]
fn drain_stops_sources_and_loses_nothing_in_flight() {
    let graph = resolve(
        r#"
nodes:
  - {id: src, kind: count, pacing: {rate_hz: 2000}}
  - {id: slow, kind: pass, params: {sleep_us: 500}}
  - {id: out, kind: record, params: {name: drain_out}}
edges:
  - {from: src.out, to: slow.in, capacity: 8}
  - {from: slow.out, to: out.in, capacity: 8}
"#,
        "test.yaml",
        &registry(),
        &[],
    )
    .unwrap();
    let stop = StopHandle::new();
    let trigger = stop.clone();
    std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(150));
        trigger.drain();
    });
    let outcome = run(
        graph,
        RunOptions {
            stop,
            observer: None,
        },
    );
    assert!(outcome.error.is_none());
    assert_eq!(outcome.report.outcome, "drained");
    let produced = outcome.report.node("src").unwrap().items_out;
    assert!(produced > 10);
    assert_eq!(
        recorded("drain_out").len() as u64,
        produced,
        "every produced item reaches the sink"
    );
}

#[test]
fn fixed_rate_pacing_holds_the_rate() {
    let started = Instant::now();
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 13}, pacing: {rate_hz: 60}}
  - {id: out, kind: record, params: {name: paced_out}}
edges:
  - {from: src.out, to: out.in}
"#,
    );
    assert!(outcome.error.is_none());
    // 13 items at 60 Hz: the last is released 12/60 s = 200 ms after the first. The upper
    // bound is loose for a loaded machine, and a rate misread by ten (2 s) still fails it.
    let elapsed = started.elapsed();
    assert!(
        elapsed >= Duration::from_millis(195) && elapsed < Duration::from_millis(1200),
        "{elapsed:?}"
    );
}

#[test]
fn fan_out_shares_payloads_instead_of_copying() {
    // One output read by two sinks: each item reaches both as the one allocation the source
    // made (the sinks hold every payload, so no address is reused in between).
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 6}}
  - {id: a, kind: record, params: {name: fan_a, keep: true}}
  - {id: b, kind: record, params: {name: fan_b, keep: true}}
edges:
  - {from: src.out, to: a.in}
  - {from: src.out, to: b.in}
"#,
    );
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    let (a, b) = (common::kept("fan_a"), common::kept("fan_b"));
    assert_eq!(a.len(), 6);
    assert_eq!(b.len(), 6);
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.value, y.value);
        assert!(
            std::sync::Arc::ptr_eq(x, y),
            "item {} was copied on the way to the second sink",
            x.value
        );
    }
}

#[test]
fn a_run_that_makes_nothing_is_an_error_naming_why() {
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 0}}
  - {id: out, kind: record, params: {name: nothing_out}}
edges:
  - {from: src.out, to: out.in}
"#,
    );
    match &outcome.error {
        Some(RunError::NothingDone(why)) => assert!(why.contains("no items"), "{why}"),
        other => panic!("{other:?}"),
    }
    // Every item skipped by a node is nothing done too.
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 6}}
  - {id: picky, kind: pass, on_error: skip, params: {reject_every: 1}}
  - {id: out, kind: record, params: {name: all_skipped_out}}
edges:
  - {from: src.out, to: picky.in}
  - {from: picky.out, to: out.in}
"#,
    );
    match &outcome.error {
        Some(RunError::NothingDone(why)) => {
            assert!(why.contains("'picky'") && why.contains("all 6"), "{why}")
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_run_whose_sinks_receive_nothing_fails_naming_the_node_that_held_the_stream_and_why() {
    // Two items, a window of three: the source produced, but no sink was given anything.
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 2}}
  - {id: relay, kind: pass}
  - {id: history, kind: window, params: {size: 3}}
  - {id: out, kind: record, params: {name: starved_out}}
edges:
  - {from: src.out, to: relay.in}
  - {from: relay.out, to: history.in}
  - {from: history.out, to: out.in}
"#,
    );
    match &outcome.error {
        Some(RunError::NothingDone(why)) => assert!(
            why.contains("'history' (window) received 2 item(s)")
                && why.contains("a window needs 3 items, it got 2"),
            "{why}"
        ),
        other => panic!("{other:?}"),
    }
    assert!(recorded("starved_out").is_empty());
    // Three items fill the window: the sink gets one, and the run succeeds.
    let outcome = run_yaml(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 3}}
  - {id: history, kind: window, params: {size: 3}}
  - {id: out, kind: record, params: {name: fed_out}}
edges:
  - {from: src.out, to: history.in}
  - {from: history.out, to: out.in}
"#,
    );
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    assert_eq!(recorded("fed_out"), vec![3]);
}

#[test]
fn an_abort_names_the_nodes_that_did_not_finish() {
    let graph = resolve(
        r#"
nodes:
  - {id: src, kind: count}
  - {id: slow, kind: record, params: {name: abort_out, sleep_us: 20000}}
edges:
  - {from: src.out, to: slow.in}
"#,
        "test.yaml",
        &registry(),
        &[],
    )
    .unwrap_or_else(|d| panic!("{d}"));
    let stop = StopHandle::new();
    let aborter = stop.clone();
    std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(200));
        aborter.abort();
    });
    let outcome = run(
        graph,
        RunOptions {
            stop,
            observer: None,
        },
    );
    match &outcome.error {
        Some(RunError::Aborted { unfinished }) => {
            assert!(unfinished.contains(&"slow".to_string()), "{unfinished:?}")
        }
        other => panic!("{other:?}"),
    }
    assert!(
        outcome.report.outcome.starts_with("aborted"),
        "{}",
        outcome.report.outcome
    );
    assert!(!outcome.report.node("slow").unwrap().finished);
}
