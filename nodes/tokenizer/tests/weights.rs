//! Weights round-trip exactly; a missing file or another config's weights are clear errors.

use crate::common;

use common::tiny;

use bevworld_tokenizer::{WeightsError, load_weights, save_weights};
use burn::prelude::*;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

#[test]
fn weights_round_trip_and_mismatches_are_named() {
    let device = Device::flex();
    let config = tiny();
    let model = config.init_seeded(0, &device);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("tokenizer-tiny.bpk");
    save_weights(&model, &path).expect("save");

    let loaded = load_weights(&config, &path, &device).expect("load");
    let n = config.latent_size();
    let latent = Tensor::<4>::from_data(
        TensorData::new(
            (0..4 * n * n)
                .map(|i| ((i % 17) as f32 - 8.0) * 0.1)
                .collect::<Vec<f32>>(),
            [1, 4, n, n],
        ),
        &device,
    );
    assert_eq!(
        values(model.voxels(latent.clone()).table().clone()),
        values(loaded.voxels(latent).table().clone())
    );

    let missing = dir.path().join("absent.bpk");
    let err = load_weights(&config, &missing, &device).expect_err("error");
    assert!(matches!(err, WeightsError::NotFound { .. }));
    assert!(err.to_string().contains("absent.bpk"));

    // Weights of a wider decoder do not fit the tiny config.
    let mut wider = config.clone();
    wider.name = "wider".into();
    wider.decoder.dim = 64;
    let wide_path = dir.path().join("wider.bpk");
    save_weights(&wider.init_seeded(1, &device), &wide_path).expect("save");
    let err = load_weights(&config, &wide_path, &device).expect_err("error");
    let message = err.to_string();
    assert!(matches!(err, WeightsError::Mismatch { .. }), "{message}");
    assert!(message.contains("tokenizer-tiny"), "{message}");

    let garbage = dir.path().join("garbage.bpk");
    std::fs::write(&garbage, b"not a burnpack file").expect("write");
    assert!(load_weights(&config, &garbage, &device).is_err());
}
