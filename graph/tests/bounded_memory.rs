//! Backpressure bounds memory: with a slow sink, the number of live payloads stays near the
//! queue capacity however many items flow. Its own test binary, since the live-payload counter
//! is process-wide.

mod common;

use std::sync::atomic::Ordering;

use bevworld_graph::{RunOptions, resolve, run};
use common::{PEAK, recorded, registry};

#[test]
fn block_policy_keeps_live_payloads_near_capacity() {
    let graph = resolve(
        r#"
nodes:
  - {id: src, kind: count, params: {count: 2000}}
  - {id: mid, kind: pass}
  - {id: slow, kind: record, params: {name: memory_slow, sleep_us: 50}}
edges:
  - {from: src.out, to: mid.in, capacity: 4, policy: block}
  - {from: mid.out, to: slow.in, capacity: 4, policy: block}
"#,
        "memory.yaml",
        &registry(),
        &[],
    )
    .unwrap();
    let outcome = run(graph, RunOptions::default());
    assert!(outcome.error.is_none());
    assert_eq!(recorded("memory_slow").len(), 2000);
    // Two queues of 4, plus at most one item held by each of the three nodes.
    let peak = PEAK.load(Ordering::SeqCst);
    assert!(peak <= 4 + 4 + 3, "peak live payloads {peak}");
}
