//! An in-process collecting sink: a command runs a graph and gets back, as values, the messages
//! of an output the graph exposes (`interface: {outputs: ...}`), where it would otherwise have
//! had a node write a file and read it back.

use std::any::Any;
use std::sync::{Arc, Mutex};

use crate::diagnostic::{Diagnostic, Diagnostics};
use crate::error::NodeError;
use crate::node::{Inputs, Node, Sink};
use crate::pacing::Pacing;
use crate::policy::EdgePolicy;
use crate::port::{Port, PortType};
use crate::registry::{KindSpec, NodeKind};
use crate::schema::{OnError, SyncMode};
use crate::validate::{NodeSpec, ResolvedEdge, ResolvedGraph};

/// The messages collected from one exposed output, in the order they arrived.
pub struct Collected<T> {
    items: Arc<Mutex<Vec<Arc<T>>>>,
}

impl<T> Collected<T> {
    /// Everything collected so far (after the run: everything the output sent).
    pub fn take(&self) -> Vec<Arc<T>> {
        match self.items.lock() {
            Ok(mut items) => std::mem::take(&mut *items),
            Err(poisoned) => std::mem::take(&mut *poisoned.into_inner()),
        }
    }
}

struct CollectingSink<T> {
    items: Arc<Mutex<Vec<Arc<T>>>>,
}

/// The collector's one input.
const COLLECTED: &str = "collected";

impl<T: Any + Send + Sync> Sink for CollectingSink<T> {
    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let item = inputs.shared(&Port::<T>::new(COLLECTED))?;
        match self.items.lock() {
            Ok(mut items) => items.push(item),
            Err(poisoned) => poisoned.into_inner().push(item),
        }
        Ok(())
    }
}

impl ResolvedGraph {
    /// Adds a sink that collects what the exposed output `output` sends, as `T`: what a command
    /// reads once the run ends. The output must exist and carry `T`.
    pub fn collect<T: Any + Send + Sync>(
        &mut self,
        output: &str,
    ) -> Result<Collected<T>, Diagnostics> {
        let problem = |message: String, hint: Option<String>| {
            Diagnostics(vec![Diagnostic {
                file: self.spec.file.clone(),
                position: None,
                message,
                hint,
            }])
        };
        let Some(exposed) = self.spec.interface.outputs.get(output).cloned() else {
            let names: Vec<&str> = self
                .spec
                .interface
                .outputs
                .keys()
                .map(String::as_str)
                .collect();
            return Err(problem(
                format!("the graph exposes no output '{output}'"),
                Some(format!("exposed outputs: {}", names.join(", "))),
            ));
        };
        let from = &self.spec.nodes[exposed.node];
        let carried = from.kind.outputs[exposed.port].ty;
        if carried != PortType::of::<T>() {
            return Err(problem(
                format!(
                    "output '{output}' carries {}, not the {} it is collected as",
                    carried.name(),
                    PortType::of::<T>().name()
                ),
                None,
            ));
        }
        let kind = NodeKind::internal(
            KindSpec::sink(
                "collect",
                "hands an exposed output's messages to the command that runs the graph",
            )
            .input(Port::<T>::new(COLLECTED).spec()),
        );
        let items = Arc::new(Mutex::new(Vec::new()));
        self.spec.nodes.push(NodeSpec {
            id: format!("collect:{output}"),
            kind,
            params: serde_json::Value::Null,
            on_error: OnError::Stop,
            pacing: Pacing::Unpaced,
            sync: SyncMode::Aligned,
            align_tolerance_us: 0,
        });
        self.nodes.push(Node::Sink(Box::new(CollectingSink {
            items: Arc::clone(&items),
        })));
        self.spec.edges.push(ResolvedEdge {
            from_node: exposed.node,
            from_port: exposed.port,
            to_node: self.spec.nodes.len() - 1,
            to_port: 0,
            capacity: self.spec.settings.default_capacity,
            policy: EdgePolicy::Block,
        });
        Ok(Collected { items })
    }
}
