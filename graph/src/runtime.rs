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
use crate::validate::{GraphSpec, ResolvedGraph};

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

/// Hears of a run's progress as it goes (the command line's progress bar); a run works
/// without one. Called from the nodes' threads.
pub trait RunObserver: Send + Sync {
    /// A source announced `items` it will produce.
    fn expect_items(&self, _items: u64) {}
    /// A source released one item into the graph.
    fn item_released(&self) {}
    /// Every node has stopped.
    fn finished(&self) {}
}

/// Options that are not part of the graph file.
#[derive(Clone, Default)]
pub struct RunOptions {
    pub stop: StopHandle,
    pub observer: Option<Arc<dyn RunObserver>>,
}

/// A finished run: its metrics, and its error if it failed.
pub struct RunOutcome {
    pub report: RunReport,
    pub error: Option<RunError>,
}

struct Shared {
    stop: StopHandle,
    failures: Mutex<Vec<RunError>>,
    observer: Option<Arc<dyn RunObserver>>,
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
    let shared = Arc::new(Shared {
        stop: stop.clone(),
        failures: Mutex::new(Vec::new()),
        observer: options.observer,
    });
    let ResolvedGraph { spec, nodes } = graph;
    let wiring = Wiring::new(&spec, &stop);
    let edge_counters = wiring.counters.clone();
    let spawned = spawn_nodes(&spec, nodes, wiring, &shared);
    let grace = Duration::from_millis(spec.settings.shutdown_grace_ms);
    let (reports, hung) = await_nodes(spawned.done, spawned.pending, grace, &stop);
    if let Some(observer) = &shared.observer {
        observer.finished();
    }
    let failures = shared
        .failures
        .lock()
        .map(|mut f| std::mem::take(&mut *f))
        .unwrap_or_default();
    report(
        &spec,
        Ending {
            reports,
            hung,
            failures,
            startup_error: spawned.startup_error,
            draining: stop.is_draining(),
            aborted: stop.is_aborted(),
            wall_seconds: started.elapsed().as_secs_f64(),
        },
        &edge_counters,
    )
}

/// One bounded channel per edge: each node's senders per output port and its receivers.
struct Wiring {
    /// `[node][output port]` → the edges leaving it.
    senders: Vec<Vec<Vec<EdgeSender>>>,
    /// `[node]` → (input port, receiver) per incoming edge.
    receivers: Vec<Vec<(usize, Receiver<Message>)>>,
    /// Per edge, in the graph's edge order.
    counters: Vec<Arc<EdgeCounters>>,
}

impl Wiring {
    fn new(spec: &GraphSpec, stop: &StopHandle) -> Self {
        let mut senders: Vec<Vec<Vec<EdgeSender>>> = spec
            .nodes
            .iter()
            .map(|n| n.kind.outputs.iter().map(|_| Vec::new()).collect())
            .collect();
        let mut receivers: Vec<Vec<(usize, Receiver<Message>)>> =
            vec![Vec::new(); spec.nodes.len()];
        let mut counters = Vec::new();
        for edge in &spec.edges {
            let (tx, rx) = bounded::<Message>(edge.capacity);
            let edge_counters = Arc::new(EdgeCounters::default());
            let evict = matches!(
                edge.policy,
                crate::policy::EdgePolicy::DropOldest | crate::policy::EdgePolicy::Latest
            )
            .then(|| rx.clone());
            senders[edge.from_node][edge.from_port].push(EdgeSender {
                tx,
                evict,
                counters: Arc::clone(&edge_counters),
                abort: stop.abort_rx.clone(),
            });
            receivers[edge.to_node].push((edge.to_port, rx));
            counters.push(edge_counters);
        }
        Self {
            senders,
            receivers,
            counters,
        }
    }
}

/// The node threads, once started.
struct Spawned {
    /// Each thread sends its node's index and report when it ends.
    done: Receiver<(usize, NodeReport)>,
    /// Per node, its id while its thread runs (`None` once reported or never started).
    pending: Vec<Option<String>>,
    startup_error: Option<RunError>,
}

/// Starts one thread per node.
fn spawn_nodes(
    spec: &GraphSpec,
    nodes: Vec<Node>,
    wiring: Wiring,
    shared: &Arc<Shared>,
) -> Spawned {
    let (done_tx, done_rx) = crossbeam_channel::unbounded::<(usize, NodeReport)>();
    let mut pending: Vec<Option<String>> = Vec::with_capacity(nodes.len());
    let mut startup_error = None;
    for (index, (((declared, node), outputs), inputs)) in spec
        .nodes
        .iter()
        .zip(nodes)
        .zip(wiring.senders)
        .zip(wiring.receivers)
        .enumerate()
    {
        let output_ports: Arc<[&'static str]> =
            declared.kind.outputs.iter().map(|p| p.name).collect();
        let input_ports: Arc<[&'static str]> =
            declared.kind.inputs.iter().map(|p| p.name).collect();
        let is_source = matches!(node, Node::Source(_));
        let thread = NodeThread {
            report: NodeReport::new(
                &declared.id,
                declared.kind.name,
                declared.kind.role.as_str(),
            ),
            who: Who {
                id: declared.id.clone(),
                kind: declared.kind.name,
                on_error: declared.on_error,
            },
            pacing: declared.pacing,
            sync: declared.sync,
            align_tolerance_us: declared.align_tolerance_us,
            idle_spin: Duration::from_micros(spec.settings.idle_spin_us),
            inputs,
            input_ports,
            outputs: Outputs::new(output_ports, outputs, is_source),
        };
        let for_thread = Arc::clone(shared);
        let done = done_tx.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("node:{}", declared.id))
            .spawn(move || {
                let span = info_span!("node", id = %thread.who.id, kind = thread.who.kind);
                let _entered = span.enter();
                let report = run_node(thread, node, &for_thread);
                let _ = done.send((index, report));
            });
        match spawned {
            Ok(_) => pending.push(Some(declared.id.clone())),
            Err(error) => {
                startup_error = Some(RunError::Startup(format!(
                    "spawning node '{}': {error}",
                    declared.id
                )));
                shared.stop.abort();
                pending.push(None);
            }
        }
    }
    Spawned {
        done: done_rx,
        pending,
        startup_error,
    }
}

/// Collects every node's report; after an abort, waits at most `grace` for the stragglers,
/// and returns those still running as hung.
fn await_nodes(
    done: Receiver<(usize, NodeReport)>,
    mut pending: Vec<Option<String>>,
    grace: Duration,
    stop: &StopHandle,
) -> (Vec<Option<NodeReport>>, Vec<String>) {
    let mut reports: Vec<Option<NodeReport>> = (0..pending.len()).map(|_| None).collect();
    let mut abort_seen: Option<Instant> = None;
    while pending.iter().any(Option::is_some) {
        let wait = match abort_seen {
            Some(at) => grace.saturating_sub(at.elapsed()),
            None => Duration::from_millis(50),
        };
        match done.recv_timeout(wait) {
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
    let hung = pending.into_iter().flatten().collect();
    (reports, hung)
}

/// How the node threads ended.
struct Ending {
    reports: Vec<Option<NodeReport>>,
    hung: Vec<String>,
    failures: Vec<RunError>,
    startup_error: Option<RunError>,
    draining: bool,
    /// The stop handle was aborted (by a failure, or by the user).
    aborted: bool,
    wall_seconds: f64,
}

/// The run's metrics (edge drops attributed to the receiving node) and its error: a startup
/// error, else the first failure, else the hung nodes.
fn report(spec: &GraphSpec, ending: Ending, counters: &[Arc<EdgeCounters>]) -> RunOutcome {
    let Ending {
        reports,
        hung,
        mut failures,
        startup_error,
        draining,
        aborted,
        wall_seconds,
    } = ending;
    let mut nodes: Vec<NodeReport> = reports.into_iter().flatten().collect();
    for report in &mut nodes {
        report.summarise();
    }
    let edges: Vec<EdgeReport> = spec
        .edges
        .iter()
        .zip(counters)
        .map(|(edge, counters)| {
            let (from, to) = spec.edge_label(edge);
            EdgeReport {
                from,
                to,
                policy: edge.policy.as_str(),
                capacity: edge.capacity,
                sent: counters.sent.load(Ordering::Relaxed),
                dropped: counters.dropped.load(Ordering::Relaxed),
            }
        })
        .collect();
    for report in &mut nodes {
        report.drops = spec
            .edges
            .iter()
            .zip(&edges)
            .filter(|(edge, _)| spec.nodes[edge.to_node].id == report.id)
            .map(|(_, e)| e.dropped)
            .sum();
    }
    let error = if let Some(error) = startup_error {
        Some(error)
    } else if !failures.is_empty() {
        Some(failures.remove(0))
    } else if !hung.is_empty() {
        Some(RunError::Hung {
            nodes: hung.clone(),
            grace_ms: spec.settings.shutdown_grace_ms,
        })
    } else if aborted {
        Some(RunError::Aborted {
            unfinished: nodes
                .iter()
                .filter(|n| !n.finished)
                .map(|n| n.id.clone())
                .collect(),
        })
    } else {
        nothing_done(&nodes, draining)
    };
    if !hung.is_empty() {
        warn!(
            "nodes still running after {} ms: {hung:?}",
            spec.settings.shutdown_grace_ms
        );
    }
    let outcome = match &error {
        Some(error @ RunError::Aborted { .. }) => error.to_string(),
        Some(error) => format!("failed: {error}"),
        None if draining => "drained".to_string(),
        None => "completed".to_string(),
    };
    RunOutcome {
        report: RunReport {
            graph: spec.name.clone(),
            wall_seconds,
            outcome,
            nodes,
            edges,
        },
        error,
    }
}

/// A run that made nothing: no source produced an item (a dataset past its `start`, a shard
/// with no scenes), or a node skipped every item it was given. A drained run may stop before
/// its first item; that is the user's choice, not a fault.
fn nothing_done(nodes: &[NodeReport], draining: bool) -> Option<RunError> {
    let sources: Vec<&NodeReport> = nodes.iter().filter(|n| n.role == "source").collect();
    let produced: u64 = sources.iter().map(|n| n.items_out).sum();
    let skipped: u64 = sources.iter().map(|n| n.skips).sum();
    if produced == 0 && !draining {
        return Some(RunError::NothingDone(if skipped > 0 {
            format!("the sources skipped all {skipped} items they read (see the warnings above)")
        } else {
            "the sources produced no items (a `start` past the end, a shard with no scenes, an empty selection?)".into()
        }));
    }
    if let Some(n) = nodes
        .iter()
        .find(|n| n.role != "source" && n.items_in > 0 && n.skips == n.items_in)
    {
        return Some(RunError::NothingDone(format!(
            "node '{}' skipped all {} items it received (see the warnings above)",
            n.id, n.skips
        )));
    }
    nothing_reached_an_output(nodes, draining)
}

/// A run whose every sink made nothing (received no item, or says it made nothing of what it
/// received) produced nothing a user asked for, whatever its sources read: it fails, naming
/// where the stream stopped and, when that node says, why.
fn nothing_reached_an_output(nodes: &[NodeReport], draining: bool) -> Option<RunError> {
    let sinks: Vec<&NodeReport> = nodes.iter().filter(|n| n.role == "sink").collect();
    let made_nothing = |n: &NodeReport| n.items_in == 0 || n.nothing_made.is_some();
    if draining || sinks.is_empty() || !sinks.iter().all(|n| made_nothing(n)) {
        return None;
    }
    // Where the stream stopped: a node that was given items and made nothing of them. One
    // that says why comes first; the graph's order breaks ties (upstream nodes are declared
    // first in every shipped graph).
    let stopped = |n: &&NodeReport| {
        n.role != "source"
            && n.items_in > 0
            && (n.nothing_made.is_some() || (n.role == "task" && n.items_out == 0))
    };
    let culprit = nodes
        .iter()
        .filter(stopped)
        .find(|n| n.nothing_made.is_some())
        .or_else(|| nodes.iter().find(stopped));
    let message = match culprit {
        Some(n) => format!(
            "no sink made anything: node '{}' ({}) received {} item(s) and made nothing of them{}",
            n.id,
            n.kind,
            n.items_in,
            n.nothing_made
                .as_deref()
                .map(|why| format!(": {why}"))
                .unwrap_or_default()
        ),
        None => "no sink received an item".to_string(),
    };
    Some(RunError::NothingDone(message))
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
    if let (Some(total), Some(observer)) = (info.total, &shared.observer) {
        observer.expect_items(total);
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
                    && shared.stop.is_aborted()
                {
                    break;
                }
                released = Clock::now();
            }
        }
        if thread.outputs.flush(released).is_err() {
            break;
        }
        thread.report.items_out += 1;
        if let Some(observer) = &shared.observer {
            observer.item_released();
        }
    }
    thread.report.finished = !shared.stop.is_aborted();
    thread.report
}

enum Consumer {
    Task(Box<dyn Task>),
    Sink(Box<dyn Sink>),
}

fn run_consumer(thread: NodeThread, mut consumer: Consumer, shared: &Shared) -> NodeReport {
    let mut report = drive_consumer(thread, &mut consumer, shared);
    (report.extra, report.nothing_made) = match &consumer {
        Consumer::Task(task) => (task.report(), task.nothing_made()),
        Consumer::Sink(sink) => (sink.report(), sink.nothing_made()),
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
    let receivers = std::mem::take(&mut thread.inputs);
    let mut connected: Vec<usize> = receivers.iter().map(|(port, _)| *port).collect();
    connected.sort_unstable();
    connected.dedup();
    // Aligned over the ports that have edges: an optional input left unconnected never waits.
    let aligned = connected.len() > 1 && thread.sync == SyncMode::Aligned;
    let mut aligner = Aligner::over(port_count, &connected, thread.align_tolerance_us);
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
            if !deliver(&mut thread, consumer, *port, message) {
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
                    if !deliver(&mut thread, consumer, *port, message) {
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
    thread.report.finished = !shared.stop.is_aborted();
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
        if polls.is_multiple_of(16) {
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
