//! Runs a resolved graph: one thread per node, one bounded channel per edge.
//!
//! Shutdown has two speeds:
//! - **drain** (a source ended, or Ctrl-C): sources stop producing, everything already in the
//!   graph flows on to the sinks, and each node finishes once all its inputs have closed;
//! - **abort** (a node failed or panicked): every blocked send and receive wakes at once and
//!   nodes return without finishing. Nodes stuck in their own compute are waited for up to the
//!   grace period and then reported as hung, so a run never hangs.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::message::Instant as Clock;

use crossbeam_channel::{Receiver, RecvTimeoutError, Select, Sender, TryRecvError, bounded};
use tracing::{debug, info_span, warn};

use crate::align::Aligner;
use crate::error::{NodeError, RunError};
use crate::message::Message;
use crate::metrics::{EdgeReport, NodeReport, RunReport};
use crate::node::{Inputs, Node, Outputs, Sink, Source, Task};
use crate::pacing::{Pacer, Pacing};
use crate::policy::{EdgeCounters, EdgeSender};
use crate::schema::{OnError, SyncMode};
use crate::validate::ResolvedGraph;

/// Stops a running graph from another thread (a Ctrl-C handler, a test).
#[derive(Clone)]
pub struct StopHandle {
    drain: Arc<AtomicBool>,
    abort_tx: Arc<Mutex<Option<Sender<()>>>>,
    abort_rx: Receiver<()>,
}

impl Default for StopHandle {
    fn default() -> Self {
        let (tx, rx) = bounded(0);
        Self {
            drain: Arc::new(AtomicBool::new(false)),
            abort_tx: Arc::new(Mutex::new(Some(tx))),
            abort_rx: rx,
        }
    }
}

impl StopHandle {
    pub fn new() -> Self {
        Self::default()
    }

    /// Sources stop producing; in-flight items still reach the sinks.
    pub fn drain(&self) {
        self.drain.store(true, Ordering::SeqCst);
    }

    pub fn is_draining(&self) -> bool {
        self.drain.load(Ordering::SeqCst)
    }

    /// Wakes every blocked node and stops the graph now.
    pub fn abort(&self) {
        self.drain();
        let mut guard = match self.abort_tx.lock() {
            Ok(guard) => guard,
            Err(poisoned) => poisoned.into_inner(),
        };
        // Dropping the only sender disconnects the channel: every select on it fires.
        guard.take();
    }

    pub fn is_aborted(&self) -> bool {
        matches!(self.abort_rx.try_recv(), Err(TryRecvError::Disconnected))
    }
}

/// Options that are not part of the graph file.
#[derive(Clone, Default)]
pub struct RunOptions {
    pub stop: StopHandle,
    /// Show the progress bar (also needs `settings.progress` and a terminal).
    pub progress: bool,
}

/// A finished run: its metrics, and its error if it failed.
pub struct RunOutcome {
    pub report: RunReport,
    pub error: Option<RunError>,
}

struct Shared {
    stop: StopHandle,
    failures: Mutex<Vec<RunError>>,
    progress: indicatif::ProgressBar,
}

impl Shared {
    fn fail(&self, error: RunError) {
        warn!("{error}");
        if let Ok(mut failures) = self.failures.lock() {
            failures.push(error);
        }
        self.stop.abort();
    }
}

/// Who a node is, for error messages and the skip rule.
struct Who {
    id: String,
    kind: &'static str,
    on_error: OnError,
}

struct NodeThread {
    who: Who,
    pacing: Pacing,
    sync: SyncMode,
    align_tolerance_us: i64,
    idle_spin: Duration,
    inputs: Vec<(usize, Receiver<Message>)>,
    input_ports: Arc<[&'static str]>,
    outputs: Outputs,
    report: NodeReport,
}

/// Runs the graph to completion (or failure) and returns its metrics.
pub fn run(graph: ResolvedGraph, options: RunOptions) -> RunOutcome {
    let started = Instant::now();
    let stop = options.stop.clone();
    let progress = if options.progress && graph.settings.progress {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {msg} [{bar:30}] {pos}/{len} items, {per_sec}, eta {eta}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message(graph.name.clone());
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let shared = Arc::new(Shared {
        stop: stop.clone(),
        failures: Mutex::new(Vec::new()),
        progress,
    });

    // Channels, one per edge.
    let node_count = graph.nodes.len();
    let mut senders: Vec<Vec<Vec<EdgeSender>>> = graph
        .nodes
        .iter()
        .map(|n| n.kind.outputs.iter().map(|_| Vec::new()).collect())
        .collect();
    let mut receivers: Vec<Vec<(usize, Receiver<Message>)>> = vec![Vec::new(); node_count];
    let mut edge_counters = Vec::new();
    for edge in &graph.edges {
        let (tx, rx) = bounded::<Message>(edge.capacity);
        let counters = Arc::new(EdgeCounters::default());
        let evict = matches!(
            edge.policy,
            crate::policy::EdgePolicy::DropOldest | crate::policy::EdgePolicy::Latest
        )
        .then(|| rx.clone());
        senders[edge.from_node][edge.from_port].push(EdgeSender {
            tx,
            evict,
            counters: Arc::clone(&counters),
            abort: stop.abort_rx.clone(),
        });
        receivers[edge.to_node].push((edge.to_port, rx));
        edge_counters.push(counters);
    }

    let node_ids: Vec<String> = graph.nodes.iter().map(|n| n.id.clone()).collect();
    let edge_labels: Vec<(String, String)> =
        graph.edges.iter().map(|e| graph.edge_label(e)).collect();
    let inbound: Vec<Vec<usize>> = (0..node_count)
        .map(|node| {
            graph
                .edges
                .iter()
                .enumerate()
                .filter(|(_, e)| e.to_node == node)
                .map(|(i, _)| i)
                .collect()
        })
        .collect();

    // One thread per node.
    let (done_tx, done_rx) = crossbeam_channel::unbounded::<(usize, NodeReport)>();
    let mut pending: Vec<Option<String>> = Vec::with_capacity(node_count);
    let mut startup_error = None;
    for (index, ((resolved, outputs), inputs)) in graph
        .nodes
        .into_iter()
        .zip(senders)
        .zip(receivers)
        .enumerate()
    {
        let output_ports: Arc<[&'static str]> =
            resolved.kind.outputs.iter().map(|p| p.name).collect();
        let input_ports: Arc<[&'static str]> =
            resolved.kind.inputs.iter().map(|p| p.name).collect();
        let is_source = matches!(resolved.node, Node::Source(_));
        let thread = NodeThread {
            report: NodeReport::new(
                &resolved.id,
                resolved.kind.name,
                resolved.kind.role.as_str(),
            ),
            who: Who {
                id: resolved.id.clone(),
                kind: resolved.kind.name,
                on_error: resolved.on_error,
            },
            pacing: resolved.pacing,
            sync: resolved.sync,
            align_tolerance_us: resolved.align_tolerance_us,
            idle_spin: Duration::from_micros(graph.settings.idle_spin_us),
            inputs,
            input_ports,
            outputs: Outputs::new(output_ports, outputs, is_source),
        };
        let node = resolved.node;
        let shared = Arc::clone(&shared);
        let done = done_tx.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("node:{}", resolved.id))
            .spawn(move || {
                let span = info_span!("node", id = %thread.who.id, kind = thread.who.kind);
                let _entered = span.enter();
                let report = run_node(thread, node, &shared);
                let _ = done.send((index, report));
            });
        match spawned {
            Ok(_) => pending.push(Some(resolved.id)),
            Err(error) => {
                startup_error = Some(RunError::Startup(format!(
                    "spawning node '{}': {error}",
                    resolved.id
                )));
                stop.abort();
                pending.push(None);
            }
        }
    }
    drop(done_tx);

    // Collect reports; after an abort, wait at most the grace period for the stragglers.
    let grace = Duration::from_millis(graph.settings.shutdown_grace_ms);
    let mut reports: Vec<Option<NodeReport>> = (0..node_count).map(|_| None).collect();
    let mut abort_seen: Option<Instant> = None;
    while pending.iter().any(Option::is_some) {
        let wait = match abort_seen {
            Some(at) => grace.saturating_sub(at.elapsed()),
            None => Duration::from_millis(50),
        };
        match done_rx.recv_timeout(wait) {
            Ok((index, report)) => {
                pending[index] = None;
                reports[index] = Some(report);
            }
            Err(RecvTimeoutError::Timeout) => {
                if abort_seen.is_none() && stop.is_aborted() {
                    abort_seen = Some(Instant::now());
                } else if abort_seen.is_some_and(|at| at.elapsed() >= grace) {
                    break;
                }
            }
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    shared.progress.finish_and_clear();
    let hung: Vec<String> = pending.into_iter().flatten().collect();

    let mut nodes: Vec<NodeReport> = reports.into_iter().flatten().collect();
    for report in &mut nodes {
        report.summarise();
    }
    // Attribute edge drops to the receiving node.
    let mut edges = Vec::new();
    for (edge_index, (edge, counters)) in graph.edges.iter().zip(&edge_counters).enumerate() {
        let dropped = counters.dropped.load(Ordering::Relaxed);
        edges.push(EdgeReport {
            from: edge_labels[edge_index].0.clone(),
            to: edge_labels[edge_index].1.clone(),
            policy: edge.policy.as_str(),
            capacity: edge.capacity,
            sent: counters.sent.load(Ordering::Relaxed),
            dropped,
        });
    }
    for (node_id, edge_indices) in node_ids.iter().zip(&inbound) {
        let dropped: u64 = edge_indices.iter().map(|&e| edges[e].dropped).sum();
        if let Some(report) = nodes.iter_mut().find(|r| &r.id == node_id) {
            report.drops = dropped;
        }
    }

    let mut failures = shared
        .failures
        .lock()
        .map(|mut f| std::mem::take(&mut *f))
        .unwrap_or_default();
    let error = if let Some(error) = startup_error {
        Some(error)
    } else if !failures.is_empty() {
        Some(failures.remove(0))
    } else if !hung.is_empty() {
        Some(RunError::Hung {
            nodes: hung.clone(),
            grace_ms: graph.settings.shutdown_grace_ms,
        })
    } else {
        None
    };
    if !hung.is_empty() {
        warn!(
            "nodes still running after {} ms: {hung:?}",
            graph.settings.shutdown_grace_ms
        );
    }
    let outcome = match &error {
        Some(error) => format!("failed: {error}"),
        None if stop.is_draining() => "drained".to_string(),
        None => "completed".to_string(),
    };
    RunOutcome {
        report: RunReport {
            graph: graph.name,
            wall_seconds: started.elapsed().as_secs_f64(),
            outcome,
            nodes,
            edges,
        },
        error,
    }
}

fn run_node(thread: NodeThread, node: Node, shared: &Shared) -> NodeReport {
    match node {
        Node::Source(source) => run_source(thread, source, shared),
        Node::Task(task) => run_consumer(thread, Consumer::Task(task), shared),
        Node::Sink(sink) => run_consumer(thread, Consumer::Sink(sink), shared),
    }
}

/// Calls a node method, turning a panic into an error that names the node.
fn guarded<T>(who: &Who, shared: &Shared, call: impl FnOnce() -> Result<T, NodeError>) -> Step<T> {
    match catch_unwind(AssertUnwindSafe(call)) {
        Ok(Ok(value)) => Step::Ok(value),
        Ok(Err(NodeError::Shutdown)) => Step::Stop,
        Ok(Err(NodeError::Item(cause))) if who.on_error == OnError::Skip => {
            warn!(node = %who.id, "skipped bad input item: {cause}");
            Step::Skipped
        }
        Ok(Err(error)) => {
            let cause = match error {
                NodeError::Item(cause) => format!("bad input item: {cause}"),
                other => other.to_string(),
            };
            shared.fail(RunError::NodeFailed {
                node: who.id.clone(),
                kind: who.kind.to_string(),
                cause,
            });
            Step::Stop
        }
        Err(payload) => {
            let cause = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic payload".into());
            shared.fail(RunError::NodePanicked {
                node: who.id.clone(),
                kind: who.kind.to_string(),
                cause,
            });
            Step::Stop
        }
    }
}

enum Step<T> {
    Ok(T),
    Skipped,
    Stop,
}

fn run_source(thread: NodeThread, mut source: Box<dyn Source>, shared: &Shared) -> NodeReport {
    let mut report = drive_source(thread, source.as_mut(), shared);
    report.extra = source.report();
    report
}

fn drive_source(mut thread: NodeThread, source: &mut dyn Source, shared: &Shared) -> NodeReport {
    let info = match guarded(&thread.who, shared, || source.start()) {
        Step::Ok(info) => info,
        _ => return thread.report,
    };
    if let Some(total) = info.total {
        shared.progress.inc_length(total);
    }
    let mut pacer = Pacer::new(thread.pacing);
    let abort = shared.stop.abort_rx.clone();
    loop {
        if shared.stop.is_draining() {
            debug!("draining: source stops producing");
            break;
        }
        let before = Clock::now();
        let produced = guarded(&thread.who, shared, || source.next(&mut thread.outputs));
        let mut released = Clock::now();
        thread
            .report
            .latency
            .record(released.saturating_duration_since(before));
        let time_of_validity = match produced {
            Step::Ok(Some(tov)) => tov,
            Step::Ok(None) => break,
            Step::Skipped => {
                thread.report.skips += 1;
                thread.outputs.pending.clear();
                continue;
            }
            Step::Stop => break,
        };
        let deadline = match thread.pacing {
            Pacing::Unpaced => None,
            _ => pacer.deadline(time_of_validity, Instant::now()),
        };
        if let Some(deadline) = deadline {
            let wait = deadline.saturating_duration_since(Instant::now());
            if !wait.is_zero() {
                // Sleep, but wake at once on abort.
                if let Ok(()) | Err(RecvTimeoutError::Disconnected) =
                    abort.recv_timeout(wait).map(|_| ())
                {
                    if shared.stop.is_aborted() {
                        break;
                    }
                }
                released = Clock::now();
            }
        }
        if thread.outputs.flush(released).is_err() {
            break;
        }
        thread.report.items_out += 1;
        shared.progress.inc(1);
    }
    thread.report
}

enum Consumer {
    Task(Box<dyn Task>),
    Sink(Box<dyn Sink>),
}

fn run_consumer(thread: NodeThread, mut consumer: Consumer, shared: &Shared) -> NodeReport {
    let mut report = drive_consumer(thread, &mut consumer, shared);
    report.extra = match &consumer {
        Consumer::Task(task) => task.report(),
        Consumer::Sink(sink) => sink.report(),
    };
    report
}

fn drive_consumer(
    mut thread: NodeThread,
    mut consumer: &mut Consumer,
    shared: &Shared,
) -> NodeReport {
    let started = match &mut consumer {
        Consumer::Task(task) => guarded(&thread.who, shared, || task.start()),
        Consumer::Sink(sink) => guarded(&thread.who, shared, || sink.start()),
    };
    if !matches!(started, Step::Ok(())) {
        return thread.report;
    }
    let port_count = thread.input_ports.len();
    let aligned = port_count > 1 && thread.sync == SyncMode::Aligned;
    let mut aligner = Aligner::new(port_count, thread.align_tolerance_us);
    let receivers = std::mem::take(&mut thread.inputs);
    let abort = shared.stop.abort_rx.clone();
    let spin = thread.idle_spin;

    // One input group, reused for every call: no allocation per message.
    let mut inputs = Inputs {
        ports: Arc::clone(&thread.input_ports),
        messages: vec![None; port_count],
    };
    let mut deliver =
        |thread: &mut NodeThread, consumer: &mut Consumer, port: usize, message: Message| -> bool {
            let arrived = Clock::now();
            thread.report.items_in += 1;
            thread
                .report
                .age
                .record(arrived.saturating_duration_since(message.header().entered_graph));
            if !aligned {
                inputs.messages[port] = Some(message);
                let keep_going = call(thread, consumer, &mut inputs, shared, arrived);
                inputs.messages[port] = None;
                return keep_going;
            }
            aligner.push(port, message);
            while let Some(group) = aligner.pop_group() {
                inputs.messages = group;
                if !call(thread, consumer, &mut inputs, shared, Clock::now()) {
                    return false;
                }
            }
            true
        };

    if receivers.len() == 1 {
        // The common chain case: one input. It parks on a plain `recv`, the cheapest wake-up;
        // an abort still reaches it, because aborting sources drop their senders and the
        // disconnection cascades down the graph.
        let (port, rx) = &receivers[0];
        loop {
            let message = match try_recv_spinning(rx, spin) {
                Ok(message) => message,
                Err(TryRecvError::Disconnected) => break,
                Err(TryRecvError::Empty) => match rx.recv() {
                    Ok(message) => message,
                    Err(_) => break,
                },
            };
            let depth = rx.len() + 1;
            thread.report.max_queue_depth = thread.report.max_queue_depth.max(depth);
            if !deliver(&mut thread, &mut consumer, *port, message) {
                return thread.report;
            }
        }
    } else if !receivers.is_empty() {
        let mut select = Select::new();
        let abort_index = select.recv(&abort);
        let mut slots: Vec<Option<usize>> = vec![None; abort_index + 1];
        for (edge, (_, rx)) in receivers.iter().enumerate() {
            let index = select.recv(rx);
            if slots.len() <= index {
                slots.resize(index + 1, None);
            }
            slots[index] = Some(edge);
        }
        let mut open = receivers.len();
        while open > 0 {
            let operation = select.select();
            let index = operation.index();
            if index == abort_index {
                let _ = operation.recv(&abort);
                return thread.report;
            }
            let Some(edge) = slots.get(index).copied().flatten() else {
                break;
            };
            let (port, rx) = &receivers[edge];
            match operation.recv(rx) {
                Ok(message) => {
                    let depth = rx.len() + 1;
                    thread.report.max_queue_depth = thread.report.max_queue_depth.max(depth);
                    if !deliver(&mut thread, &mut consumer, *port, message) {
                        return thread.report;
                    }
                }
                Err(_) => {
                    select.remove(index);
                    open -= 1;
                }
            }
        }
    }
    aligner.close();
    thread.report.unaligned = aligner.unmatched();
    if shared.stop.is_aborted() {
        return thread.report;
    }
    let before = thread.outputs.sent();
    let outputs = &mut thread.outputs;
    let _ = match &mut consumer {
        Consumer::Task(task) => guarded(&thread.who, shared, || task.finish(outputs)),
        Consumer::Sink(sink) => guarded(&thread.who, shared, || sink.finish()),
    };
    thread.report.items_out += thread.outputs.sent() - before;
    thread.report
}

/// Polls an empty queue for up to `spin` before the caller parks the thread: an item that
/// arrives within microseconds is taken without the cost of a futex wake-up.
fn try_recv_spinning(rx: &Receiver<Message>, spin: Duration) -> Result<Message, TryRecvError> {
    match rx.try_recv() {
        Err(TryRecvError::Empty) if !spin.is_zero() => {}
        other => return other,
    }
    let started = Instant::now();
    let mut polls = 0u32;
    loop {
        for _ in 0..32 {
            std::hint::spin_loop();
        }
        match rx.try_recv() {
            Err(TryRecvError::Empty) => {}
            other => return other,
        }
        polls += 1;
        // Let other nodes run on a busy machine; check the clock only now and then.
        if polls % 16 == 0 {
            std::thread::yield_now();
            if started.elapsed() >= spin {
                return Err(TryRecvError::Empty);
            }
        }
    }
}

/// One call of `process`/`consume`; false when the node must stop.
fn call(
    thread: &mut NodeThread,
    consumer: &mut Consumer,
    inputs: &mut Inputs,
    shared: &Shared,
    started: Clock,
) -> bool {
    if let Some(header) = inputs.header() {
        thread.outputs.inherit(*header);
    }
    let before_sent = thread.outputs.sent();
    let outputs = &mut thread.outputs;
    let inputs = &*inputs;
    let step = match consumer {
        Consumer::Task(task) => guarded(&thread.who, shared, || task.process(inputs, outputs)),
        Consumer::Sink(sink) => guarded(&thread.who, shared, || sink.consume(inputs)),
    };
    thread
        .report
        .latency
        .record(Clock::now().saturating_duration_since(started));
    thread.report.items_out += thread.outputs.sent() - before_sent;
    match step {
        Step::Ok(()) => true,
        Step::Skipped => {
            thread.report.skips += 1;
            true
        }
        Step::Stop => false,
    }
}
