//! Small node kinds for exercising the runtime: a counting source, pass-through and faulty
//! tasks, and a recording sink.

#![allow(dead_code)]

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use bevworld_graph::{
    Inputs, KindSpec, Models, Node, NodeError, Outputs, ParamError, Port, Registry, Sink, Source,
    SyncMode, Task,
};
use serde::{Deserialize, Serialize};

// The test kinds' ports, each named once (`bevworld_graph::Port`).
pub const IN: Port<Counted> = Port::new("in");
pub const LEFT: Port<Counted> = Port::new("left");
pub const RIGHT: Port<Counted> = Port::new("right");
pub const TEXT: Port<String> = Port::new("text");
pub const OUT: Port<Counted> = Port::new("out");

/// A payload that counts how many of its kind are alive, to check memory stays bounded.
pub struct Counted {
    pub value: u64,
}

pub static LIVE: AtomicUsize = AtomicUsize::new(0);
pub static PEAK: AtomicUsize = AtomicUsize::new(0);

impl Counted {
    pub fn new(value: u64) -> Self {
        let live = LIVE.fetch_add(1, Ordering::SeqCst) + 1;
        PEAK.fetch_max(live, Ordering::SeqCst);
        Self { value }
    }
}

impl Drop for Counted {
    fn drop(&mut self) {
        LIVE.fetch_sub(1, Ordering::SeqCst);
    }
}

/// What recording sinks saw, by sink name.
pub fn recorded(name: &str) -> Vec<u64> {
    records()
        .lock()
        .unwrap()
        .iter()
        .filter(|(n, _)| n == name)
        .map(|(_, v)| *v)
        .collect()
}

fn records() -> &'static Mutex<Vec<(String, u64)>> {
    static RECORDS: OnceLock<Mutex<Vec<(String, u64)>>> = OnceLock::new();
    RECORDS.get_or_init(|| Mutex::new(Vec::new()))
}

/// The payloads a recording sink with `keep: true` received, held alive so that two equal
/// pointers can only be one allocation.
pub fn kept(name: &str) -> Vec<Arc<Counted>> {
    kept_payloads()
        .lock()
        .unwrap()
        .iter()
        .filter(|(n, _)| n == name)
        .map(|(_, payload)| Arc::clone(payload))
        .collect()
}

/// Payloads by sink name.
type Kept = Mutex<Vec<(String, Arc<Counted>)>>;

fn kept_payloads() -> &'static Kept {
    static KEPT: OnceLock<Kept> = OnceLock::new();
    KEPT.get_or_init(|| Mutex::new(Vec::new()))
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CountParams {
    /// Items to produce; absent = forever.
    pub count: Option<u64>,
    #[serde(default = "one")]
    pub step_us: i64,
    #[serde(default)]
    pub offset_us: i64,
}

fn one() -> i64 {
    1
}

struct CountSource {
    params: CountParams,
    next: u64,
}

impl Source for CountSource {
    fn start(&mut self) -> Result<bevworld_graph::SourceInfo, NodeError> {
        Ok(bevworld_graph::SourceInfo {
            total: self.params.count,
        })
    }

    fn next(&mut self, out: &mut Outputs) -> Result<Option<i64>, NodeError> {
        if self.params.count.is_some_and(|count| self.next >= count) {
            return Ok(None);
        }
        let value = self.next;
        self.next += 1;
        let tov = self.params.offset_us + value as i64 * self.params.step_us;
        out.set_time_of_validity(tov);
        out.send(&OUT, Counted::new(value))?;
        Ok(Some(tov))
    }
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FaultParams {
    /// Fail on this item value.
    #[serde(default)]
    pub fail_at: Option<u64>,
    /// Panic on this item value.
    #[serde(default)]
    pub panic_at: Option<u64>,
    /// Reject (as a bad item) every item divisible by this.
    #[serde(default)]
    pub reject_every: Option<u64>,
    /// Sleep this long on each item.
    #[serde(default)]
    pub sleep_us: u64,
    /// Sleep this long once, on this item.
    #[serde(default)]
    pub stall_at: Option<u64>,
}

struct FaultyPass {
    params: FaultParams,
}

impl Task for FaultyPass {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let item = inputs.shared(&IN)?;
        let value = item.value;
        if self.params.sleep_us > 0 {
            std::thread::sleep(Duration::from_micros(self.params.sleep_us));
        }
        if self.params.stall_at == Some(value) {
            std::thread::sleep(Duration::from_secs(30));
        }
        if self.params.fail_at == Some(value) {
            return Err(NodeError::fatal(format!("refused item {value}")));
        }
        if self.params.panic_at == Some(value) {
            panic!("boom at item {value}");
        }
        if self.params.reject_every.is_some_and(|n| value % n == 0) {
            return Err(NodeError::item(format!("item {value} is bad")));
        }
        out.send_shared(&OUT, item)
    }
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RecordParams {
    pub name: String,
    #[serde(default)]
    pub sleep_us: u64,
    /// Keep each payload alive (see `kept`).
    #[serde(default)]
    pub keep: bool,
}

struct RecordSink {
    params: RecordParams,
}

impl Sink for RecordSink {
    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let payload = inputs.shared(&IN)?;
        let value = payload.value;
        if self.params.keep {
            kept_payloads()
                .lock()
                .unwrap()
                .push((self.params.name.clone(), payload));
        }
        if self.params.sleep_us > 0 {
            std::thread::sleep(Duration::from_micros(self.params.sleep_us));
        }
        records()
            .lock()
            .unwrap()
            .push((self.params.name.clone(), value));
        Ok(())
    }
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

/// Joins two inputs: emits left.value * 1000 + right.value.
struct Join;

impl Task for Join {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let left = inputs.get(&LEFT)?.value;
        let right = inputs.get(&RIGHT)?.value;
        out.send(&OUT, Counted::new(left * 1000 + right))
    }
}

/// Takes a text; used only for type-mismatch validation tests.
struct TextSink;

impl Sink for TextSink {
    fn consume(&mut self, _inputs: &Inputs) -> Result<(), NodeError> {
        Ok(())
    }
}

/// A sink that takes anything and keeps nothing.
pub struct Discard;

impl Sink for Discard {
    fn consume(&mut self, _inputs: &Inputs) -> Result<(), NodeError> {
        Ok(())
    }
}

#[derive(Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Flavour {
    #[default]
    Plain,
    Fancy,
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TextParams {
    #[serde(default)]
    pub flavour: Flavour,
    #[serde(default = "one_f")]
    pub scale: f64,
}

fn one_f() -> f64 {
    1.0
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WindowParams {
    pub size: usize,
}

/// Emits one item per `size` items received (their sum), and says why when it emitted none:
/// a history buffer in miniature.
struct Window {
    size: usize,
    held: Vec<u64>,
    received: usize,
    emitted: usize,
}

impl Task for Window {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        self.held.push(inputs.get(&IN)?.value);
        self.received += 1;
        if self.held.len() == self.size {
            let sum = self.held.drain(..).sum();
            self.emitted += 1;
            out.send(&OUT, Counted::new(sum))?;
        }
        Ok(())
    }

    fn nothing_made(&self) -> Option<String> {
        (self.emitted == 0).then(|| {
            format!(
                "a window needs {} items, it got {}",
                self.size, self.received
            )
        })
    }
}

pub fn registry() -> Registry {
    let mut registry = Registry::new();
    registry.register(
        KindSpec::task("window", "sums every `size` items")
            .input(IN.spec())
            .output(OUT.spec()),
        |params: WindowParams| {
            Ok(Node::Task(Box::new(Window {
                size: params.size,
                held: Vec::new(),
                received: 0,
                emitted: 0,
            })))
        },
    );
    registry.register(
        KindSpec::source("count", "counts up").output(OUT.spec()),
        |params: CountParams| Ok(Node::Source(Box::new(CountSource { params, next: 0 }))),
    );
    registry.register(
        KindSpec::task("pass", "passes items on, with optional faults")
            .input(IN.spec())
            .output(OUT.spec()),
        |params: FaultParams| Ok(Node::Task(Box::new(FaultyPass { params }))),
    );
    registry.register(
        KindSpec::sink("record", "records values").input(IN.spec()),
        |params: RecordParams| Ok(Node::Sink(Box::new(RecordSink { params }))),
    );
    registry.register(
        KindSpec::task("join", "pairs two streams")
            .input(LEFT.spec())
            .input(RIGHT.spec())
            .output(OUT.spec())
            .sync(SyncMode::Aligned),
        |_: NoParams| Ok(Node::Task(Box::new(Join))),
    );
    registry.models(|bundle: &OffsetBundle| {
        if bundle.offset >= 1000 {
            vec![
                ParamError::field("offset", format!("{} is too large", bundle.offset))
                    .with_accepted("below 1000"),
            ]
        } else {
            Vec::new()
        }
    });
    registry.register_with_models(
        KindSpec::task("offset", "adds its model bundle's offset to every item")
            .input(IN.spec())
            .output(OUT.spec()),
        |params: &OffsetParams, models: &Models| {
            models.require(&params.model, &["offset"]).map(|_| ())
        },
        |params: OffsetParams, models: &Models| {
            let offset = models.load(&params.model, |bundle| {
                let bundle: OffsetBundle = serde_json::from_value(bundle.clone())
                    .map_err(|e| ParamError::field("model", e.to_string()))?;
                Ok(Offset(bundle.offset))
            })?;
            Ok(Node::Task(Box::new(OffsetPass { offset })))
        },
    );
    registry.register_checked(
        KindSpec::sink("text_sink", "takes text").input(TEXT.spec()),
        |params: &TextParams| {
            if params.scale <= 0.0 {
                return Err(ParamError::field(
                    "scale",
                    format!("must be > 0, got {}", params.scale),
                )
                .with_accepted("a number > 0"));
            }
            Ok(())
        },
        |_: TextParams| Ok(Node::Sink(Box::new(TextSink))),
    );
    registry
}

/// A model bundle of the test registry: one number.
#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OffsetBundle {
    pub offset: u64,
    #[serde(default)]
    pub note: Option<String>,
}

/// The loaded "model": shared by every node naming its bundle.
pub struct Offset(pub u64);

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OffsetParams {
    pub model: String,
}

struct OffsetPass {
    offset: Arc<Offset>,
}

impl Task for OffsetPass {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let item = inputs.get(&IN)?;
        out.send(&OUT, Counted::new(item.value + self.offset.0))
    }
}
