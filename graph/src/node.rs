//! The three node traits, one small trait each (as in copper-rs): a `Source` produces, a `Task`
//! transforms, a `Sink` consumes. Each runs on its own thread; the runtime owns the channels.

use std::any::Any;
use std::sync::Arc;

use crate::error::NodeError;
use crate::message::{Header, Instant, Message};
use crate::policy::{EdgeSender, SendOutcome};
use crate::port::Port;

/// What a source knows about its stream before it starts.
#[derive(Clone, Debug, Default)]
pub struct SourceInfo {
    /// Number of items it will produce, when known (drives the progress bar).
    pub total: Option<u64>,
}

/// Produces items. `next` returns the item's time of validity, or `None` at the end.
pub trait Source: Send {
    /// Opens files and devices; runs on the node's thread before the first `next`.
    fn start(&mut self) -> Result<SourceInfo, NodeError> {
        Ok(SourceInfo::default())
    }

    /// Emits one item on its output ports through `out`.
    ///
    /// Returns `Ok(Some(time_of_validity_us))` after emitting, `Ok(None)` when the stream ended.
    /// The time of validity drives recorded-time pacing and stamps the messages' headers;
    /// `out.set_time_of_validity` must be called before sending.
    fn next(&mut self, out: &mut Outputs) -> Result<Option<i64>, NodeError>;

    /// Figures of the node's own to add to its metrics at the end of the run (named counters
    /// and means, e.g. points dropped by a limit, mean PSNR).
    fn report(&self) -> Figures {
        Figures::new()
    }
}

/// Named figures a node reports into its metrics.
pub type Figures = std::collections::BTreeMap<String, f64>;

/// Transforms inputs into outputs.
pub trait Task: Send {
    fn start(&mut self) -> Result<(), NodeError> {
        Ok(())
    }

    /// Called once per input group (one message, or one aligned set of messages).
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError>;

    /// Called once after every input closed; may emit final items (a flushed buffer).
    fn finish(&mut self, _out: &mut Outputs) -> Result<(), NodeError> {
        Ok(())
    }

    /// See `Source::report`.
    fn report(&self) -> Figures {
        Figures::new()
    }

    /// Why the node sent nothing of what it received, in the user's terms (a history that
    /// never filled: how many frames it got, how many it needs). Asked at the end of a run in
    /// which no sink made anything, to name the real cause.
    fn nothing_made(&self) -> Option<String> {
        None
    }
}

/// Consumes inputs (writes files, prints metrics).
pub trait Sink: Send {
    fn start(&mut self) -> Result<(), NodeError> {
        Ok(())
    }

    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError>;

    /// Called once after every input closed: flush and close files.
    fn finish(&mut self) -> Result<(), NodeError> {
        Ok(())
    }

    /// See `Source::report`.
    fn report(&self) -> Figures {
        Figures::new()
    }

    /// `Some(why)` when the sink made nothing of what it received (every item was of a kind
    /// it does not write, nothing could be scored). A run in which no sink made anything
    /// fails, naming this.
    fn nothing_made(&self) -> Option<String> {
        None
    }
}

/// A constructed node of one of the three roles.
pub enum Node {
    Source(Box<dyn Source>),
    Task(Box<dyn Task>),
    Sink(Box<dyn Sink>),
}

impl Node {
    pub fn role(&self) -> Role {
        match self {
            Node::Source(_) => Role::Source,
            Node::Task(_) => Role::Task,
            Node::Sink(_) => Role::Sink,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    Source,
    Task,
    Sink,
}

impl Role {
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Source => "source",
            Role::Task => "task",
            Role::Sink => "sink",
        }
    }
}

/// The messages of one input group, by input port.
pub struct Inputs {
    pub(crate) ports: Arc<[&'static str]>,
    pub(crate) messages: Vec<Option<Message>>,
}

impl Inputs {
    /// Builds an input group directly; for unit tests of nodes outside a running graph.
    pub fn from_messages(ports: &[&'static str], messages: Vec<Option<Message>>) -> Self {
        Self {
            ports: ports.into(),
            messages,
        }
    }

    fn index(&self, port: &str) -> Result<usize, NodeError> {
        self.ports
            .iter()
            .position(|name| *name == port)
            .ok_or_else(|| NodeError::fatal(format!("no input port named '{port}'")))
    }

    /// The message on `port`, if this group has one.
    pub fn message(&self, port: &str) -> Option<&Message> {
        self.index(port)
            .ok()
            .and_then(|i| self.messages.get(i))
            .and_then(Option::as_ref)
    }

    /// The payload on `port`; an error when the port has no message in this group.
    pub fn get<T: Any>(&self, port: &Port<T>) -> Result<&T, NodeError> {
        self.message(port.name)
            .ok_or_else(|| NodeError::fatal(format!("input '{}' has no message", port.name)))?
            .get::<T>()
    }

    /// The payload on `port`, shared: for passing it on without a copy.
    pub fn shared<T: Any + Send + Sync>(&self, port: &Port<T>) -> Result<Arc<T>, NodeError> {
        self.message(port.name)
            .ok_or_else(|| NodeError::fatal(format!("input '{}' has no message", port.name)))?
            .shared::<T>()
    }

    /// The header of the group: that of its first present message.
    pub fn header(&self) -> Option<&Header> {
        self.messages.iter().flatten().next().map(Message::header)
    }
}

/// The output ports of one node, each fanned out to its edges.
pub struct Outputs {
    pub(crate) ports: Arc<[&'static str]>,
    pub(crate) edges: Vec<Vec<EdgeSender>>,
    /// The header the next sends are stamped with.
    pub(crate) header: Header,
    pub(crate) seq: u64,
    pub(crate) sent: u64,
    pub(crate) is_source: bool,
    /// Sources' sends wait here until the pacer releases the item.
    pub(crate) pending: Vec<(usize, Message)>,
}

impl Outputs {
    pub(crate) fn new(
        ports: Arc<[&'static str]>,
        edges: Vec<Vec<EdgeSender>>,
        is_source: bool,
    ) -> Self {
        Self {
            ports,
            edges,
            header: Header {
                seq: 0,
                time_of_validity_us: 0,
                entered_graph: Instant::now(),
            },
            seq: 0,
            sent: 0,
            is_source,
            pending: Vec::new(),
        }
    }

    /// Outputs with no edges; sends go nowhere. For unit tests of nodes.
    pub fn detached(ports: &[&'static str]) -> Self {
        Self::new(
            ports.into(),
            ports.iter().map(|_| Vec::new()).collect(),
            true,
        )
    }

    fn index(&self, port: &str) -> Result<usize, NodeError> {
        self.ports
            .iter()
            .position(|name| *name == port)
            .ok_or_else(|| NodeError::fatal(format!("no output port named '{port}'")))
    }

    /// Whether anything listens on `port`, so a node can skip work nobody consumes.
    pub fn is_connected<T>(&self, port: &Port<T>) -> bool {
        self.index(port.name)
            .map(|i| !self.edges[i].is_empty())
            .unwrap_or(false)
    }

    /// Sources call this once per item, before sending: it starts a new header.
    pub fn set_time_of_validity(&mut self, time_of_validity_us: i64) {
        if self.is_source {
            // `entered_graph` is stamped when the pacer releases the item (see `flush`).
            self.header = Header {
                seq: self.seq,
                time_of_validity_us,
                entered_graph: self.header.entered_graph,
            };
            self.seq += 1;
        } else {
            self.header.time_of_validity_us = time_of_validity_us;
        }
    }

    pub(crate) fn inherit(&mut self, header: Header) {
        self.header = header;
    }

    pub fn send<T: Any + Send + Sync>(
        &mut self,
        port: &Port<T>,
        payload: T,
    ) -> Result<(), NodeError> {
        self.send_shared(port, Arc::new(payload))
    }

    /// Sends a payload that is already shared; fan-out clones the `Arc`, never the data.
    pub fn send_shared<T: Any + Send + Sync>(
        &mut self,
        port: &Port<T>,
        payload: Arc<T>,
    ) -> Result<(), NodeError> {
        let index = self.index(port.name)?;
        let message = Message::from_shared(self.header, payload);
        self.sent += 1;
        if self.is_source {
            self.pending.push((index, message));
            return Ok(());
        }
        self.deliver(index, message)
    }

    /// Releases a source's buffered sends, stamped with the release time.
    pub(crate) fn flush(&mut self, released: Instant) -> Result<(), NodeError> {
        // Drain in place so the buffer keeps its capacity: no allocation per item.
        let mut pending = std::mem::take(&mut self.pending);
        let mut result = Ok(());
        for (index, mut message) in pending.drain(..) {
            message.restamp(released);
            if result.is_ok() {
                result = self.deliver(index, message);
            }
        }
        self.pending = pending;
        result
    }

    fn deliver(&mut self, index: usize, message: Message) -> Result<(), NodeError> {
        let edges = &self.edges[index];
        let Some((last, others)) = edges.split_last() else {
            return Ok(());
        };
        let mut closed = 0usize;
        for edge in others {
            if edge.send(message.clone()) == SendOutcome::Closed {
                closed += 1;
            }
        }
        // The last edge takes the message itself: one reference-count round trip less per hop.
        if last.send(message) == SendOutcome::Closed {
            closed += 1;
        }
        if closed == edges.len() {
            return Err(NodeError::Shutdown);
        }
        Ok(())
    }

    /// Items sent so far, across ports.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// The header that sends are stamped with now.
    pub fn header(&self) -> Header {
        self.header
    }
}
