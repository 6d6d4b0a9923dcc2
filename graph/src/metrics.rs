//! Per-node metrics: items in and out, service latency percentiles, deepest input queue, drops
//! and skips. Printed as a table at the end of a run, or written as JSON.

use std::fmt::Write as _;
use std::time::Duration;

use serde::Serialize;

/// A log-linear latency histogram in fixed memory: 16 sub-buckets per power of two of
/// nanoseconds, so a percentile is within about 6% of the true value whatever the run length.
#[derive(Clone, Debug)]
pub struct LatencyHistogram {
    counts: Vec<u64>,
    total: u64,
    max_ns: u64,
}

const SUB_BUCKET_BITS: u32 = 4;
const SUB_BUCKETS: u64 = 1 << SUB_BUCKET_BITS;
const BUCKETS: usize = (64 - SUB_BUCKET_BITS as usize + 1) * SUB_BUCKETS as usize;

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            counts: vec![0; BUCKETS],
            total: 0,
            max_ns: 0,
        }
    }
}

impl LatencyHistogram {
    fn bucket_of(ns: u64) -> usize {
        if ns < SUB_BUCKETS {
            return ns as usize;
        }
        let magnitude = 63 - ns.leading_zeros(); // >= SUB_BUCKET_BITS
        let shift = magnitude - SUB_BUCKET_BITS;
        let sub = (ns >> shift) - SUB_BUCKETS; // in [0, SUB_BUCKETS)
        ((shift as u64 + 1) * SUB_BUCKETS + sub) as usize
    }

    /// The upper bound of a bucket's values, so reported percentiles never under-state.
    fn bucket_upper(index: usize) -> u64 {
        let index = index as u64;
        if index < SUB_BUCKETS {
            return index;
        }
        let shift = index / SUB_BUCKETS - 1;
        let sub = index % SUB_BUCKETS;
        let upper = (u128::from(SUB_BUCKETS + sub + 1) << shift) - 1;
        u64::try_from(upper).unwrap_or(u64::MAX)
    }

    pub fn record(&mut self, duration: Duration) {
        let ns = u64::try_from(duration.as_nanos()).unwrap_or(u64::MAX);
        self.record_ns(ns);
    }

    pub fn record_ns(&mut self, ns: u64) {
        let bucket = Self::bucket_of(ns).min(BUCKETS - 1);
        self.counts[bucket] += 1;
        self.total += 1;
        self.max_ns = self.max_ns.max(ns);
    }

    pub fn count(&self) -> u64 {
        self.total
    }

    pub fn max_ns(&self) -> u64 {
        self.max_ns
    }

    /// The q-quantile (0..=1) in nanoseconds; 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        if self.total == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (index, count) in self.counts.iter().enumerate() {
            seen += count;
            if seen >= rank {
                return Self::bucket_upper(index).min(self.max_ns);
            }
        }
        self.max_ns
    }

    pub fn merge(&mut self, other: &LatencyHistogram) {
        for (mine, theirs) in self.counts.iter_mut().zip(&other.counts) {
            *mine += theirs;
        }
        self.total += other.total;
        self.max_ns = self.max_ns.max(other.max_ns);
    }
}

/// What one node did during a run.
#[derive(Clone, Debug, Serialize)]
pub struct NodeReport {
    pub id: String,
    pub kind: String,
    pub role: &'static str,
    pub items_in: u64,
    pub items_out: u64,
    /// Time spent in the node's own `next`/`process`/`consume` per call.
    pub latency_p50_us: f64,
    pub latency_p99_us: f64,
    pub latency_max_us: f64,
    /// Time from entering the graph to arriving here (sinks and tasks).
    pub age_p50_us: f64,
    pub age_p99_us: f64,
    /// Deepest queue seen on any of its inputs.
    pub max_queue_depth: usize,
    /// Items evicted on its input edges by `drop_oldest`/`latest`.
    pub drops: u64,
    /// Items left unmatched by its timestamp aligner.
    pub unaligned: u64,
    /// Bad input items skipped under `on_error: skip`.
    pub skips: u64,
    /// Extra figures a node reports (PSNR, Chamfer, pillar counts), by name.
    pub extra: std::collections::BTreeMap<String, f64>,
    /// Why the node made nothing of what it received, when it says (`Task::nothing_made`,
    /// `Sink::nothing_made`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nothing_made: Option<String>,
    /// The node reached its end: a source its last item or a drain, a task or sink its
    /// `finish` (buffers flushed, files closed). False after an abort cut it short.
    pub finished: bool,
    #[serde(skip)]
    pub latency: LatencyHistogram,
    #[serde(skip)]
    pub age: LatencyHistogram,
}

impl NodeReport {
    pub(crate) fn new(id: &str, kind: &str, role: &'static str) -> Self {
        Self {
            id: id.to_string(),
            kind: kind.to_string(),
            role,
            items_in: 0,
            items_out: 0,
            latency_p50_us: 0.0,
            latency_p99_us: 0.0,
            latency_max_us: 0.0,
            age_p50_us: 0.0,
            age_p99_us: 0.0,
            max_queue_depth: 0,
            drops: 0,
            unaligned: 0,
            skips: 0,
            extra: Default::default(),
            nothing_made: None,
            finished: false,
            latency: LatencyHistogram::default(),
            age: LatencyHistogram::default(),
        }
    }

    /// Fills the percentile fields from the histograms.
    pub(crate) fn summarise(&mut self) {
        let us = |ns: u64| ns as f64 / 1000.0;
        self.latency_p50_us = us(self.latency.quantile_ns(0.50));
        self.latency_p99_us = us(self.latency.quantile_ns(0.99));
        self.latency_max_us = us(self.latency.max_ns());
        self.age_p50_us = us(self.age.quantile_ns(0.50));
        self.age_p99_us = us(self.age.quantile_ns(0.99));
    }
}

/// One edge's counters at the end of a run.
#[derive(Clone, Debug, Serialize)]
pub struct EdgeReport {
    pub from: String,
    pub to: String,
    pub policy: &'static str,
    pub capacity: usize,
    pub sent: u64,
    pub dropped: u64,
}

/// The whole run.
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    pub graph: String,
    pub wall_seconds: f64,
    /// Why the run ended: "completed", "drained" (Ctrl-C or SIGTERM), "aborted: …" (a second
    /// Ctrl-C, naming the nodes that did not finish) or "failed: …".
    pub outcome: String,
    pub nodes: Vec<NodeReport>,
    pub edges: Vec<EdgeReport>,
}

impl RunReport {
    pub fn node(&self, id: &str) -> Option<&NodeReport> {
        self.nodes.iter().find(|node| node.id == id)
    }

    /// A fixed-width table for the terminal.
    pub fn table(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{:<14} {:<16} {:>8} {:>8} {:>10} {:>10} {:>10} {:>6} {:>7} {:>6}",
            "node", "kind", "in", "out", "p50 µs", "p99 µs", "max µs", "queue", "drops", "skips"
        );
        for node in &self.nodes {
            let _ = writeln!(
                out,
                "{:<14} {:<16} {:>8} {:>8} {:>10.1} {:>10.1} {:>10.1} {:>6} {:>7} {:>6}",
                truncate(&node.id, 14),
                truncate(&node.kind, 16),
                node.items_in,
                node.items_out,
                node.latency_p50_us,
                node.latency_p99_us,
                node.latency_max_us,
                node.max_queue_depth,
                node.drops + node.unaligned,
                node.skips
            );
            for (name, value) in &node.extra {
                let _ = writeln!(out, "{:<14}   {name} = {value:.4}", "");
            }
        }
        let _ = writeln!(out, "{} in {:.3} s", self.outcome, self.wall_seconds);
        out
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self)
            .unwrap_or_else(|error| format!("{{\"error\": \"{error}\"}}"))
    }
}

fn truncate(text: &str, width: usize) -> String {
    if text.chars().count() <= width {
        text.to_string()
    } else {
        let mut cut: String = text.chars().take(width.saturating_sub(1)).collect();
        cut.push('…');
        cut
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_within_bucket_precision() {
        let mut histogram = LatencyHistogram::default();
        for ns in 1..=10_000u64 {
            histogram.record_ns(ns * 100);
        }
        let p50 = histogram.quantile_ns(0.5) as f64;
        let p99 = histogram.quantile_ns(0.99) as f64;
        assert!((p50 - 500_000.0).abs() / 500_000.0 < 0.07, "p50 {p50}");
        assert!((p99 - 990_000.0).abs() / 990_000.0 < 0.07, "p99 {p99}");
        assert_eq!(histogram.max_ns(), 1_000_000);
        assert_eq!(histogram.quantile_ns(1.0), 1_000_000);
    }

    #[test]
    fn small_values_are_exact_and_empty_is_zero() {
        let mut histogram = LatencyHistogram::default();
        assert_eq!(histogram.quantile_ns(0.5), 0);
        for ns in [3, 3, 3, 7] {
            histogram.record_ns(ns);
        }
        assert_eq!(histogram.quantile_ns(0.5), 3);
        assert_eq!(histogram.quantile_ns(1.0), 7);
    }

    #[test]
    fn every_bucket_upper_bound_contains_its_values() {
        for ns in (0..200_000u64).step_by(7).chain([u64::MAX / 2, u64::MAX]) {
            let bucket = LatencyHistogram::bucket_of(ns);
            assert!(bucket < BUCKETS);
            assert!(LatencyHistogram::bucket_upper(bucket) >= ns, "ns {ns}");
        }
    }
}
