//! The `encode` and `render` nodes refuse inputs that do not belong together, with errors that
//! say what to connect or configure, and never panic.

use crate::common;

use common::nuscenes_frame;

use std::path::PathBuf;

use bevworld_graph::{Header, Inputs, Instant, Message, Models, Node, Outputs, Registry, Task};
use bevworld_pillarize::{Limits, Pillarizer};
use bevworld_types::{BevFeatures, BevGrid, FrameMeta};

fn header() -> Header {
    Header {
        seq: 0,
        time_of_validity_us: 0,
        entered_graph: Instant::now(),
    }
}

fn task(kind: &str) -> Box<dyn Task> {
    let mut registry = Registry::new();
    bevworld_tokenizer::register(&mut registry);
    let model = PathBuf::from(
        std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"),
    )
    .join("../../configs/models/tokenizer-tiny.yaml");
    // The graph's `models:` section, with the one bundle the node names.
    let models = Models::new(std::collections::BTreeMap::from([(
        "tiny".to_string(),
        serde_json::json!({"tokenizer": {"config": model, "weights": "untrained"}}),
    )]));
    let params = serde_json::json!({"model": "tiny"});
    match registry
        .get(kind)
        .expect("registered")
        .build_with(&params, &models)
    {
        Ok(node) => match node {
            Node::Task(task) => task,
            _ => panic!("{kind} is not a task"),
        },
        Err(error) => panic!("{kind}: {}", error.message),
    }
}

#[test]
fn encode_refuses_pillars_of_another_frame() {
    let Some(frame) = nuscenes_frame() else {
        return;
    };
    let grid = bevworld_tokenizer::FrameInputs::new(&common::tiny()).pillar_grid();
    let mut pillars = Pillarizer::new(grid, Limits::default()).run(&[[1.0, 2.0, 0.0, 0.5]]);
    pillars.meta.frame_token = "another-frame".into();
    let mut encode = task("encode");
    let inputs = Inputs::from_messages(
        &["frame", "pillars"],
        vec![
            Some(Message::new(header(), frame.clone())),
            Some(Message::new(header(), pillars.clone())),
        ],
    );
    let error = encode
        .process(&inputs, &mut Outputs::detached(&["latent", "fused"]))
        .expect_err("mismatched frames");
    let message = format!("{error}");
    assert!(
        message.contains("another-frame") && message.contains(&frame.frame_token),
        "{message}"
    );

    // The same pillars, re-labelled to the frame, encode.
    pillars.meta.frame_token = frame.frame_token.clone();
    let inputs = Inputs::from_messages(
        &["frame", "pillars"],
        vec![
            Some(Message::new(header(), frame)),
            Some(Message::new(header(), pillars)),
        ],
    );
    encode
        .process(&inputs, &mut Outputs::detached(&["latent", "fused"]))
        .expect("encodes");
}

#[test]
fn render_refuses_latents_of_another_model_or_shape() {
    let Some(frame) = nuscenes_frame() else {
        return;
    };
    let latent = |model: &str, n: usize| BevFeatures {
        meta: FrameMeta::default(),
        grid: BevGrid {
            x_range: [-80.0, 80.0],
            y_range: [-80.0, 80.0],
            resolution: 160.0 / n as f32,
            height: n,
            width: n,
        },
        channels: (0..4).map(|c| format!("latent_{c}")).collect(),
        data: vec![0.0; 4 * n * n],
        model: model.into(),
        weights_hash: "untrained".into(),
    };
    let mut render = task("render");
    let ports = ["images", "lidar", "side_by_side"];
    let run = |render: &mut Box<dyn Task>, features: BevFeatures| {
        let inputs = Inputs::from_messages(
            &["latent", "frame"],
            vec![
                Some(Message::new(header(), features)),
                Some(Message::new(header(), frame.clone())),
            ],
        );
        render.process(&inputs, &mut Outputs::detached(&ports))
    };
    let message = format!(
        "{}",
        run(&mut render, latent("tokenizer-paper", 32)).expect_err("model")
    );
    assert!(
        message.contains("tokenizer-paper") && message.contains("`model`"),
        "{message}"
    );
    let message = format!(
        "{}",
        run(&mut render, latent("tokenizer-tiny", 96)).expect_err("shape")
    );
    assert!(
        message.contains("96") && message.contains("4 x 64 x 64"),
        "{message}"
    );
    // Nothing listens on the detached ports, so nothing is cast; the latent is accepted.
    run(&mut render, latent("tokenizer-tiny", 64)).expect("a fitting latent is accepted");
}
