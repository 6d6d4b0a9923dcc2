//! What several tokenizer test files need: the repository's configs, the real nuScenes
//! keyframe beside the checkout, and volume-rendering weights of hand-written logits.
#![allow(dead_code)] // each test file uses its own part

use std::path::PathBuf;

use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_tokenizer::TokenizerConfig;
use bevworld_types::SensorFrame;

/// This crate's folder, from cargo at run time (a reused build cache may have compiled the
/// tests at another path).
pub fn crate_dir() -> PathBuf {
    PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
}

/// `configs/models/tokenizer-NAME.yaml`.
pub fn model_config(name: &str) -> TokenizerConfig {
    let path = crate_dir().join(format!("../../configs/models/tokenizer-{name}.yaml"));
    TokenizerConfig::from_yaml_file(&path).expect("model config")
}

pub fn tiny() -> TokenizerConfig {
    model_config("tiny")
}

/// The keyframe of the real nuScenes sample (`BEVWORLD_DATA`), when it is there.
pub fn nuscenes_frame() -> Option<SensorFrame> {
    let root = bevworld_sensors::real_dataset("nuscenes-sample")?;
    Some(
        Dataset::open(&root, &DatasetOptions::default())
            .expect("nuScenes sample")
            .read(0)
            .expect("frame 0"),
    )
}

/// The render weights of `rays` rays of alpha logits, row-major, on the CPU.
pub fn weights_of(logits: Vec<f32>, rays: usize) -> Vec<f32> {
    let samples = logits.len() / rays;
    bevworld_tokenizer::render::render_weights(burn::tensor::Tensor::from_data(
        burn::tensor::TensorData::new(logits, [rays, samples]),
        &burn::prelude::Device::flex(),
    ))
    .into_data()
    .try_to_vec::<f32>()
    .expect("f32")
}
