//! Graphviz DOT output of a validated graph.

use crate::node::Role;
use crate::validate::GraphSpec;

pub fn to_dot(graph: &GraphSpec) -> String {
    let mut out = String::new();
    out.push_str(&format!(
        "digraph \"{}\" {{\n  rankdir=LR;\n  node [fontname=\"Helvetica\"];\n",
        escape(&graph.name)
    ));
    for node in &graph.nodes {
        let shape = match node.kind.role {
            Role::Source => "invhouse",
            Role::Task => "box",
            Role::Sink => "house",
        };
        out.push_str(&format!(
            "  \"{}\" [shape={shape}, label=\"{}\\n({})\"];\n",
            escape(&node.id),
            escape(&node.id),
            escape(node.kind.name)
        ));
    }
    for edge in &graph.edges {
        let from = &graph.nodes[edge.from_node];
        let to = &graph.nodes[edge.to_node];
        let style = if edge.policy == crate::policy::EdgePolicy::Block {
            "solid"
        } else {
            "dashed"
        };
        out.push_str(&format!(
            "  \"{}\" -> \"{}\" [label=\"{} → {}\\n{} ×{}\", style={style}];\n",
            escape(&from.id),
            escape(&to.id),
            from.kind.outputs[edge.from_port].name,
            to.kind.inputs[edge.to_port].name,
            edge.policy.as_str(),
            edge.capacity
        ));
    }
    out.push_str("}\n");
    out
}

fn escape(text: &str) -> String {
    text.replace('\\', "\\\\").replace('"', "\\\"")
}
